"""DVC stage `evaluate@<dataset>`: trained runs -> the papers' tables on the test split (+ MLflow).

    python pipelines/evaluate.py dataset=bandai2_locomotion

Writes reports/eval/<ds>/results.csv, reports/metrics/<ds>.json, reports/plots/<ds>/*.csv and
data/samples/<ds>.npz (see motionsynth.evaluation).
"""

import hydra
import yaml
from _common import log, one_line_errors
from omegaconf import DictConfig, OmegaConf

from motionsynth.evaluation import evaluate, log_to_mlflow


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    c = OmegaConf.to_container(cfg, resolve=True)
    params = yaml.safe_load(open(f"{cfg.paths.root}/params.yaml"))
    runs = {r["name"]: r["model"] for r in params["train_runs"].values() if r["dataset"] == cfg.dataset.name}
    ctx = evaluate(c, runs)
    if cfg.tracking.enabled:
        log_to_mlflow(ctx)
    log.info("evaluate %s: %d result rows from %d runs; %s", ctx.name, len(ctx.rows), len(runs), ctx.timings)


if __name__ == "__main__":
    main()

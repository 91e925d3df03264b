"""DVC stage `train@<dataset>-<run>`: prepared windows -> models/<dataset>/<run>/ (+ MLflow run).

    python pipelines/train.py dataset=bandai2_locomotion model=vae_lstm [train.lr=1e-3 ...]
    python pipelines/train.py dataset=bandai2_locomotion model=erd variant=controls_given
"""

import hydra
from _common import log, progress, write_json
from omegaconf import DictConfig, OmegaConf

from motionsynth.training.run import run, run_name


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    if cfg.get("model") is None:
        raise SystemExit("choose a model: python pipelines/train.py model=<name> (one of conf/model/*.yaml)")
    summary = run(OmegaConf.to_container(cfg, resolve=True), progress=progress(cfg))
    name = run_name(OmegaConf.to_container(cfg, resolve=True))
    write_json(f"{cfg.paths.reports}/metrics/train/{cfg.dataset.name}/{name}.json", summary)
    log.info("train %s on %s: %d epochs, best %s = %.5f", name, cfg.dataset.name,
             summary["epochs_run"], summary["monitor"], summary.get(summary["monitor"], float("nan")))


if __name__ == "__main__":
    main()

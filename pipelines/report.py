"""DVC stage `report`: every dataset's evaluation + the published numbers -> reports/README.md (+ MLflow).

    python pipelines/report.py

Reads reports/eval/<ds>/results.csv, reports/plots/<ds>/*.csv and reports/animations/<ds>/index.json for
the datasets of params.yaml `evaluate` (a dataset without results is reported as not evaluated) and
reports/published_results.csv; writes reports/README.md, reports/tables/*.md, reports/figures/eval/*.png
(see motionsynth.evaluation.report). Options: conf/report/default.yaml.
"""

from pathlib import Path

import hydra
import yaml
from _common import log, one_line_errors, resolved
from omegaconf import DictConfig

from motionsynth.evaluation.report import log_report, write_report


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    root = Path(cfg.paths.root)
    datasets = list(yaml.safe_load((root / "params.yaml").read_text()).get("evaluate") or [])
    opts = resolved(cfg, "report")
    published = Path(opts["published"])
    published = published if published.is_absolute() else root / published
    experiment = f"{cfg.tracking.experiment_prefix}/{opts['mlflow_experiment']}"
    hint = (f" (`mlflow ui --backend-store-uri sqlite:///mlflow.db`, experiment `{experiment}`)"
            if cfg.tracking.enabled else "")
    res = write_report(Path(cfg.paths.reports), datasets, published, opts, profile=str(cfg.profile_name),
                       eval_opts=resolved(cfg, "eval"), mlflow_hint=hint)
    if cfg.tracking.enabled:
        log_report(root, experiment, res, {"profile": str(cfg.profile_name), "datasets": datasets,
                                           "published": str(published)})
    for r in res["claims"]:
        log.info("claim %-36s paper: %-14s ours: %s", r.claim["id"], r.verdict("paper"), r.verdict("ours"))
    log.info("report: %s; %d files in %.1f s", res["status"], len(res["files"]), res["seconds"])


if __name__ == "__main__":
    main()

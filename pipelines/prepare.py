"""DVC stage `prepare@<dataset>`: data/interim/<dataset> -> data/processed/<dataset>/<representation>/."""

import hydra
from _common import log, one_line_errors, resolved, start, track, write_json
from omegaconf import DictConfig

from motionsynth.data.prepare import prepare


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    start(cfg)
    ds = cfg.dataset
    reps = resolved(cfg, "dataset")["prepare"]["representations"]
    summary = prepare(f"{cfg.paths.interim}/{ds.name}", f"{cfg.paths.processed}/{ds.name}", reps)
    write_json(f"{cfg.paths.stage_metrics}/{ds.name}/prepare.json", summary)
    track(cfg, "prepare", {"prepare": resolved(cfg.dataset, "prepare")}, summary["representations"])
    for rep, s in summary["representations"].items():
        log.info("prepare %s/%s: %d sequences, %d frames at %g fps, clips %s", ds.name, rep,
                 s["sequences"], s["frames"], s["fps"], {k: v["windows"] for k, v in s["clips"].items()})


if __name__ == "__main__":
    main()

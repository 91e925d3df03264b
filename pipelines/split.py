"""DVC stage `split@<dataset>`: data/processed/<dataset> -> data/splits/<dataset>/<representation>/<protocol>.csv."""

import hydra
from _common import log, one_line_errors, resolved, start, track, write_json
from omegaconf import DictConfig

from motionsynth.data.splits import split_dataset


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    start(cfg)
    ds = cfg.dataset
    summary = split_dataset(f"{cfg.paths.processed}/{ds.name}", f"{cfg.paths.splits}/{ds.name}",
                            resolved(cfg.dataset, "split"), int(cfg.seed))
    write_json(f"{cfg.paths.stage_metrics}/{ds.name}/split.json", summary)
    track(cfg, "split", {"split": resolved(cfg.dataset, "split"), "seed": cfg.seed}, summary)
    for key, s in summary.items():
        log.info("split %s/%s: sequences %s", ds.name, key, s["sequences"])


if __name__ == "__main__":
    main()

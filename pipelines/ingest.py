"""DVC stage `ingest@<dataset>`: raw zip archive -> canonical store in data/interim/<dataset>/."""

import hydra
from _common import log, one_line_errors, progress, resolved, start, track, write_json
from omegaconf import DictConfig

from motionsynth.data.ingest import ingest
from motionsynth.reporting import ingest_metrics


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    start(cfg)
    ds = cfg.dataset
    out = f"{cfg.paths.interim}/{ds.name}"
    summary = ingest(resolved(cfg, "dataset"), f"{cfg.paths.raw}/{ds.archive}", out,
                     max_items=cfg.ingest.max_items, progress=progress(cfg), limits=resolved(cfg, "ingest"))
    write_json(f"{cfg.paths.stage_metrics}/{ds.name}/ingest.json", summary)
    write_json(f"{cfg.paths.reports}/metrics/data/{ds.name}.json", ingest_metrics(summary))
    track(cfg, "ingest", {"dataset": resolved(cfg, "dataset"), "ingest": resolved(cfg, "ingest")},
          {k: v for k, v in summary.items() if isinstance(v, (int, float))}, [f"{out}/rejected.csv"])
    log.info("ingest %s: %d seen = %d accepted + %d rejected + %d filtered out", ds.name, summary["seen"],
             summary["accepted"], summary["rejected"], summary["filtered"])


if __name__ == "__main__":
    main()

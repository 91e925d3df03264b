"""DVC stage `animate@<dataset>`: data/samples/<ds>.npz -> reports/animations/<ds>/seq<i>.gif + .mp4.

    python pipelines/animate.py dataset=h36m

Ground truth and every method side by side (motionsynth.viz.animation.render_comparison), one GIF and one
MP4 per sampled sequence, plus index.json (panels, frames, render times) for the report. Options:
conf/report/default.yaml `animate`.
"""

from pathlib import Path

import hydra
from _common import log, one_line_errors, resolved
from omegaconf import DictConfig

from motionsynth.viz.animation import animate_samples


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    ds = cfg.dataset.name
    samples = Path(cfg.paths.samples) / f"{ds}.npz"
    out = Path(cfg.paths.reports) / "animations" / ds
    index = animate_samples(samples, out, resolved(cfg, "report")["animate"])
    log.info("animate %s: %d sequences in %.1f s (%s)", ds, len(index["sequences"]), index["total_s"],
             ", ".join(f"seq{s['index']} {s['render_s']:.1f} s" for s in index["sequences"]))


if __name__ == "__main__":
    main()

"""DVC stage `data_report`: reports/data.md with the counts table and one PNG per dataset."""

from pathlib import Path

import hydra
from _common import log, one_line_errors
from hydra import compose
from omegaconf import DictConfig, OmegaConf

from motionsynth.reporting import data_report


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    names = list(OmegaConf.load(Path(cfg.paths.root) / "params.yaml").datasets)
    datasets = [OmegaConf.to_container(compose("config", overrides=[f"dataset={n}"]).dataset) for n in names]
    p = cfg.paths
    metrics = data_report(datasets, Path(p.stage_metrics), Path(p.interim), Path(p.reports) / "figures" / "data",
                          Path(p.reports) / "data.md", cfg.profile_name)
    for name, m in metrics.items():
        log.info("%s: %d accepted + %d rejected + %d filtered out = %d seen", name, m["accepted"], m["rejected"],
                 m["filtered"], m["seen"])


if __name__ == "__main__":
    main()

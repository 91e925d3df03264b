"""How a training job is named and where it writes: its run name, its MLflow run name and its
:class:`Job` (a DVC stage, a sweep's child or a DVC experiment). Plain data, no torch: the sweep
callbacks in the launching process (:mod:`motionsynth.sweeps`) and the trainer
(:mod:`motionsynth.training.run`) both read it, so neither imports the other."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence


@dataclass
class Job:
    """Where one training job writes, and how it appears in MLflow."""

    out_dir: Path | None = None           # None: <paths.models>/<dataset>/<run_name> (the DVC stages)
    experiment: str | None = None         # None: <tracking.experiment_prefix>/<dataset>
    overrides: list[str] = field(default_factory=list)   # the job's key overrides (tag, checkpoint folder)
    parent_run_id: str | None = None
    sweep: bool = False
    swept: list[str] = field(default_factory=list)       # the sweep's varying keys: they alone name a child run

    @property
    def name_overrides(self) -> list[str]:
        return [o for o in self.overrides if o.split("=", 1)[0] in self.swept] if self.swept else self.overrides


def mlflow_run_name(model_run: str, dataset: str, overrides: Sequence[str] = ()) -> str:
    """``train:glogen@h36m train.lr=0.002``: model (run), dataset and the key overrides."""
    return " ".join([f"train:{model_run}@{dataset}", *overrides])


def run_name(cfg: dict[str, Any]) -> str:
    """``run_name``, else ``<model>`` or ``<model>-<variant_name>``: names the run's folder under
    ``models/<dataset>/``, its metrics file and its MLflow run."""
    if cfg.get("run_name"):
        return str(cfg["run_name"])
    variant = cfg.get("variant_name")
    return cfg["model"]["name"] + (f"-{variant}" if variant else "")

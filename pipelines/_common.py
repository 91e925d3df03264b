"""Shared wiring for the thin Hydra entry points (logging, paths, tracking, metrics files)."""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))  # runnable without install

from motionsynth import tracking  # noqa: E402

log = logging.getLogger("motionsynth")


def progress(cfg: DictConfig) -> bool:
    """Progress bars on an interactive terminal only (not in CI logs); PROGRESS=0 turns them off."""
    return bool(cfg.progress) and os.environ.get("PROGRESS", "1") != "0" and sys.stderr.isatty()


def write_json(path: str | Path, obj: Any) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=1, default=str) + "\n")


_recorder: tracking.StageRecorder | None = None


def start(cfg: DictConfig) -> None:
    """Call first in every data stage: starts the MLflow recorder on the other core."""
    global _recorder
    if cfg.tracking.enabled:
        _recorder = tracking.StageRecorder(cfg.paths.root, f"{cfg.tracking.experiment_prefix}/{cfg.dataset.name}")


def track(cfg: DictConfig, stage: str, params: dict, metrics: dict, artifacts: list = ()) -> None:
    """Log this stage's run to MLflow: params, numeric metrics and artifacts."""
    if not cfg.tracking.enabled:
        return
    rec = _recorder or tracking.StageRecorder(cfg.paths.root, f"{cfg.tracking.experiment_prefix}/{cfg.dataset.name}")
    ds = cfg.dataset.name
    rec.submit(f"{stage}:{ds}", params, metrics,
               {"stage": stage, "dataset": ds, "profile": str(cfg.profile_name)}, list(artifacts))


def resolved(cfg: DictConfig, key: str) -> dict:
    return OmegaConf.to_container(cfg[key], resolve=True)  # type: ignore[return-value]

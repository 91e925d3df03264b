"""Crash-safe checkpoints.

* Writes are atomic: the state goes to a temporary file in the same directory,
  is flushed and fsync'ed, then renamed over the target (``os.replace``), so a
  ``kill -9`` at any moment leaves either the old or the new checkpoint, never
  a torn one.
* Loading uses ``torch.load(..., weights_only=True)``: a checkpoint holds only
  tensors and plain containers, never pickled objects.
* A checkpoint records the fingerprint of the resolved config it was trained
  with; resuming under a different config is refused (the run starts afresh).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import torch


def fingerprint(cfg: Any) -> str:
    """A stable hash of a JSON-serialisable config."""
    return hashlib.sha256(json.dumps(cfg, sort_keys=True, default=str).encode()).hexdigest()[:16]


def save_atomic(state: dict[str, Any], path: str | Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(state, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    return torch.load(path, map_location=map_location, weights_only=True)

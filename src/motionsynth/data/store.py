"""The canonical on-disk format: one ragged store per dataset.

A store directory holds all sequences of a dataset concatenated along time, so
a stage reads (or memory-maps) a handful of files instead of thousands:

* ``positions.npy``  float32 ``[N, J, 3]`` metres (``N`` = total frames);
* ``views2d.npy``    float32 ``[N, V, J, 2]`` 2-D views, when the source has them;
* ``view_depth.npy`` float32 ``[N, V]`` camera-space depth of the root, with views2d;
* ``body_mask.npy``  bool ``[N, P]`` for multi-person sources;
* ``meta.parquet``   one row per sequence: ``sequence_id``, ``offset``, ``frames``, ``fps``, labels...;
* ``skeleton.json``, ``extras.json``.

``offset``/``frames`` index a sequence's rows: ``positions[offset:offset+frames]``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .types import Sequence, Skeleton

ARRAYS = ("positions", "views2d", "view_depth", "body_mask")


def write_store(out: str | Path, sequences: list[Sequence], skeleton: Skeleton,
                extras: dict[str, Any] | None = None) -> pd.DataFrame:
    """Write ``sequences`` to the store at ``out``; return the meta table."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    frames = np.array([s.num_frames for s in sequences], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(frames)[:-1]]).astype(np.int64) if len(frames) else frames
    rows = [dict(s.meta, frames=int(f), offset=int(o), fps=float(s.fps))
            for s, f, o in zip(sequences, frames, offsets)]
    meta = pd.DataFrame(rows)
    for name in ARRAYS:
        parts = [getattr(s, name, None) for s in sequences]
        present = [p is not None for p in parts]
        if not any(present):
            continue
        if not all(present):
            missing = [s.meta.get("sequence_id") for s, p in zip(sequences, present) if not p][:3]
            raise ValueError(f"{name} present for some sequences but not for {missing}")
        np.save(out / f"{name}.npy", np.concatenate(parts, axis=0))
    meta.to_parquet(out / "meta.parquet", index=False)
    skeleton.save(out / "skeleton.json")
    (out / "extras.json").write_text(json.dumps(extras or {}, indent=1, default=_jsonable))
    return meta


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer, np.floating)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o)}")


@dataclass
class Store:
    """A read-only view of a store directory; arrays are memory-mapped."""

    root: Path
    meta: pd.DataFrame
    skeleton: Skeleton
    extras: dict[str, Any]

    @classmethod
    def open(cls, root: str | Path) -> "Store":
        root = Path(root)
        if not (root / "meta.parquet").exists():
            raise FileNotFoundError(f"{root}: not a motionsynth store (meta.parquet missing)")
        return cls(root, pd.read_parquet(root / "meta.parquet"), Skeleton.load(root / "skeleton.json"),
                   json.loads((root / "extras.json").read_text()) if (root / "extras.json").exists() else {})

    def array(self, name: str) -> np.ndarray | None:
        p = self.root / f"{name}.npy"
        return np.load(p, mmap_mode="r") if p.exists() else None

    def __len__(self) -> int:
        return len(self.meta)

    def sequence(self, i: int) -> Sequence:
        """Sequence ``i`` as a :class:`Sequence` (arrays copied out of the memory map)."""
        row = self.meta.iloc[i]
        sl = slice(int(row["offset"]), int(row["offset"] + row["frames"]))
        arrs = {n: (np.array(a[sl]) if (a := self.array(n)) is not None else None) for n in ARRAYS}
        seq = Sequence(arrs["positions"], float(row["fps"]), row.to_dict(),
                       views2d=arrs["views2d"], body_mask=arrs["body_mask"])
        seq.view_depth = arrs["view_depth"]  # type: ignore[attr-defined]
        return seq

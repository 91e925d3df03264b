"""The canonical on-disk format: one ragged store per dataset.

A store directory holds all sequences of a dataset concatenated along time, so
a stage reads (or memory-maps) a handful of files instead of thousands:

* ``positions.npy``  float32 ``[N, J, 3]`` metres (``N`` = total frames);
* ``views2d.npy``    float32 ``[N, V, J, 2]`` 2-D views, when the source has them;
* ``view_depth.npy`` float32 ``[N, V]`` camera-space depth of the root, with views2d;
* ``body_mask.npy``  bool ``[N, P]`` for multi-person sources;
* ``meta.parquet``   one row per sequence: ``sequence_id``, ``offset``, ``frames``, ``fps``, labels...;
* ``skeleton.json``, ``extras.json``.

* ``classes.json``: the class table, one entry per contiguous ``label``: ``raw`` id in the
  source and ``name`` (``[]`` when the source has no classes);
* tables such as ``rejected.csv`` / ``filtered.csv`` written beside them by ingest.

``offset``/``frames`` index a sequence's rows: ``positions[offset:offset+frames]``.

A store is written atomically (:func:`atomic_dir`): into a hidden sibling folder that is renamed
into place once complete, so a writer killed part-way leaves the previous store, or none, and
never a partial one that a later stage would read as valid.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas as pd

from .types import MissingDataError, Sequence, Skeleton

ARRAYS = ("positions", "views2d", "view_depth", "body_mask")
_TMP, _OLD = ".tmp-", ".old-"   # hidden siblings: .<name>.tmp-<pid>-<random>, .<name>.old-<pid>-<random>


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def _remove_stale(out: Path) -> None:
    """Delete the leftovers of writers of ``out`` that were killed (their process is gone)."""
    for p in out.parent.glob(f".{out.name}.*-*"):
        tag = p.name[len(out.name) + 1:]
        for kind in (_TMP, _OLD):
            if tag.startswith(kind):
                pid = tag[len(kind):].split("-", 1)[0]
                if pid.isdigit() and not _pid_alive(int(pid)):
                    shutil.rmtree(p, ignore_errors=True)


def _sibling(out: Path, kind: str) -> Path:
    """A new empty hidden folder beside ``out`` (default permissions, unlike ``mkdtemp``'s 0700)."""
    p = out.parent / f".{out.name}{kind}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    p.mkdir()
    return p


@contextlib.contextmanager
def atomic_dir(out: str | Path) -> Iterator[Path]:
    """Yield an empty hidden sibling folder of ``out``; when the block ends normally, it replaces
    ``out`` (the old one is renamed aside, the new one renamed in, the old one deleted). When the
    block fails, the folder is deleted and ``out`` is left as it was."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(out)
    tmp = _sibling(out, _TMP)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if out.exists():
        old = _sibling(out, _OLD)
        os.replace(out, old / out.name)        # out is gone from here ...
    os.replace(tmp, out)                        # ... to here: a kill in between leaves no store, never a partial one
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_store(out: str | Path, sequences: list[Sequence], skeleton: Skeleton,
                extras: dict[str, Any] | None = None, classes: list[dict[str, Any]] | None = None,
                tables: dict[str, pd.DataFrame] | None = None) -> pd.DataFrame:
    """Write ``sequences`` (and ``tables``: file name -> CSV) to the store at ``out``, atomically
    (:func:`atomic_dir`); return the meta table."""
    with atomic_dir(out) as tmp:
        meta = _write(tmp, sequences, skeleton, extras, classes)
        for name, df in (tables or {}).items():
            df.to_csv(tmp / name, index=False)
    return meta


def _write(out: Path, sequences: list[Sequence], skeleton: Skeleton, extras: dict[str, Any] | None,
           classes: list[dict[str, Any]] | None) -> pd.DataFrame:
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
    (out / "classes.json").write_text(json.dumps(list(classes or []), indent=1, default=_jsonable))
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
            raise MissingDataError(f"{root}: no store there (meta.parquet missing): "
                                   f"`dvc repro ingest@{root.name}` makes it")
        return cls(root, pd.read_parquet(root / "meta.parquet"), Skeleton.load(root / "skeleton.json"),
                   json.loads((root / "extras.json").read_text()) if (root / "extras.json").exists() else {})

    @property
    def classes(self) -> list[dict[str, Any]] | None:
        """The class table (``classes.json``), or ``None`` for a store written before it existed."""
        p = self.root / "classes.json"
        return json.loads(p.read_text()) if p.exists() else None

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

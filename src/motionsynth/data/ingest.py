"""Stage ``ingest``: one archive -> one canonical store, with full accounting.

Every candidate item the reader lists, and every hostile archive member, is
*seen*; each seen item ends up either *accepted* (written to the store) or
*rejected* (with its reason). ``accepted + rejected == seen`` is asserted.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from .archive import Archive
from .readers import DatasetReader
from .store import write_store
from .types import InputError, Rejected, Sequence, Skeleton

log = logging.getLogger(__name__)


def build_reader(reader_cfg: Mapping[str, Any]) -> DatasetReader:
    """Instantiate the reader named by ``reader_cfg['_target_']``."""
    from hydra.utils import instantiate

    reader = instantiate(dict(reader_cfg), _convert_="all")
    if not isinstance(reader, DatasetReader):
        raise TypeError(f"{reader_cfg.get('_target_')} is not a DatasetReader")
    return reader


def annotate_skeleton(skel: Skeleton, ann: Mapping[str, Any] | None) -> Skeleton:
    """Apply the dataset config's ``skeleton:`` annotations (root, hips, shoulders, feet).

    An annotation naming a joint the skeleton lacks is a config error."""
    ann = dict(ann or {})
    names = set(skel.names)
    for key in ("root",):
        if ann.get(key) is not None:
            if ann[key] not in names:
                raise KeyError(f"skeleton.{key}: unknown joint {ann[key]!r}")
            setattr(skel, key, ann[key])
    for key in ("hips", "shoulders"):
        if ann.get(key) is not None:
            pair = tuple(ann[key])
            bad = [j for j in pair if j not in names]
            if len(pair) != 2 or bad:
                raise KeyError(f"skeleton.{key}: needs two known joints, unknown {bad}")
            setattr(skel, key, pair)
    if ann.get("feet") is not None:
        bad = [j for j in ann["feet"] if j not in names]
        if bad:
            raise KeyError(f"skeleton.feet: unknown joints {bad}")
        skel.feet = list(ann["feet"])
    if skel.root is None:
        skel.root = skel.names[0]
    return skel


def ingest(dataset: Mapping[str, Any], archive_path: str | Path, out_dir: str | Path,
           max_items: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Read ``archive_path`` with the dataset's reader and write the store to ``out_dir``.

    Returns a summary with the accounting (``seen``, ``accepted``, ``rejected``),
    the rejected list, dataset statistics and notes. ``max_items`` limits the
    items read (the ``smoke`` profile); the limit is reported, never silent.
    """
    t0 = time.perf_counter()
    name = dataset["name"]
    reader = build_reader(dataset["reader"])
    out_dir = Path(out_dir)
    rejected: list[Rejected] = []
    sequences: list[Sequence] = []
    with Archive(archive_path) as ar:
        items, pre_rejected = reader.list_items(ar)
        listed = len(items) + len(pre_rejected) + len(ar.unsafe)
        if max_items is not None and len(items) > max_items:
            items = _spread(items, max_items)
        rejected += ar.unsafe + pre_rejected
        template = reader.template_skeleton(ar) if hasattr(reader, "template_skeleton") else None
        skeleton: Skeleton | None = template
        for item in tqdm(items, desc=f"ingest {name}", disable=not progress, unit="seq", leave=False):
            try:
                seq, skel = reader.read(ar, item)
                if skeleton is None:
                    skeleton = skel
                elif skel.names != skeleton.names:
                    raise InputError(item.member, _joint_mismatch(skel.names, skeleton.names))
            except InputError as e:
                log.warning("rejected %s", e)
                rejected.append(Rejected.from_error(e))
                continue
            seq.meta = {"sequence_id": item.key, "dataset": name, **seq.meta}
            sequences.append(seq)
        notes = reader.notes(ar)
        extras = reader.extras(ar)
        seen = len(items) + len(pre_rejected) + len(ar.unsafe)

    if skeleton is None:
        raise RuntimeError(f"{name}: no sequence could be read from {archive_path}; "
                           f"{len(rejected)} rejected, first: {rejected[:1]}")
    skeleton = annotate_skeleton(skeleton, dataset.get("skeleton"))
    sequences.sort(key=lambda s: s.meta["sequence_id"])
    meta = write_store(out_dir, sequences, skeleton, extras)
    rej = pd.DataFrame([r.__dict__ for r in rejected], columns=["member", "reason"])
    rej.to_csv(out_dir / "rejected.csv", index=False)
    accepted = len(sequences)
    assert accepted + len(rejected) == seen, f"{name}: accounting broken: {accepted}+{len(rejected)}!={seen}"

    summary = {
        "dataset": name,
        "seen": seen,
        "accepted": accepted,
        "rejected": len(rejected),
        "listed_in_archive": listed,
        "limited_to": max_items if listed > seen else None,
        "frames": int(meta["frames"].sum()),
        "hours": float((meta["frames"] / meta["fps"]).sum() / 3600.0),
        "fps": _fps_summary(meta),
        "joints": skeleton.num_joints,
        "classes": _nunique(meta, "label"),
        "subjects": _nunique(meta, "subject"),
        "views": int(np.load(out_dir / "views2d.npy", mmap_mode="r").shape[1]) if (out_dir / "views2d.npy").exists() else 0,
        "multi_body_sequences": int((meta["bodies"] > 1).sum()) if "bodies" in meta else 0,
        "rejected_items": [r.__dict__ for r in rejected],
        "notes": notes,
        "seconds": round(time.perf_counter() - t0, 3),
    }
    log.info("%s: seen %d, accepted %d, rejected %d, %d frames (%.2f h) in %.1fs", name, seen, accepted,
             len(rejected), summary["frames"], summary["hours"], summary["seconds"])
    return summary


def _spread(items: list, k: int) -> list:
    """``k`` items spread evenly over the sorted list (so a smoke run sees every class)."""
    idx = np.unique(np.linspace(0, len(items) - 1, k).round().astype(int))
    return [items[i] for i in idx]


def _joint_mismatch(got: list[str], want: list[str]) -> str:
    unknown = [j for j in got if j not in want]
    missing = [j for j in want if j not in got]
    if unknown or missing:
        return f"skeleton differs from the dataset's: unknown joints {unknown[:5]}, missing joints {missing[:5]}"
    return "skeleton differs from the dataset's: same joints in a different order"


def _nunique(meta: pd.DataFrame, col: str) -> int:
    if col not in meta:
        return 0
    s = meta[col].dropna()
    s = s[s.astype(str) != ""]
    return int(s.nunique())


def _fps_summary(meta: pd.DataFrame) -> float:
    vals = meta["fps"].round(3).unique()
    return float(vals[0]) if len(vals) == 1 else float(meta["fps"].mode().iloc[0])

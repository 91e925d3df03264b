"""Stage ``ingest``: one archive -> one canonical store, with full accounting.

Every candidate item the reader lists, every hostile archive member, and every member of the
reader's format that the config leaves out is *seen*; each seen item ends up *accepted*
(written to the store), *rejected* (with its reason) or *filtered out* (with the setting that
left it out, :meth:`DatasetReader.why_filtered`). ``accepted + rejected + filtered == seen`` is
asserted. A profile's item limit (``ingest.max_items``) is reported, never silent.

Classes: the raw class ids of the dataset's items (every listed item, before the item limit:
:meth:`DatasetReader.class_names`) are sorted and mapped to the contiguous labels ``0..C-1``; the
store's ``label`` is contiguous, ``label_raw`` keeps the source's id and ``classes.json`` the table,
so the class count and names come from the data, never from a copied config.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from .archive import Archive
from .readers import DatasetReader
from .store import write_store
from .types import InputError, Item, Rejected, Sequence, Skeleton

log = logging.getLogger(__name__)
MB = 2**20


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
           max_items: int | None = None, progress: bool = True,
           limits: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Read ``archive_path`` with the dataset's reader and write the store to ``out_dir``.

    Returns a summary with the accounting (``seen``, ``accepted``, ``rejected``, ``filtered``),
    the rejected list, the filter reasons, the class table, dataset statistics and notes.
    ``max_items`` limits the items read (the ``smoke`` profile). ``limits``: the archive-member
    caps ``max_member_mb`` and ``max_compression_ratio`` (``conf/config.yaml: ingest``); a member
    over either is rejected unread.
    """
    t0 = time.perf_counter()
    name = dataset["name"]
    reader = build_reader(dataset["reader"])
    limits = dict(limits or {})
    out_dir = Path(out_dir)
    rejected: list[Rejected] = []
    sequences: list[Sequence] = []
    max_mb, max_ratio = limits.get("max_member_mb"), limits.get("max_compression_ratio")
    with Archive(archive_path, None if max_mb is None else int(float(max_mb) * MB),
                 None if max_ratio is None else float(max_ratio)) as ar:
        items, pre_rejected = reader.list_items(ar)
        filtered = filtered_members(reader, ar, items, pre_rejected)
        classes = class_table(reader.class_names(ar, items))
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
                _relabel(seq, classes, item)
            except InputError as e:
                log.warning("rejected %s", e)
                rejected.append(Rejected.from_error(e))
                continue
            seq.meta = {"sequence_id": item.key, "dataset": name, **seq.meta}
            sequences.append(seq)
        notes = reader.notes(ar)
        extras = reader.extras(ar)
        seen = len(items) + len(pre_rejected) + len(ar.unsafe) + len(filtered)

    why_filtered = dict(Counter(f.reason for f in filtered).most_common())
    if skeleton is None:
        raise InputError(str(archive_path), f"no sequence of dataset {name!r} could be read: {seen} seen, "
                                            f"{len(rejected)} rejected, {len(filtered)} filtered out"
                         + (f" (first rejected: {rejected[0].member}: {rejected[0].reason})" if rejected else "")
                         + (f" (filtered: {_reasons(why_filtered)})" if filtered else ""))
    skeleton = annotate_skeleton(skeleton, dataset.get("skeleton"))
    sequences.sort(key=lambda s: s.meta["sequence_id"])
    table = lambda rs: pd.DataFrame([r.__dict__ for r in rs], columns=["member", "reason"])  # noqa: E731
    meta = write_store(out_dir, sequences, skeleton, extras, classes,
                       {"rejected.csv": table(rejected), "filtered.csv": table(filtered)})
    accepted = len(sequences)
    assert accepted + len(rejected) + len(filtered) == seen, \
        f"{name}: accounting broken: {accepted} + {len(rejected)} + {len(filtered)} != {seen}"

    summary = {
        "dataset": name,
        "seen": seen,
        "accepted": accepted,
        "rejected": len(rejected),
        "filtered": len(filtered),
        "listed_in_archive": listed,
        "limited_to": max_items if listed > seen - len(filtered) else None,
        "frames": int(meta["frames"].sum()),
        "hours": float((meta["frames"] / meta["fps"]).sum() / 3600.0),
        "fps": _fps_summary(meta),
        "joints": skeleton.num_joints,
        "classes": _nunique(meta, "label"),
        "class_table": classes,
        "subjects": _nunique(meta, "subject"),
        "views": int(np.load(out_dir / "views2d.npy", mmap_mode="r").shape[1]) if (out_dir / "views2d.npy").exists() else 0,
        "multi_body_sequences": int((meta["bodies"] > 1).sum()) if "bodies" in meta else 0,
        "rejected_items": [r.__dict__ for r in rejected],
        "filtered_reasons": why_filtered,
        "notes": notes,
        "seconds": round(time.perf_counter() - t0, 3),
    }
    log.info("%s: seen %d = accepted %d + rejected %d + filtered out %d, %d frames (%.2f h) in %.1fs", name, seen,
             accepted, len(rejected), len(filtered), summary["frames"], summary["hours"], summary["seconds"])
    return summary


def filtered_members(reader: DatasetReader, ar: Archive, items: list[Item], rejected: list[Rejected]) -> list[Rejected]:
    """Members of the reader's format that are no listed item's, no rejection's and no auxiliary
    member: what the config's filters left out, each with its reason."""
    if reader.format_pattern is None:
        return []
    used = {m for it in items for m in it.members.values()} | {r.member for r in rejected}
    used |= reader.auxiliary_members()
    return [Rejected(m, reader.why_filtered(m)) for m in ar.glob(reader.format_pattern) if m not in used]


def class_table(names: Mapping[int, str]) -> list[dict[str, Any]]:
    """The contiguous class table of raw class ids (sorted): ``[{label, raw, name}, ...]``."""
    return [{"label": i, "raw": int(raw), "name": str(names[raw])} for i, raw in enumerate(sorted(names))]


def _relabel(seq: Sequence, classes: list[dict[str, Any]], item: Item) -> None:
    """``label`` -> the contiguous label, ``label_raw`` keeps the source's id."""
    if seq.meta.get("label") is None:
        return
    raw = int(seq.meta["label"])
    index = {c["raw"]: c for c in classes}
    if raw not in index:
        raise InputError(item.member, f"class id {raw} is none of the dataset's classes {sorted(index)}")
    seq.meta["label_raw"], seq.meta["label"] = raw, index[raw]["label"]
    seq.meta.setdefault("label_name", index[raw]["name"])


def _reasons(counts: Mapping[str, int]) -> str:
    return "; ".join(f"{n} {why}" for why, n in counts.items())


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

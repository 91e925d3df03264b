"""Stage ``split``: named protocols -> per-sequence split tables, plus train-only statistics.

A protocol (``split.protocols.<name>`` in the dataset config) is one of

* ``by: <meta column>`` with ``train``/``test`` value lists (or ``rest``), for
  cross-subject and cross-view protocols. Values match on the column's trailing
  number when both have one (``S11`` == 11, ``P008`` == 8, ``C001`` == 1), else on
  the string; a sequence matching neither list is ``unused`` (e.g. S6 in the
  c-SkeletonGAN protocol);
* ``by: sequence`` with ``stratify: label`` and ``test_fraction``: a seeded
  per-file split, stratified by class.

Either kind may restrict itself with ``keep: {<meta column>: [values]}`` (matched like the
lists above): the other sequences are ``unused`` (e.g. the ``csgan`` protocol keeps camera
``55011271`` alone, as the c-SkeletonGAN / SA-GCN reference does). The table of a protocol that
leaves sequences unused has a ``reason`` column saying why (empty for the others), and the stage's
summary counts the sequences per reason. (Tables without unused sequences keep their three columns
and the statistics files of ``stats_over: [train]`` their keys: other datasets' outputs stay byte
for byte what they were, so DVC does not retrain on them.)

Validation sequences are carved from train (``val_fraction``, seeded,
stratified). Every draw is grouped by ``source_id``, so all windows, all
camera views and all phases of one source take stay in one split.

Normalisation statistics (``<protocol>_stats.npz``) come from the train split, or from the splits
the protocol names in ``stats_over`` (``csgan``: ``[train, val]``, every training subject, as the
reference computes them; the validation carve-out still only selects checkpoints). Never from test
or unused sequences. They are over every stored frame of those sequences: for a representation
prepared with ``all_phases`` (``bench2d``) that is every source frame (50 Hz), which is what the
reference averages over.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from .normalise import depth_scaled
from .types import ConfigError, MissingDataError

SPLITS = ("train", "val", "test", "unused")


def _key(v: Any) -> Any:
    m = re.search(r"(\d+)$", str(v))
    return int(m.group(1)) if m else str(v)


def _column(meta: pd.DataFrame, column: str) -> pd.Series:
    if column not in meta:
        raise KeyError(f"split protocol: unknown meta column {column!r}; have {list(meta.columns)}")
    return meta[column].map(_key)


def protocol_table(meta: pd.DataFrame, protocol: Mapping[str, Any], val_fraction: float, seed: int) -> pd.DataFrame:
    """``split`` (``train``/``val``/``test``/``unused``) and ``reason`` (why a row is ``unused``;
    ``""`` otherwise) per row of ``meta``."""
    by = protocol.get("by", "sequence")
    rng = np.random.default_rng(seed)
    reason = pd.Series("", index=meta.index, dtype=object)
    if by == "sequence":
        split = _stratified(meta, "test", float(protocol.get("test_fraction", 0.2)),
                            protocol.get("stratify"), rng, pd.Series("train", index=meta.index))
    else:
        keys = _column(meta, by)
        train, test = protocol.get("train"), protocol.get("test")
        if train == "rest" and test == "rest":
            raise ValueError("split protocol: train and test cannot both be 'rest'")
        in_train = keys.isin([_key(v) for v in train]) if train != "rest" else None
        in_test = keys.isin([_key(v) for v in test]) if test != "rest" else None
        if in_train is None:
            in_train = ~in_test
        if in_test is None:
            in_test = ~in_train
        if (in_train & in_test).any():
            raise ValueError(f"split protocol: values in both train and test: {sorted(set(meta[by][in_train & in_test]))}")
        split = pd.Series(np.where(in_train, "train", np.where(in_test, "test", "unused")), index=meta.index)
        neither = split == "unused"
        reason[neither] = by + " " + meta.loc[neither, by].astype(str) + " is in neither train nor test"
    for column, values in (protocol.get("keep") or {}).items():
        out = ~_column(meta, column).isin([_key(v) for v in values]) & (split != "unused")
        split[out] = "unused"
        reason[out] = (column + " " + meta.loc[out, column].astype(str)
                       + f" is not in keep.{column} ({', '.join(map(str, values))})")
    # validation carved out of train, grouped by source, stratified like the protocol
    strat = protocol.get("stratify", "label" if "label" in meta else None)
    split = _stratified(meta, "val", val_fraction, strat, rng, split, among="train")
    return pd.DataFrame({"split": split, "reason": reason})


def assign(meta: pd.DataFrame, protocol: Mapping[str, Any], val_fraction: float, seed: int) -> pd.Series:
    """Split label per row of ``meta`` (``train``/``val``/``test``/``unused``): :func:`protocol_table`'s."""
    return protocol_table(meta, protocol, val_fraction, seed)["split"]


def _stratified(meta: pd.DataFrame, target: str, fraction: float, stratify: str | None,
                rng: np.random.Generator, split: pd.Series, among: str = "train") -> pd.Series:
    """Move ``fraction`` of the ``among`` sources (grouped by ``source_id``) to ``target``, per stratum."""
    split = split.copy()
    if fraction <= 0:
        return split
    pool = meta[split == among]
    groups = pool.groupby("source_id", sort=True).first()
    strata = groups[stratify] if stratify and stratify in groups else pd.Series(0, index=groups.index)
    chosen: list[str] = []
    for _, members in sorted(strata.groupby(strata).groups.items(), key=lambda kv: str(kv[0])):
        ids = np.array(sorted(members))
        n = int(round(fraction * len(ids)))
        if len(ids) >= 2:
            n = min(max(n, 1), len(ids) - 1)  # every class present on both sides where possible
        else:
            n = 0
        chosen += rng.permutation(ids)[:n].tolist()
    split[meta["source_id"].isin(chosen) & (split == among)] = target
    return split


def train_stats(rep_dir: Path, meta: pd.DataFrame, split: pd.Series, depth_scale: bool = False,
                over: Sequence[str] = ("train",)) -> dict[str, np.ndarray]:
    """Mean/std of pose (per joint and dimension), root and controls over every frame of the
    sequences whose split is in ``over`` (default: the train split only; never test or unused).

    The c-SkeletonGAN / SA-GCN steps (``create_2d_data_corrected``): with ``depth_scale`` (2-D),
    ``mean_depth`` (their ``avg_z``) is the centre joint's mean camera depth over those frames,
    and the pose statistics are those of the depth-scaled poses (see :mod:`.normalise`): the plain
    mean and the population std (``ddof=0``, ``np.std``'s default) per dimension, in float64,
    stored as float32 (std floored at 1e-6). ``train_frames`` counts the train split's frames; with
    ``over`` other than the train split alone, ``stats_over`` names the splits and ``stats_frames``
    counts the frames the statistics are over.
    """
    rows = meta[split.isin(list(over)).to_numpy()]
    if len(rows) == 0:
        raise ValueError(f"{rep_dir}: no {'/'.join(over)} sequences for the statistics")
    idx = np.concatenate([np.arange(o, o + f) for o, f in zip(rows["offset"], rows["frames"])])
    arrays = {n: np.asarray(np.load(rep_dir / f"{n}.npy", mmap_mode="r")[idx], dtype=np.float64)
              for n in ("pose", "root", "controls") if (rep_dir / f"{n}.npy").exists()}
    out: dict[str, np.ndarray] = {"train_frames": np.int64(meta["frames"][split.to_numpy() == "train"].sum())}
    if list(over) != ["train"]:
        out |= {"stats_over": np.array(list(over)), "stats_frames": np.int64(len(idx))}
    if depth_scale:
        out["mean_depth"] = np.float64(arrays["root"][:, 2].mean())
        arrays["pose"] = depth_scaled(arrays["pose"], arrays["root"][:, 2], float(out["mean_depth"]))
    for name, x in arrays.items():
        out[f"{name}_mean"] = x.mean(0).astype(np.float32)
        out[f"{name}_std"] = np.maximum(x.std(0), 1e-6).astype(np.float32)
    return out


def check_no_leak(table: pd.DataFrame, windows: pd.DataFrame | None = None) -> None:
    """Assert every source take and every window belongs to exactly one split."""
    per_seq = table.groupby("sequence_id")["split"].nunique()
    if (per_seq > 1).any():
        raise AssertionError(f"sequences in several splits: {per_seq[per_seq > 1].index[:5].tolist()}")
    used = table[table["split"] != "unused"]
    per_src = used.groupby("source_id")["split"].nunique()
    if table.attrs.get("grouped_by_source", True) and (per_src > 1).any():
        raise AssertionError(f"source takes across splits: {per_src[per_src > 1].index[:5].tolist()}")
    if windows is not None and len(windows):
        s = table.set_index("sequence_id")["split"]
        if windows["sequence_id"].map(s).isna().any():
            raise AssertionError("windows whose sequence has no split")


def split_dataset(processed: str | Path, out: str | Path, cfg: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """Write ``out/<rep>/<protocol>.csv`` and ``<protocol>_stats.npz`` for every representation."""
    processed, out = Path(processed), Path(out)
    summary: dict[str, Any] = {}
    reps = sorted(p.parent for p in processed.glob("*/meta.parquet"))
    if not reps:
        raise MissingDataError(f"{processed}: no prepared representation there: "
                               f"`dvc repro prepare@{processed.name}` makes it")
    for rep_dir in reps:
        meta = pd.read_parquet(rep_dir / "meta.parquet")
        wins = {p.stem.removeprefix("windows_"): pd.read_parquet(p) for p in sorted(rep_dir.glob("windows_*.parquet"))}
        rep_out = out / rep_dir.name
        rep_out.mkdir(parents=True, exist_ok=True)
        rep_cfg = json.loads((rep_dir / "representation.json").read_text())
        for name, protocol in cfg["protocols"].items():
            protocol = dict(protocol)
            if protocol.get("space") and protocol["space"] != rep_cfg["space"]:
                continue  # e.g. a view protocol that only applies to 2-D projections
            over = list(protocol.get("stats_over", ["train"]))
            if not over or set(over) - {"train", "val"}:
                raise ConfigError(f"conf/dataset/{processed.name}.yaml: split.protocols.{name}.stats_over must name "
                                  f"train and/or val (statistics never see test or unused sequences), got {over}")
            assigned = protocol_table(meta, protocol, float(cfg.get("val_fraction", 0.1)), seed)
            split = assigned["split"]
            table = pd.DataFrame({"sequence_id": meta["sequence_id"], "source_id": meta["source_id"],
                                  "split": split.to_numpy()})
            if (split == "unused").any():
                table["reason"] = assigned["reason"].to_numpy()
            # view protocols legitimately put views of one take on both sides
            table.attrs["grouped_by_source"] = protocol.get("by") not in ("view",)
            for w in wins.values():
                check_no_leak(table, w)
            table.to_csv(rep_out / f"{name}.csv", index=False)
            stats = train_stats(rep_dir, meta, split, bool(rep_cfg.get("depth_scale", False)), over)
            np.savez(rep_out / f"{name}_stats.npz", **stats)
            s = table["split"]
            summary[f"{rep_dir.name}/{name}"] = {
                "sequences": {k: int((s == k).sum()) for k in SPLITS},
                "frames": {k: int(meta["frames"][s == k].sum()) for k in SPLITS},
                "windows": {fam: {k: int(w["seq"].map(s).eq(k).sum()) for k in SPLITS} for fam, w in wins.items()},
                "unused_reasons": {str(r): int(n) for r, n in assigned["reason"][s.to_numpy() == "unused"].value_counts(
                    sort=False).sort_index().items()},
                "stats_over": over, "stats_frames": int(stats.get("stats_frames", stats["train_frames"])),
            }
    return summary

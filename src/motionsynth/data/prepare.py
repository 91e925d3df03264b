"""Stage ``prepare``: canonical store -> model-ready frames and clip windows.

For each *representation* named in the dataset config (``prepare.representations``):

* ``space: 3d``: joints selected, resampled to ``fps``, split into a
  root-relative, facing-normalised ``pose`` ``[N, J, 3]``, a ``root`` trajectory
  ``[N, 3]`` = (x, z, heading) and ``controls`` ``[N, 3]`` (see :mod:`.controls`).
* ``space: 2d``: every camera view becomes its own sequence; joints are centred
  on ``center`` (then selected), resampled; ``pose`` ``[N, J, 2]`` and
  ``root`` ``[N, 3]`` = (u, v, camera depth of the centre joint). Depth scaling
  and mean/std normalisation use train-split statistics, so they happen in
  ``split``/training, never here.

  ``all_phases: true`` (2-D, an integer down-sampling ratio ``k``, e.g. 50 Hz -> 16.7 Hz,
  ``k = 3``) keeps every frame: each view of a source sequence becomes ``k`` sequences, phase
  ``p = 0 .. k-1`` holding the source frames ``p, p + k, p + 2k, ...``, with sequence id
  ``<source>@<view>+<p>`` and a ``phase`` column ``p`` in ``meta.parquet`` (only there: other
  representations' tables keep their columns, byte for byte). Why store the phases rather than the source rate or the first phase alone: the
  Human3.6M 2-D benchmark (c-SkeletonGAN / SA-GCN / GlocalNet, ``split``'s ``csgan`` protocol)
  takes its normalisation statistics over *every* 50 Hz frame and draws its clips (every 3rd
  frame) at *any* start frame, so at any phase. With the phases stored, ``split`` gets every
  50 Hz frame from the representation itself (the frames of a take's phase sequences are
  exactly its source frames), the evaluation cuts a clip of any start frame ``t`` as a dense run
  of phase ``t mod k`` from pose ``t // k``, and training and windows stay dense at the
  benchmark rate (``every`` keeps meaning key poses, as GloGen / LocGen read it). The phases of
  one take share its ``source_id``, so a split never separates them.

Clip windows for each model family (``clips:``) are written as index tables
(:mod:`.clips`). No statistic over all data is computed here.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from .clips import resample, windows
from .controls import root_and_controls
from .store import Store
from .types import ConfigError, Skeleton

log = logging.getLogger(__name__)

META_COLS = ["sequence_id", "source_id", "dataset", "member", "subject", "view", "label",
             "label_raw", "label_name", "style", "frames", "offset", "fps"]


def prepare(store_dir: str | Path, out_dir: str | Path, representations: Mapping[str, Any]) -> dict[str, Any]:
    """Write every representation of the store at ``store_dir`` under ``out_dir/<rep>/``."""
    t0 = time.perf_counter()
    store = Store.open(store_dir)
    summary: dict[str, Any] = {"dataset": str(store.meta["dataset"].iloc[0]) if len(store) else "",
                               "input_sequences": len(store), "representations": {}}
    for name, rep in representations.items():
        rep = dict(rep)
        space = rep.get("space", "3d")
        if space not in ("3d", "2d"):
            raise ValueError(f"prepare.representations.{name}.space must be 3d or 2d, got {space!r}")
        if rep.get("all_phases") and space != "2d":
            raise ConfigError(f"prepare.representations.{name}.all_phases: only 2-D representations keep "
                              f"every phase; {name} is {space}")
        fn = _prepare_3d if space == "3d" else _prepare_2d
        summary["representations"][name] = fn(store, Path(out_dir) / name, rep)
        # the representation's own description and the store's class table, read by split and training
        (Path(out_dir) / name / "representation.json").write_text(json.dumps(
            {k: v for k, v in rep.items() if k != "clips"} | {"space": space}, indent=1))
        if store.classes is not None:
            (Path(out_dir) / name / "classes.json").write_text(json.dumps(store.classes, indent=1))
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    return summary


def select_joints(skel: Skeleton, rep: Mapping[str, Any]) -> tuple[np.ndarray, Skeleton]:
    """The joints a representation keeps (``joints``, minus ``drop_joints``): their indices in
    ``skel`` and the reduced skeleton."""
    names = list(rep.get("joints") or skel.names)
    drop = set(rep.get("drop_joints") or [])
    unknown = [j for j in list(drop) + names if j not in skel.names]
    if unknown:
        raise KeyError(f"unknown joints {unknown} for skeleton {skel.names}")
    names = [n for n in names if n not in drop]
    return skel.indices(names), skel.subset(names)


def _prepare_3d(store: Store, out: Path, rep: Mapping[str, Any]) -> dict[str, Any]:
    skel = store.skeleton
    if skel.hips is None:
        raise ValueError("3d representation needs skeleton.hips in the dataset config")
    idx, sub = select_joints(skel, rep)
    fps = float(rep["fps"])
    pos_all = store.array("positions")
    mask_all = store.array("body_mask")
    root_i, hips = skel.index(skel.root), tuple(skel.indices(list(skel.hips)))
    sh = tuple(skel.indices(list(skel.shoulders))) if skel.shoulders else None
    poses, roots, ctrls, rows = [], [], [], []
    dropped_frames = 0
    for _, row in store.meta.iterrows():  # one iteration per sequence; frames are vectorised
        sl = slice(int(row["offset"]), int(row["offset"] + row["frames"]))
        p = np.asarray(pos_all[sl], dtype=np.float32)
        if mask_all is not None:  # multi-person: keep frames where the first body is tracked
            keep = np.asarray(mask_all[sl][:, 0])
            dropped_frames += int((~keep).sum())
            p = p[keep]
        p = resample(p, float(row["fps"]), fps)
        if len(p) < 2:
            dropped_frames += len(p)
            continue
        pose, root, ctrl = root_and_controls(p, root_i, hips, sh, fps, float(rep.get("facing_sigma_s", 0.1)))
        poses.append(pose[:, idx])
        roots.append(root)
        ctrls.append(ctrl)
        rows.append(_row(row, len(pose), fps, row["sequence_id"], row.get("view", "")))
    meta = _finish(out, rows, {"pose": poses, "root": roots, "controls": ctrls}, sub)
    return _clips_and_summary(out, meta, rep, fps, dropped_frames, store)


def _prepare_2d(store: Store, out: Path, rep: Mapping[str, Any]) -> dict[str, Any]:
    skel = store.skeleton
    v2d, depth = store.array("views2d"), store.array("view_depth")
    if v2d is None:
        raise ValueError(f"{store.root}: 2d representation needs views2d from ingest")
    idx, sub = select_joints(skel, rep)
    center = skel.index(rep.get("center") or skel.root)
    fps = float(rep["fps"])
    view_names = _view_names(store, v2d.shape[1])
    poses, roots, rows = [], [], []
    for _, row in store.meta.iterrows():
        sl = slice(int(row["offset"]), int(row["offset"] + row["frames"]))
        uv = np.asarray(v2d[sl], dtype=np.float32)                  # [T, V, J, 2]
        d = np.asarray(depth[sl], dtype=np.float32) if depth is not None else np.ones(uv.shape[:2], np.float32)
        cam_names = view_names(row)
        phases = _phases(float(row["fps"]), fps, rep)
        for v in range(uv.shape[1]):
            for p in phases:
                q = resample(uv[p:, v], float(row["fps"]), fps)     # [T', J, 2]
                dv = resample(d[p:, v], float(row["fps"]), fps)
                c = q[:, center]
                poses.append((q - c[:, None, :])[:, idx])
                roots.append(np.concatenate([c, dv[:, None]], axis=1))
                sid = f"{row['sequence_id']}@{cam_names[v]}" + (f"+{p}" if len(phases) > 1 else "")
                rows.append(_row(row, len(q), fps, sid, cam_names[v], phase=p if len(phases) > 1 else None))
    meta = _finish(out, rows, {"pose": poses, "root": roots}, sub)
    return _clips_and_summary(out, meta, rep, fps, 0, store)


def _phases(src_fps: float, fps: float, rep: Mapping[str, Any]) -> list[int]:
    """The start frames of the down-sampled sequences of one source sequence: ``[0]``, or with
    ``all_phases`` every offset ``0 .. k-1`` of the integer ratio ``k = src_fps / fps``."""
    if not rep.get("all_phases"):
        return [0]
    ratio = src_fps / fps
    k = round(ratio)
    if k < 1 or abs(ratio - k) > 1e-6 * ratio:
        raise ConfigError(f"all_phases needs an integer down-sampling ratio; the source is at {src_fps:g} fps "
                          f"and the representation at {fps:g} fps (ratio {ratio:g})")
    return list(range(k))


def _view_names(store: Store, V: int):
    cams = store.extras.get("cameras")

    def names(row) -> list[str]:
        subj = str(row.get("subject", ""))
        if cams and subj in cams:
            return [str(cams[subj][k].get("name", k)) for k in sorted(cams[subj], key=int)][:V]
        if V == 1 and row.get("view"):
            return [str(row["view"])]
        return [f"v{i}" for i in range(V)]
    return names


def _row(row: pd.Series, frames: int, fps: float, sid: str, view: str, phase: int | None = None) -> dict[str, Any]:
    r = {c: row.get(c, "") for c in META_COLS}
    r.update(sequence_id=sid, source_id=row["sequence_id"], view=view, frames=frames, fps=fps)
    if phase is not None:
        r["phase"] = phase
    return r


def _finish(out: Path, rows: list[dict], arrays: dict[str, list[np.ndarray]], skel: Skeleton) -> pd.DataFrame:
    out.mkdir(parents=True, exist_ok=True)
    meta = pd.DataFrame(rows, columns=META_COLS + (["phase"] if rows and "phase" in rows[0] else []))
    meta["offset"] = np.concatenate([[0], np.cumsum(meta["frames"].to_numpy())[:-1]]).astype(np.int64) if len(meta) else []
    for col in ("subject", "view", "style", "label_name", "member", "dataset", "source_id"):
        meta[col] = meta[col].astype(str)
    for col in ("label", "label_raw"):
        meta[col] = pd.to_numeric(meta[col], errors="coerce").fillna(-1).astype(np.int64)
    if "phase" in meta:
        meta["phase"] = meta["phase"].astype(np.int64)
    for name, parts in arrays.items():
        np.save(out / f"{name}.npy", np.concatenate(parts, axis=0).astype(np.float32) if parts else np.zeros((0,)))
    meta.to_parquet(out / "meta.parquet", index=False)
    skel.save(out / "skeleton.json")
    return meta


def _clips_and_summary(out: Path, meta: pd.DataFrame, rep: Mapping[str, Any], fps: float,
                       dropped_frames: int, store: Store) -> dict[str, Any]:
    frames = meta["frames"].to_numpy()
    clip_counts = {}
    for family, c in (rep.get("clips") or {}).items():
        c = dict(c)
        if family == "vae_lstm" or "length" in c:
            win = windows(frames, int(c["length"]), int(c.get("stride", c["length"])), c.get("pad", "end"),
                          int(c.get("min_frames", 1)))
            win["every"] = 1
        else:  # sparse poses every k frames, plus the dense frames between them
            k, n = int(c["every"]), int(c["num_sparse"])
            length = (n - 1) * k + 1
            win = windows(frames, length, int(c.get("stride", k)), "none")
            win["every"] = k
        win["sequence_id"] = meta["sequence_id"].to_numpy()[win["seq"].to_numpy()] if len(win) else []
        win.to_parquet(out / f"windows_{family}.parquet", index=False)
        used = set(win["seq"].tolist())
        clip_counts[family] = {"windows": int(len(win)), "sequences_used": len(used),
                               "sequences_too_short": int(len(meta) - len(used))}
    return {"sequences": int(len(meta)), "frames": int(frames.sum()), "fps": fps,
            "joints": int(np.load(out / "pose.npy", mmap_mode="r").shape[1]) if len(meta) else 0,
            "dims": int(np.load(out / "pose.npy", mmap_mode="r").shape[2]) if len(meta) else 0,
            "dropped_untracked_frames": dropped_frames, "clips": clip_counts}

"""Running a :class:`~motionsynth.generate.planning.Plan`: VAE-LSTM along a control path, GloGen +
LocGen along a class schedule with blended chunk seams."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence as Seq

import numpy as np

from .config import compose_config
from .inputs import schedule_text
from .outputs import write_outputs
from .planning import Plan, plan
from .runs import _load


# ============================================================================ run

@dataclass
class Result:
    plan: Plan
    files: list[Path]
    positions: np.ndarray            # [N, T, J, 3] metres
    timings: dict[str, float]
    info: dict[str, Any]



def run(p: Plan) -> Result:
    """Load the model(s), generate, write the files."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(int(p.cfg["threads"]))
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    try:
        if p.family == "vae_lstm":
            model, train = _load(p.runs["vae_lstm"], p.cfg)
            timings["load_s"] = time.perf_counter() - t0
            t1 = time.perf_counter()
            positions, info = _generate_vae(p, model, train)
        else:
            glogen, train = _load(p.runs["glogen"], p.cfg)
            locgen, _ = _load(p.runs["locgen"], p.cfg)
            timings["load_s"] = time.perf_counter() - t0
            t1 = time.perf_counter()
            positions, info = _generate_glocal(p, glogen, locgen, train)
        timings["generate_s"] = time.perf_counter() - t1
    finally:
        torch.set_num_threads(threads)                  # process-wide state: give it back to a library caller
    files = write_outputs(p, positions, info, timings)
    return Result(p, files, positions, timings, info)


def generate(overrides: Seq[str] | Mapping = ()) -> Result:
    """The whole command: options (``key=value`` strings or a composed config dict) -> files."""
    cfg = dict(overrides) if isinstance(overrides, Mapping) else compose_config(overrides)
    return run(plan(cfg))


def _generate_vae(p: Plan, model, train) -> tuple[np.ndarray, dict]:
    import torch

    from ..data.controls import integrate_controls, to_global

    T, ctrl = p.frames, p.controls
    f = int(getattr(model, "factor", 1))
    Tp = -(-T // f) * f
    c = np.concatenate([ctrl, np.repeat(ctrl[-1:], Tp - T, 0)]) if Tp > T else ctrl
    z = ((c - train.ctrl_mean) / train.ctrl_std).astype(np.float32)
    torch.manual_seed(int(p.cfg["seed"]))
    with torch.inference_mode():
        out = model.generate(None, torch.from_numpy(z)[None], length=Tp, num_samples=p.num_samples)[:, :T]
    local = train.norm.inverse(out.numpy().astype(np.float64))                   # [N, T, J, 3] root-relative
    root = integrate_controls(ctrl, p.fps, start=np.array([0.0, 0.0, p.start_heading]))   # [T, 3] x, z, heading
    glob = to_global(local, root)                                                 # [N, T, J, 3]
    info = {"controls": ctrl.astype(np.float32), "root": root.astype(np.float32),
            "path": p.path_name, "seed": int(p.cfg["seed"]), "start_heading_deg": math.degrees(p.start_heading)}
    return glob.astype(np.float32), info


def blend_seams(x: np.ndarray, seams: Seq[int], width: int) -> np.ndarray:
    """Remove the velocity jump at each seam pose ``q`` of ``x`` ``[n, F]`` (in increasing order):
    the excess ``(x[q] - x[q-1]) - (x[q-1] - x[q-2])`` is subtracted from ``x[q:]`` with a
    raised-cosine weight falling from 1 at ``q`` to 0 at ``q + width``, so pose ``q`` continues the
    previous velocity and later poses converge back to the generated ones."""
    x = x.copy()
    if width <= 0:
        return x
    w = 0.5 * (1 + np.cos(np.pi * np.arange(width) / width))                      # 1 .. ~0
    for q in sorted(seams):
        if q < 2 or q >= len(x):
            continue
        excess = (x[q] - x[q - 1]) - (x[q - 1] - x[q - 2])
        n = min(width, len(x) - q)
        x[q:q + n] -= w[:n, None] * excess
    return x


def seam_jumps(x: np.ndarray, at: Seq[int], window: int = 5) -> list[float]:
    """For each pose ``q`` in ``at``: the step into it, ``|x[q] - x[q-1]|``, over the median of the
    ``2 * window`` steps around it (1 = as smooth as the motion around it; a visible pop is
    several times that). Local, so it does not mistake a faster activity for a jump."""
    step = np.linalg.norm(np.diff(x, axis=0), axis=-1)                           # step[i] = |x[i+1] - x[i]|
    out = []
    for q in at:
        i = q - 1
        if not 0 <= i < len(step):
            continue
        near = np.r_[step[max(0, i - window):i], step[i + 1:i + 1 + window]]
        out.append(float(step[i] / max(float(np.median(near)) if len(near) else 1.0, 1e-12)))
    return out


def _generate_glocal(p: Plan, glogen, locgen, train) -> tuple[np.ndarray, dict]:
    import torch

    from ..training.data import open_split

    J, D = train.spec.joints, train.spec.dims
    t = p.t_in
    ds_cfg = p.runs["glogen"].cfg["dataset"]
    if p.seed_window is not None:
        sp, idx, _ = p.seed_window
        wd = open_split(p.cfg["processed_dir"], p.cfg["splits_dir"], ds_cfg["name"], ds_cfg["training"], "glocal", sp)
        b = wd.batch(np.array([idx]))
        seed = b.pose[:, ::b.every][:, :t]
    else:
        seed = torch.zeros(1, t, J, D)
    bounds = np.cumsum([0, *p.steps])                 # entry e covers sparse poses [bounds[e], bounds[e+1])
    n_sparse = int(bounds[-1]) + 1                    # + the end keyframe of the last gap
    sparse, seams = seed, []
    with torch.inference_mode():
        for e, entry in enumerate(p.entries):         # one roll-out per entry: switches land exactly
            end = n_sparse if e == len(p.entries) - 1 else int(bounds[e + 1])
            start = sparse.shape[1]
            if end > start:
                out = glogen.generate(sparse[:, -t:], labels=torch.tensor([entry.label]), length=t + end - start)
                sparse = torch.cat([sparse, out[:, t:]], 1)
                seams += range(start, end, t)        # where GloGen starts a chunk
        x = sparse[0].reshape(n_sparse, -1).numpy().astype(np.float64)
        switches = [int(q) for q in bounds[1:-1]]
        g = p.cfg["glocal"]
        width = int(g.get("blend_poses") or 0)
        where = {"seams": seams, "switches": switches, "none": []}[g.get("blend_at", "seams")]
        chunk_only = [q for q in seams if q not in set(switches)]
        raw = seam_jumps(x, switches, t), seam_jumps(x, chunk_only, t)
        x_raw, x = x, blend_seams(x, where, width)
        fin = seam_jumps(x, switches, t), seam_jumps(x, chunk_only, t)
        xs = torch.from_numpy(x.astype(np.float32)).reshape(1, n_sparse, J, D)
        dense = locgen.generate(xs, M=p.M)[:, :p.frames]
    local = train.norm.inverse(dense.numpy().astype(np.float64))                 # [1, T, J, 3]
    sparse_labels = np.empty(n_sparse, np.int64)
    for e, entry in enumerate(p.entries):
        sparse_labels[bounds[e]:bounds[e + 1]] = entry.label
    sparse_labels[-1] = p.entries[-1].label
    frame_labels = sparse_labels[np.arange(p.frames) // (p.M + 1)]
    names = sorted(p.classes, key=p.classes.get)
    info = {"schedule": schedule_text(p.entries, p.steps, p.k, p.fps), "pace": p.pace,
            "effective_pace": p.k / (p.M + 1), "M": p.M, "k": p.k,
            "sparse": x.reshape(n_sparse, J, D).astype(np.float32),           # normalised keyframes (blended)
            "sparse_raw": x_raw.reshape(n_sparse, J, D).astype(np.float32),   # GloGen's output
            "labels": frame_labels, "class_names": np.array(names), "class_labels": np.array([p.classes[n] for n in names]),
            "switch_frames": np.array([q * (p.M + 1) for q in switches], np.int64),
            "switch_jump_raw": np.array(raw[0]), "switch_jump": np.array(fin[0]),
            "chunk_jump_raw": np.array(raw[1]), "chunk_jump": np.array(fin[1]),
            "blend_at": str(g.get("blend_at", "seams")) if width else "none", "blend_poses": width,
            "seed_motion": g.get("seed_motion"),
            "seed_sequence": p.seed_window[2] if p.seed_window else "", "root": np.zeros((p.frames, 3), np.float32)}
    return local.astype(np.float32), info

"""Prediction errors against ground truth: GlocalNet's Euclidean error per frame (Table 4) and
VAE-LSTM's motion / pose prediction errors (Tables 1-2).

All functions are vectorised (no Python loop over sequences, frames or joints), take numpy
arrays or torch tensors (detached and moved to the CPU here) and return numpy float64.
Bad input raises ``ValueError``: wrong rank or shape, NaN/inf, a horizon or frame outside
the sequence, an unknown option.

Shapes
------
``gt`` ``[B, T, J, D]``: ``B`` sequences of ``T`` frames, ``J`` joints, ``D`` coordinates
(``D = 3`` for positions; any ``D`` for the Euclidean error).
``pred`` ``[B, T, J, D]`` (one prediction per sequence) or ``[S, B, T, J, D]`` (``S`` samples of
a stochastic model per sequence, the sample axis first). Frame ``t`` of ``pred`` and ``gt`` is
the same instant: both arrays are aligned on the same time axis.

Samples
-------
With a sample axis, each sequence's value is the **mean over its S samples** of the per-sample
error (``samples="mean"``, the expected error of one draw), or the minimum (``samples="min"``,
best-of-S, a different and much more lenient number). Then the plain mean over the ``B``
sequences, each weighted 1. The ``*_values`` functions return the per-sequence ``[B, H]``
arrays for standard deviations and confidence intervals (:func:`summarise`).

1. Euclidean error per frame (GlocalNet, Table 4)
--------------------------------------------------
GlocalNet (sec. 4.3) only says "the euclidean distance from the ground truth for the
corresponding frame", as used by acLSTM (Li et al. 2018). We define it as::

    e_b(h) = scale * || vec(P_b[t_h] - P_b[t_h, root]) - vec(G_b[t_h] - G_b[t_h, root]) ||_2

* **space**: root-relative positions: each frame's root joint (``root_index``) is subtracted
  from every joint of that frame, separately for prediction and ground truth (the root row is
  then 0 in both). ``root_index=None`` skips this (inputs already relative, or a global error).
* **norm**: ONE L2 norm of the whole flattened ``J * D`` pose-vector difference per frame
  (the norm of the difference of acLSTM's 171-dim frame vectors for its 57 joints) - not a
  mean of per-joint distances, which is ``sqrt(J)`` to ``J`` times smaller.
* **units**: the inputs' units times ``scale``. acLSTM's units are BVH file units x 0.01 with
  all 57 joints of its CMU skeleton (End Sites included); our ``cmu_aclstm`` store
  (``reader.scale: 0.01``) holds exactly those numbers, so ``scale=1`` on the store's
  positions reproduces acLSTM's units. The number grows with ``J``: compare only on the same
  skeleton.
* **horizon -> frame**: ``h`` ms after the **last seed frame** is ``k = round(h * fps / 1000)``
  frames after it (round half up; :func:`horizon_frames`). At 120 fps, 80 ms is frame 10 after
  the seed (9.6 rounded); at 60 fps frame 5; at 30 fps frame 2 (66.7 ms: 80 ms is not a whole
  number of 30-fps frames). ``frame_mapping="interpolate"`` instead reads both sequences
  linearly interpolated at the exact fractional frame ``h * fps / 1000`` (80 ms at 30 fps =
  frame 2.4 = 0.6 * frame 2 + 0.4 * frame 3).
* **seed frames**: the first ``seed_frames`` frames of both arrays are the observed seed
  (indices ``0 .. seed_frames-1``; they are not scored). The horizon-``h`` frame is index
  ``seed_frames - 1 + k``. With ``seed_frames=0`` the arrays hold only the continuation:
  index 0 is the first predicted frame (one frame after the seed) and ``h`` is index ``k - 1``.
* **averaging**: per sequence (and per sample, see above), then the plain mean over sequences.

2. Motion and pose prediction error (VAE-LSTM, Tables 1-2)
-----------------------------------------------------------
The paper (sec. 4.3): "the mean squared error between generated joint positions and ground
truth motion on the held-out test set consisting of 20 sequences", at frames 70, 90, 120, 160
and 210 of the 240-frame (4 s at 60 Hz) test clips whose first 60 frames (Table 1; 4 for
VAE-LSTM) are given. *Motion* error compares the joints' global positions; *pose* error
(Table 2) is "relative to the root of the character, ignoring both translation and rotation".

* **frames**: counted from the start of the clip, 1-based (the paper's "60 initial frames"
  are frames 1-60 and frame 70 is the 10th predicted frame): frame ``f`` is index
  ``f - frame_base`` with ``frame_base=1`` (pass 0 for 0-based frame numbers). ``pred`` and
  ``gt`` are the whole clips, seed frames included; only the listed frames are read, so
  ``T >= max(frames)`` is required. The frame numbers are at the paper's 60 Hz: resample
  to 60 fps first (our Bandai stand-in is prepared at 60 fps).
* **error** (``reduction``), per frame and sequence, with ``d_j`` the position difference of
  joint ``j``:

  - ``"mse"`` (default): ``mean_j ||d_j||^2``, the mean over joints of the squared Euclidean
    distance. This is the paper's words, "mean squared error between joint positions": the
    error of a joint *position* is its 3-D distance, squared, averaged over joints (and then
    over sequences). The paper gives neither the units nor whether the squares are averaged
    over coordinates; so
  - ``"mse_coord"``: ``mean_{j,c} d_jc^2`` = ``mse / D`` (numpy/torch ``MSELoss`` over the
    flat pose vector, the loss the baselines train with), differs by exactly a factor ``D``;
  - ``"rmse"``: ``sqrt(mse)`` per frame and sequence; ``"mpjpe"``: ``mean_j ||d_j||``;
    ``"l2"``: ``||vec(d)||`` (GlocalNet's norm).

  **Units**: the paper does not state them (its Edinburgh data are not available here), so
  absolute values cannot be matched; ours are the inputs' units (metres in our store) times
  ``scale`` (squared for the squared reductions).
* **motion** (``kind="motion"``): global positions as given (no root, no facing removal).
* **pose** (``kind="pose"``): root-relative (``root_index``, required) and, with
  ``facing_joints=(left, right)`` (e.g. the hips), facing-normalised: every frame of each
  array is rotated about the vertical axis so that its across-body vector
  ``x[left] - x[right]`` points along the first horizontal axis after the vertical one
  (+X for Y up), which removes the character's rotation as the paper says. Without
  ``facing_joints`` only the translation is removed (our prepared ``pose`` arrays are already
  facing-normalised, so passing them needs no facing removal).

3. Utilities
------------
:func:`root_relative`, :func:`remove_facing`, :func:`ms_to_frames` / :func:`frames_to_ms`,
:func:`horizon_frames`, :func:`summarise` (mean, std, 95 % CI over sequences).
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

import numpy as np

from ..checks import one_of, positive_number

__all__ = [
    "DEFAULT_HORIZONS_MS", "VAE_LSTM_FRAMES", "REDUCTIONS",
    "as_array", "root_relative", "remove_facing", "ms_to_frames", "frames_to_ms", "horizon_frames",
    "euclidean_per_frame", "euclidean_per_frame_values",
    "prediction_error", "prediction_error_values", "summarise",
]

DEFAULT_HORIZONS_MS: tuple[int, ...] = (80, 160, 240, 320, 400, 480, 560, 640)
VAE_LSTM_FRAMES: tuple[int, ...] = (70, 90, 120, 160, 210)
REDUCTIONS = ("mse", "mse_coord", "rmse", "mpjpe", "l2")
_SAMPLES = ("mean", "min")
_KINDS = ("motion", "pose")
_MAPPINGS = ("round", "interpolate")


# ----------------------------------------------------------------------------- inputs

def as_array(x: Any, name: str = "input") -> np.ndarray:
    """``x`` (numpy, torch or nested lists) as a finite float64 numpy array."""
    if hasattr(x, "detach"):  # torch tensor, without importing torch here
        x = x.detach().cpu().numpy()
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: not a numeric array ({e})") from None
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: holds NaN or inf")
    return a


def _pair(pred: Any, gt: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(pred [S, B, T, J, D], gt [B, T, J, D])``; ``S = 1`` without a sample axis."""
    g = as_array(gt, "gt")
    p = as_array(pred, "pred")
    if g.ndim != 4:
        raise ValueError(f"gt must be [B, T, J, D], got shape {g.shape}")
    if min(g.shape) < 1:
        raise ValueError(f"gt has an empty axis: shape {g.shape}")
    if p.ndim == 4 and p.shape == g.shape:
        return p[None], g
    if p.ndim == 5 and p.shape[1:] == g.shape and p.shape[0] >= 1:
        return p, g
    raise ValueError(f"pred must be [B, T, J, D] or [S, B, T, J, D] matching gt {g.shape}, got {p.shape}")


def _check_index(i: Any, n: int, name: str) -> int:
    if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
        raise ValueError(f"{name} must be an int, got {i!r}")
    if not 0 <= int(i) < n:
        raise ValueError(f"{name}={i} is outside 0..{n - 1}")
    return int(i)


def _check_fps(fps: Any) -> float:
    return positive_number(fps, "fps")


def _reduce_samples(v: np.ndarray, samples: str) -> np.ndarray:
    one_of(samples, "samples", _SAMPLES)
    return v.mean(axis=0) if samples == "mean" else v.min(axis=0)


# ----------------------------------------------------------------------------- utilities

def root_relative(x: Any, root_index: int) -> np.ndarray:
    """Positions ``[..., J, D]`` minus each frame's root joint (the root row becomes 0)."""
    a = as_array(x, "positions")
    if a.ndim < 2:
        raise ValueError(f"positions must be [..., J, D], got shape {a.shape}")
    r = _check_index(root_index, a.shape[-2], "root_index")
    return a - a[..., r:r + 1, :]


def _horizontal_axes(vertical_axis: int) -> tuple[int, int]:
    v = _check_index(vertical_axis, 3, "vertical_axis")
    return (v + 1) % 3, (v + 2) % 3


def remove_facing(x: Any, facing_joints: tuple[int, int], vertical_axis: int = 1) -> np.ndarray:
    """Rotate every frame of ``x`` ``[..., J, 3]`` about the vertical axis (through the origin)
    so that its across-body vector ``x[left] - x[right]``, projected on the ground plane, points
    along axis ``(vertical_axis + 2) % 3`` (+X for Y up: the body then faces +Z, the convention
    of :mod:`motionsynth.data.controls`). Make the poses root-relative first to rotate about the
    root. A frame whose across vector is vertical (no horizontal part) is left unrotated."""
    a = as_array(x, "positions")
    if a.ndim < 2 or a.shape[-1] != 3:
        raise ValueError(f"remove_facing needs [..., J, 3] positions, got shape {a.shape}")
    if len(facing_joints) != 2:
        raise ValueError(f"facing_joints must be (left, right), got {facing_joints!r}")
    J = a.shape[-2]
    left = _check_index(facing_joints[0], J, "facing_joints[0]")
    right = _check_index(facing_joints[1], J, "facing_joints[1]")
    if left == right:
        raise ValueError("facing_joints must be two different joints")
    ia, ib = _horizontal_axes(vertical_axis)
    across = a[..., left, :] - a[..., right, :]                          # [..., 3]
    alpha = np.arctan2(across[..., ib], across[..., ia])                   # angle from axis ia
    phi = (np.pi / 2 - alpha)[..., None]                                   # turn it onto axis ib
    c, s = np.cos(phi), np.sin(phi)
    u, w = a[..., ia], a[..., ib]
    out = a.copy()
    out[..., ia] = u * c - w * s
    out[..., ib] = u * s + w * c
    return out


def _round_half_up(x: np.ndarray) -> np.ndarray:
    # the small epsilon keeps exact halves (e.g. 7.5 from 250 ms at 30 fps) from flooring
    # after a binary rounding error in h * fps / 1000
    return np.floor(np.asarray(x, dtype=np.float64) + 0.5 + 1e-9).astype(np.int64)


def ms_to_frames(ms: Any, fps: float) -> Any:
    """Milliseconds to a whole number of frames at ``fps``: ``round(ms * fps / 1000)``, half up.
    A scalar in gives an ``int``, an array an int64 array."""
    f = _check_fps(fps)
    m = as_array(ms, "ms")
    k = _round_half_up(m * f / 1000.0)
    return int(k) if k.ndim == 0 else k


def frames_to_ms(frames: Any, fps: float) -> Any:
    """Frames to milliseconds at ``fps``: ``frames * 1000 / fps`` (float or float array)."""
    f = _check_fps(fps)
    n = as_array(frames, "frames")
    out = n * 1000.0 / f
    return float(out) if out.ndim == 0 else out


def _horizons(horizons_ms: Iterable[float]) -> np.ndarray:
    h = as_array(list(horizons_ms) if not hasattr(horizons_ms, "shape") else horizons_ms, "horizons_ms")
    if h.ndim != 1 or h.size == 0:
        raise ValueError(f"horizons_ms must be a non-empty 1-D list, got shape {h.shape}")
    if np.any(h <= 0):
        raise ValueError(f"horizons_ms must be positive, got {h.tolist()}")
    return h


def horizon_frames(horizons_ms: Iterable[float] = DEFAULT_HORIZONS_MS, fps: float = 120.0) -> np.ndarray:
    """Frames after the last seed frame for each horizon: ``round(h * fps / 1000)`` (half up),
    int64 ``[H]``. 120 fps: 10, 19, 29, 38, 48, 58, 67, 77; 60 fps: 5, 10, 14, 19, 24, 29, 34,
    38; 30 fps: 2, 5, 7, 10, 12, 14, 17, 19 for 80..640 ms. A horizon shorter than half a frame
    (0 frames) raises: it would score the last seed frame."""
    f = _check_fps(fps)
    h = _horizons(horizons_ms)
    k = _round_half_up(h * f / 1000.0)
    if np.any(k < 1):
        bad = h[k < 1].tolist()
        raise ValueError(f"horizons {bad} ms are under half a frame at {f:g} fps")
    return k


# ----------------------------------------------------------------------------- Euclidean (GlocalNet)

def euclidean_per_frame_values(pred: Any, gt: Any, fps: float,
                               horizons_ms: Iterable[float] = DEFAULT_HORIZONS_MS, *,
                               root_index: int | None, seed_frames: int = 0,
                               joints: Sequence[int] | None = None, scale: float = 1.0,
                               frame_mapping: str = "round", samples: str = "mean") -> np.ndarray:
    """Per-sequence Euclidean error per frame, ``[B, H]`` (see the module docstring, part 1).

    ``root_index``: the root joint subtracted per frame (required; ``None`` = no subtraction).
    ``seed_frames``: number of leading seed frames in both arrays (0 = they start one frame
    after the seed). ``joints``: optional subset of joint indices scored (after the root
    subtraction); default all. ``scale``: unit factor on distances. ``frame_mapping``:
    ``"round"`` (nearest frame) or ``"interpolate"`` (linear at the exact fractional frame).
    ``samples``: ``"mean"`` or ``"min"`` over a leading sample axis of ``pred``.
    """
    p, g = _pair(pred, gt)
    f = _check_fps(fps)
    T, J = g.shape[1], g.shape[2]
    if isinstance(seed_frames, bool) or not isinstance(seed_frames, (int, np.integer)) or seed_frames < 0:
        raise ValueError(f"seed_frames must be an int >= 0, got {seed_frames!r}")
    one_of(frame_mapping, "frame_mapping", _MAPPINGS)
    one_of(samples, "samples", _SAMPLES)
    scale = float(scale)
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    h = _horizons(horizons_ms)
    if frame_mapping == "round":
        k = horizon_frames(h, f).astype(np.float64)
    else:
        k = h * f / 1000.0
        if np.any(k < 1 - 1e-9) and seed_frames == 0:
            raise ValueError(f"horizons {h[k < 1 - 1e-9].tolist()} ms fall before the first "
                             f"predicted frame at {f:g} fps with seed_frames=0")
    t = (seed_frames - 1) + k                                              # fractional index [H]
    if np.any(t > T - 1 + 1e-9):
        bad = h[t > T - 1 + 1e-9].tolist()
        raise ValueError(f"horizons {bad} ms need frame index up to {t.max():g} but the arrays "
                         f"hold {T} frames (seed_frames={seed_frames}, fps={f:g})")
    lo = np.clip(np.floor(t + 1e-9).astype(np.int64), 0, T - 1)
    w = np.clip(t - lo, 0.0, 1.0)                                          # 0 for "round"
    hi = np.minimum(lo + 1, T - 1)

    def at(x: np.ndarray) -> np.ndarray:                                   # [..., T, J, D] -> [..., H, J, D]
        y = x[..., lo, :, :]
        if np.any(w > 0):
            ww = w[:, None, None]
            y = (1 - ww) * y + ww * x[..., hi, :, :]
        return y

    P, G = at(p), at(g)                                                    # [S,B,H,J,D], [B,H,J,D]
    if root_index is not None:
        r = _check_index(root_index, J, "root_index")
        P = P - P[..., r:r + 1, :]
        G = G - G[..., r:r + 1, :]
    if joints is not None:
        idx = np.asarray(list(joints), dtype=np.int64)
        if idx.ndim != 1 or idx.size == 0 or idx.min() < 0 or idx.max() >= J:
            raise ValueError(f"joints must be a non-empty list of indices in 0..{J - 1}")
        P, G = P[..., idx, :], G[..., idx, :]
    d = (P - G[None]).reshape(P.shape[:3] + (-1,))                        # [S, B, H, J*D]
    e = scale * np.sqrt(np.einsum("sbhk,sbhk->sbh", d, d))
    return _reduce_samples(e, samples)


def euclidean_per_frame(pred: Any, gt: Any, fps: float,
                        horizons_ms: Iterable[float] = DEFAULT_HORIZONS_MS, **kw: Any) -> np.ndarray:
    """GlocalNet's Euclidean error per frame at each horizon, ``[H]``: the mean over sequences
    of :func:`euclidean_per_frame_values` (same arguments; ``root_index`` is required)."""
    return euclidean_per_frame_values(pred, gt, fps, horizons_ms, **kw).mean(axis=0)


# ----------------------------------------------------------------------------- VAE-LSTM errors

def prediction_error_values(pred: Any, gt: Any, frames: Iterable[int] = VAE_LSTM_FRAMES,
                            kind: str = "motion", *, root_index: int | None = None,
                            facing_joints: tuple[int, int] | None = None, vertical_axis: int = 1,
                            reduction: str = "mse", frame_base: int = 1, scale: float = 1.0,
                            samples: str = "mean") -> np.ndarray:
    """Per-sequence motion / pose prediction error at clip frames, ``[B, F]`` (module
    docstring, part 2). ``kind="motion"``: global positions (``root_index`` and
    ``facing_joints`` must be left out); ``kind="pose"``: root-relative (``root_index``
    required), facing-normalised when ``facing_joints`` is given."""
    one_of(kind, "kind", _KINDS)
    one_of(reduction, "reduction", REDUCTIONS)
    one_of(samples, "samples", _SAMPLES)
    if frame_base not in (0, 1):
        raise ValueError(f"frame_base must be 0 or 1, got {frame_base!r}")
    scale = float(scale)
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    p, g = _pair(pred, gt)
    T, J, D = g.shape[1:]
    fr = np.asarray(list(frames))
    if fr.ndim != 1 or fr.size == 0 or not np.issubdtype(fr.dtype, np.integer):
        raise ValueError(f"frames must be a non-empty list of ints, got {list(frames)!r}")
    idx = fr.astype(np.int64) - frame_base
    if idx.min() < 0 or idx.max() >= T:
        raise ValueError(f"frames {fr.tolist()} (base {frame_base}) need indices "
                         f"{idx.min()}..{idx.max()} but the clips hold {T} frames")
    P, G = p[:, :, idx], g[:, idx]                                         # [S,B,F,J,D], [B,F,J,D]
    if kind == "motion":
        if root_index is not None or facing_joints is not None:
            raise ValueError("kind='motion' compares global positions: root_index and "
                             "facing_joints apply to kind='pose' only")
    else:
        if root_index is None:
            raise ValueError("kind='pose' needs root_index (the root joint subtracted per frame)")
        r = _check_index(root_index, J, "root_index")
        P = P - P[..., r:r + 1, :]
        G = G - G[..., r:r + 1, :]
        if facing_joints is not None:
            if D != 3:
                raise ValueError(f"facing removal needs 3-D positions, got D={D}")
            P = remove_facing(P, facing_joints, vertical_axis)
            G = remove_facing(G, facing_joints, vertical_axis)
    d = (P - G[None]) * scale
    sq = np.einsum("sbfjd,sbfjd->sbfj", d, d)                             # squared joint distances
    if reduction == "mse":
        e = sq.mean(-1)
    elif reduction == "mse_coord":
        e = sq.mean(-1) / D
    elif reduction == "rmse":
        e = np.sqrt(sq.mean(-1))
    elif reduction == "mpjpe":
        e = np.sqrt(sq).mean(-1)
    else:  # "l2"
        e = np.sqrt(sq.sum(-1))
    return _reduce_samples(e, samples)


def prediction_error(pred: Any, gt: Any, frames: Iterable[int] = VAE_LSTM_FRAMES,
                     kind: str = "motion", **kw: Any) -> np.ndarray:
    """VAE-LSTM's motion (Table 1) or pose (Table 2) prediction error at each frame, ``[F]``:
    the mean over sequences of :func:`prediction_error_values` (same arguments)."""
    return prediction_error_values(pred, gt, frames, kind, **kw).mean(axis=0)


# ----------------------------------------------------------------------------- summaries

def summarise(values: Any, axis: int = 0, z: float = 1.959964) -> dict[str, np.ndarray]:
    """Mean, sample std (ddof 1), standard error and a normal-approximation confidence
    interval ``mean +- z * sem`` (95 % by default) over ``axis`` of per-sequence values
    (e.g. the ``[B, H]`` of :func:`euclidean_per_frame_values`). With one value std/sem are
    NaN. The normal interval is a little narrow below ~30 sequences (a t quantile would be
    wider: 2.09 instead of 1.96 for 20)."""
    v = as_array(values, "values")
    if v.ndim == 0 or v.shape[axis] == 0:
        raise ValueError(f"summarise needs at least one value along axis {axis}, got shape {v.shape}")
    n = v.shape[axis]
    mean = v.mean(axis=axis)
    std = v.std(axis=axis, ddof=1) if n > 1 else np.full_like(mean, np.nan)
    sem = std / math.sqrt(n)
    return {"mean": mean, "std": std, "sem": sem, "ci_low": mean - z * sem,
            "ci_high": mean + z * sem, "n": np.asarray(n)}

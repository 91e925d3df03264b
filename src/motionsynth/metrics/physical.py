"""Physical plausibility of generated motion: foot skating and bone-length consistency.

Both take world positions ``[B, T, J, 3]`` (numpy or torch; float64 numpy out), are vectorised
over sequences, frames and joints, and raise ``ValueError`` on bad input (wrong rank or shape,
NaN/inf, out-of-range joint indices, non-positive fps or thresholds).

Foot skating ratio
------------------
The definition of Guided Motion Diffusion (Karunratanakul et al., ICCV 2023), which
OmniControl and later HumanML3D-style evaluations reuse; MDM's paper states the same idea
("frames in which either foot skids more than 2.5 cm while maintaining contact with the
ground, foot height < 5 cm"). For every transition ``t -> t+1`` (``T - 1`` per sequence) and
every foot joint ``f``:

* **contact**: the foot's height above the ground is below ``height_threshold`` (default
  0.05 m) at **both** frames ``t`` and ``t+1``. Height = coordinate ``vertical_axis`` (1 = Y up,
  our BVH convention) minus ``ground``: a number (default 0, metres), or ``"min"`` = each
  sequence's lowest foot height over all its frames and foot joints (for data whose floor is
  not at 0: the CMU acLSTM files put it anywhere between -33 and 0 BVH units).
* **sliding**: the horizontal speed ``||Δx_horizontal|| * fps`` exceeds ``speed_threshold``
  (default 0.5 m/s = GMD's 2.5 cm per frame at HumanML3D's 20 fps, expressed per second so
  that it does not depend on the frame rate), **and** so does its moving average over a
  centred window of ``smooth_window`` transitions (zero-padded at the ends, divided by the full
  window length, as ``scipy.ndimage.uniform_filter1d(mode="constant")``; GMD uses 5 frames at
  20 fps = 0.25 s; the default ``None`` takes the odd window closest below 0.25 s at ``fps``:
  5 at 20 fps, 7 at 30, 15 at 60, 31 at 120; 1 disables the average).
* a transition **skates** when any foot joint is in contact and sliding. The ratio is the
  fraction of skating transitions per sequence, then the mean over sequences (equal to the
  pooled fraction, since all sequences have ``T - 1`` transitions).

``foot_indices`` are the contact joints (ankles and/or toes: our skeletons' ``feet``); each
joint is tested on its own. The result also reports the fraction of transitions with any
foot in contact (a ratio near 0 with no contact at all means a wrong ``ground``, not clean
motion) and the mean horizontal speed of feet in contact.

Bone-length error
-----------------
For every bone (joint ``j`` with parent ``p >= 0``), its length per frame
``L_j(t) = ||x_j(t) - x_p(t)||`` against the rest length ``L0_j = ||offsets[j]||`` of the
skeleton (:class:`~motionsynth.data.types.Skeleton` offsets, same units as the positions):

* ``abs_error``: mean over sequences, frames and bones of ``|L - L0|`` (metres);
* ``rel_error``: mean of ``|L - L0| / L0`` over bones with ``L0 > min_rest`` (zero-length
  bones, e.g. coincident joints, have no relative error; they stay in ``abs_error``);
* ``std_over_time``: the standard deviation over frames of each bone's length (ddof 0), averaged
  over sequences and bones: a skeleton with the wrong but constant bone lengths scores 0 here;
* per-bone arrays for tables (``per_bone_abs``, ``per_bone_rel`` (NaN for zero-length bones),
  ``per_bone_std``) with the child joint of each bone in ``bones``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..checks import positive_number
from .errors import as_array

__all__ = ["FootSkating", "BoneLengthError", "foot_skating_ratio", "bone_lengths", "bone_length_error",
           "default_smooth_window"]


# ----------------------------------------------------------------------------- checks

def _positions(x: Any) -> np.ndarray:
    a = as_array(x, "positions")
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"positions must be [B, T, J, 3], got shape {a.shape}")
    if min(a.shape) < 1:
        raise ValueError(f"positions has an empty axis: shape {a.shape}")
    return a


_positive = positive_number


def _joint_list(idx: Sequence[int], J: int, name: str) -> np.ndarray:
    a = np.asarray(list(idx))
    if a.ndim != 1 or a.size == 0 or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"{name} must be a non-empty list of joint indices, got {list(idx)!r}")
    if a.min() < 0 or a.max() >= J:
        raise ValueError(f"{name} {a.tolist()} outside 0..{J - 1}")
    return a.astype(np.int64)


# ----------------------------------------------------------------------------- foot skating

@dataclass
class FootSkating:
    ratio: float                  # mean over sequences of the skating fraction
    per_sequence: np.ndarray      # [B] fraction of the T-1 transitions that skate
    contact_ratio: float          # fraction of transitions with any foot in contact
    mean_contact_speed: float     # mean horizontal speed (m/s) of foot joints in contact (NaN if none)
    smooth_window: int            # the moving-average window used (transitions)


def default_smooth_window(fps: float, seconds: float = 0.25) -> int:
    """The odd number of transitions closest below ``seconds`` at ``fps`` (at least 1):
    ``2 * floor(seconds * fps / 2) + 1`` (5 at 20 fps, GMD's window)."""
    return 2 * int(math.floor(seconds * _positive(fps, "fps") / 2 + 1e-9)) + 1


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average of ``n`` along the last axis, zero padding, divided by ``n``
    (``uniform_filter1d(mode="constant", cval=0)``; an even ``n`` leans one step left, as there)."""
    if n == 1:
        return x
    left = n // 2
    right = n - 1 - left
    pad = np.zeros(x.shape[:-1] + (1,), dtype=x.dtype)
    c = np.concatenate([pad, np.cumsum(x, axis=-1)], axis=-1)             # c[i] = sum x[:i]
    L = x.shape[-1]
    i = np.arange(L)
    hi = np.clip(i + right + 1, 0, L)
    lo = np.clip(i - left, 0, L)
    return (c[..., hi] - c[..., lo]) / n


def foot_skating_ratio(positions: Any, fps: float, foot_indices: Sequence[int], *,
                       height_threshold: float = 0.05, speed_threshold: float = 0.5,
                       smooth_window: int | None = None, vertical_axis: int = 1,
                       ground: float | str = 0.0) -> FootSkating:
    """Fraction of transitions in which a foot in ground contact slides (module docstring).

    ``positions`` ``[B, T, J, 3]`` in metres (world frame), ``T >= 2``; ``fps`` frames per
    second; ``foot_indices`` the contact joints; thresholds in metres and metres per second.
    """
    x = _positions(positions)
    f = _positive(fps, "fps")
    h_thr = _positive(height_threshold, "height_threshold")
    v_thr = _positive(speed_threshold, "speed_threshold")
    B, T, J, _ = x.shape
    if T < 2:
        raise ValueError(f"foot skating needs at least 2 frames, got {T}")
    feet = _joint_list(foot_indices, J, "foot_indices")
    if isinstance(vertical_axis, bool) or vertical_axis not in (0, 1, 2):
        raise ValueError(f"vertical_axis must be 0, 1 or 2, got {vertical_axis!r}")
    n = default_smooth_window(f) if smooth_window is None else smooth_window
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"smooth_window must be an int >= 1, got {smooth_window!r}")
    horiz = [a for a in range(3) if a != vertical_axis]

    fx = x[:, :, feet]                                                     # [B, T, F, 3]
    height = fx[..., vertical_axis]                                        # [B, T, F]
    if isinstance(ground, str):
        if ground != "min":
            raise ValueError(f"ground must be a number or 'min', got {ground!r}")
        height = height - height.min(axis=(1, 2), keepdims=True)
    else:
        g = float(ground)
        if not math.isfinite(g):
            raise ValueError(f"ground must be finite, got {ground!r}")
        height = height - g
    step = fx[:, 1:][..., horiz] - fx[:, :-1][..., horiz]                  # [B, T-1, F, 2]
    speed = np.sqrt((step ** 2).sum(-1)) * f                               # [B, T-1, F]
    avg = np.moveaxis(_moving_average(np.moveaxis(speed, 1, -1), int(n)), -1, 1)
    contact = (height[:, :-1] < h_thr) & (height[:, 1:] < h_thr)           # [B, T-1, F]
    skating = (contact & (speed > v_thr) & (avg > v_thr)).any(-1)          # [B, T-1]
    per_seq = skating.mean(-1)
    any_contact = contact.any(-1)
    cs = speed[contact]
    return FootSkating(ratio=float(per_seq.mean()), per_sequence=per_seq,
                       contact_ratio=float(any_contact.mean()),
                       mean_contact_speed=float(cs.mean()) if cs.size else float("nan"),
                       smooth_window=int(n))


# ----------------------------------------------------------------------------- bone lengths

@dataclass
class BoneLengthError:
    abs_error: float              # mean |L - L0| over sequences, frames, bones
    rel_error: float              # mean |L - L0| / L0 over bones with L0 > min_rest
    std_over_time: float          # mean over sequences and bones of std_t L
    bones: np.ndarray             # [K] child joint index of each bone
    rest_lengths: np.ndarray      # [K] L0
    per_bone_abs: np.ndarray      # [K] mean |L - L0| over sequences and frames
    per_bone_rel: np.ndarray      # [K] mean |L - L0| / L0 (NaN where L0 <= min_rest)
    per_bone_std: np.ndarray      # [K] mean over sequences of std_t L


def _skeleton_arrays(parents: Any, offsets: Any, skeleton: Any, J: int) -> tuple[np.ndarray, np.ndarray]:
    if skeleton is not None:
        if parents is not None or offsets is not None:
            raise ValueError("give either skeleton or parents + offsets, not both")
        parents, offsets = skeleton.parents, skeleton.offsets
    if parents is None or offsets is None:
        raise ValueError("bone lengths need parents and rest offsets (or a Skeleton)")
    par = np.asarray(parents)
    if par.shape != (J,) or not np.issubdtype(par.dtype, np.integer):
        raise ValueError(f"parents must be {J} ints (one per joint), got shape {par.shape}")
    if np.any(par < -1) or np.any(par >= J) or np.any(par == np.arange(J)):
        raise ValueError("parents must be -1 (root) or another joint's index")
    off = as_array(offsets, "offsets")
    if off.shape != (J, 3):
        raise ValueError(f"offsets must be [{J}, 3], got shape {off.shape}")
    return par.astype(np.int64), off


def bone_lengths(positions: Any, parents: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(bones [K], lengths [B, T, K])``: the child joint of every bone and its length per frame."""
    x = _positions(positions)
    par = np.asarray(parents)
    J = x.shape[2]
    if par.shape != (J,) or not np.issubdtype(par.dtype, np.integer) or np.any(par < -1) or np.any(par >= J):
        raise ValueError(f"parents must be {J} joint indices or -1, got {par.tolist()}")
    bones = np.flatnonzero(par >= 0)
    d = x[:, :, bones] - x[:, :, par[bones]]
    return bones, np.sqrt((d ** 2).sum(-1))


def bone_length_error(positions: Any, parents: Any = None, offsets: Any = None, *,
                      skeleton: Any = None, min_rest: float = 1e-6) -> BoneLengthError:
    """Deviation of every bone's length from its rest length (module docstring).

    ``positions`` ``[B, T, J, 3]``; ``parents`` ``[J]`` (-1 for a root) and ``offsets``
    ``[J, 3]`` rest offsets in the positions' units, or ``skeleton`` (a
    :class:`~motionsynth.data.types.Skeleton`, metres) instead of both.
    """
    x = _positions(positions)
    par, off = _skeleton_arrays(parents, offsets, skeleton, x.shape[2])
    min_rest = float(min_rest)
    if not (math.isfinite(min_rest) and min_rest >= 0):
        raise ValueError(f"min_rest must be >= 0, got {min_rest!r}")
    bones, L = bone_lengths(x, par)
    if bones.size == 0:
        raise ValueError("the skeleton has no bones (every joint is a root)")
    L0 = np.sqrt((off[bones] ** 2).sum(-1))                               # [K]
    dev = np.abs(L - L0)                                                   # [B, T, K]
    per_abs = dev.mean(axis=(0, 1))
    ok = L0 > min_rest
    per_rel = np.full(L0.shape, np.nan)
    per_rel[ok] = per_abs[ok] / L0[ok]
    per_std = L.std(axis=1).mean(axis=0)
    return BoneLengthError(
        abs_error=float(dev.mean()),
        rel_error=float(per_rel[ok].mean()) if ok.any() else float("nan"),
        std_over_time=float(per_std.mean()),
        bones=bones, rest_lengths=L0, per_bone_abs=per_abs, per_bone_rel=per_rel, per_bone_std=per_std)

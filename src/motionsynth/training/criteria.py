"""What selects a checkpoint, and when a run counts as converged.

Selection (``train.monitor``, default ``val/rel_zv``). A long roll-out error such as
``val/pred_mse`` (MSE over every frame after the seed) is won by a model that outputs the
mean pose: after a second or two any real motion is further from the truth than the mean is.
Early stopping on it therefore prefers collapsed weights. :func:`horizon_weighted_ratio`
scores a prediction against zero-velocity (the last seed frame held) *frame by frame*:

    rel_zv = sum_h w_h * e_h / z_h / sum_h w_h,   w_h = 1 / h,   h = 1 .. H frames after the seed

with ``e_h`` the model's and ``z_h`` zero-velocity's MSE at horizon ``h``, each averaged over
the validation windows. Zero-velocity scores exactly 1. The first horizons, where
zero-velocity is nearly exact, carry the most weight (``1/h``: half of the weight lies in the
first ``sqrt(H)`` frames or so), so a constant pose, however good at long horizons, scores
far above 1; the long horizons still count (``sum_{h > 10} 1/h`` is about half the total for
``H = 50``), so a model that is good for one frame and then drifts is not chosen either.

Convergence (:func:`converged`): the selection criterion improved by less than
``rel_tol`` (1 %) of its value over the last ``tail`` (20 %) of the optimiser steps run:
``best(steps <= (1 - tail) * S) - best(all) < rel_tol * |best(steps <= (1 - tail) * S)|``.
A run with no validation before that point cannot show convergence and is ``False``.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

import numpy as np


def horizon_weights(H: int) -> np.ndarray:
    """``w_h = 1 / h`` for ``h = 1 .. H``, normalised to sum to 1."""
    if H < 1:
        raise ValueError(f"horizon_weights needs H >= 1, got {H}")
    w = 1.0 / np.arange(1, H + 1, dtype=np.float64)
    return w / w.sum()


def horizon_weighted_ratio(err: Iterable[float], zero_velocity: Iterable[float], eps: float = 1e-12) -> float:
    """``sum_h w_h e_h / z_h`` (module docstring) from per-horizon MSEs ``err[h-1]`` and
    ``zero_velocity[h-1]``, ``h = 1 .. H``: 1 for zero-velocity itself, lower is better."""
    e, z = np.asarray(list(err), np.float64), np.asarray(list(zero_velocity), np.float64)
    if e.shape != z.shape or e.ndim != 1 or len(e) == 0:
        raise ValueError(f"horizon_weighted_ratio needs two equal 1-D sequences, got {e.shape} and {z.shape}")
    return float((horizon_weights(len(e)) * (e + eps) / (z + eps)).sum())


def converged(history: list[Mapping[str, float]], monitor: str, rel_tol: float = 0.01, tail: float = 0.2) -> bool:
    """Whether ``monitor`` improved by less than ``rel_tol`` (relative) over the last ``tail`` of
    the steps (rows of ``history`` carry ``step`` and ``monitor``; module docstring). Rows marked
    ``selectable: 0`` (a round the model says cannot be chosen, e.g. SkeletonGAN's pose stage) do not count."""
    rows = [h for h in history if monitor in h and math.isfinite(float(h[monitor])) and h.get("selectable", 1)]
    if not rows:
        return False
    last = max(float(h["step"]) for h in rows)
    before = [float(h[monitor]) for h in rows if float(h["step"]) <= (1.0 - tail) * last]
    if not before:
        return False
    b0, b1 = min(before), min(float(h[monitor]) for h in rows)
    return (b0 - b1) < rel_tol * abs(b0)

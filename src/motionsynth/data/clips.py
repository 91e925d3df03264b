"""Resampling and clip windows.

Windows are stored as index tables, not copies of the frames: a row is
``(seq, start, length)`` into a prepared frame array. :func:`gather` turns a
batch of windows into ``[B, L, ...]`` in one vectorised indexing step; indices
outside a sequence are clamped, which pads with its first or last pose (the
VAE-LSTM paper's padding).
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def resample(x: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Resample ``x`` ``[T, ...]`` from ``src_fps`` to ``dst_fps``.

    An integer down-sampling ratio takes every k-th frame (exact, as the
    reference pipelines do); any other ratio interpolates linearly.
    """
    if abs(src_fps - dst_fps) < 1e-6 * src_fps:
        return x
    ratio = src_fps / dst_fps
    k = round(ratio)
    if ratio > 1 and abs(ratio - k) < 1e-6:
        return x[::k]
    n = int(np.floor((len(x) - 1) / ratio + 1e-9)) + 1
    t = np.arange(n) * ratio
    i0 = np.minimum(np.floor(t).astype(np.int64), len(x) - 1)
    i1 = np.minimum(i0 + 1, len(x) - 1)
    w = (t - i0).reshape((-1,) + (1,) * (x.ndim - 1)).astype(x.dtype)
    return x[i0] * (1 - w) + x[i1] * w


def windows(frames: np.ndarray, length: int, stride: int, pad: str = "end", min_frames: int = 1) -> pd.DataFrame:
    """Window table over sequences of ``frames`` ``[S]`` lengths.

    Each sequence gets windows at ``0, stride, 2*stride, ...`` plus one aligned
    to its end, so no tail is lost. A sequence shorter than ``length`` gets one
    window padded with its last pose (``pad='end'``), first pose (``'start'``)
    or both (``'both'``); ``pad='none'`` drops it instead. Sequences shorter
    than ``min_frames`` are dropped. Returns columns ``seq, start, length``
    (``start`` may be negative: padding before the first frame).
    """
    rows_seq, rows_start = [], []
    for s, T in enumerate(np.asarray(frames)):  # over sequences; frames are never looped
        T = int(T)
        if T < min_frames:
            continue
        if T < length:
            if pad == "none":
                continue
            start = {"end": 0, "start": T - length, "both": -((length - T) // 2)}[pad]
            rows_seq.append(s)
            rows_start.append(start)
            continue
        starts = np.arange(0, T - length + 1, stride)
        if starts[-1] != T - length:
            starts = np.append(starts, T - length)
        rows_seq += [s] * len(starts)
        rows_start += starts.tolist()
    return pd.DataFrame({"seq": np.array(rows_seq, np.int64), "start": np.array(rows_start, np.int64),
                         "length": np.full(len(rows_seq), length, np.int64)})


def gather(data: np.ndarray, offsets: np.ndarray, frames: np.ndarray, win: pd.DataFrame,
           every: int = 1, pad_value: float | None = None) -> np.ndarray:
    """Materialise windows: ``data`` ``[N, ...]`` -> ``[B, ceil(L / every), ...]``.

    ``offsets``/``frames`` ``[S]`` locate each sequence in ``data``. Frame
    indices are clamped into their sequence (edge padding). ``pad_value`` instead
    fills the padded frames with a constant: the control signals of a padded
    (standing) stretch are 0, not the last frame's velocity repeated.
    """
    seq = win["seq"].to_numpy()
    L = int(win["length"].iloc[0]) if len(win) else 0
    t = win["start"].to_numpy()[:, None] + np.arange(0, L, every)[None, :]
    last = frames[seq][:, None] - 1
    out = data[offsets[seq][:, None] + np.clip(t, 0, last)]
    if pad_value is not None:
        out = np.array(out, copy=True)
        out[(t < 0) | (t > last)] = pad_value
    return out

"""Maximum mean discrepancy (MMD) between a set of real and a set of generated motions.

What is computed
----------------
The statistic follows the evaluation code of SA-GCN (Yu et al., ECCV 2020,
``evaluation.py``), which c-SkeletonGAN and later action-generation papers reuse:

* Gaussian kernel ``k(x, y) = exp(-||x - y||^2 / b)``, for every bandwidth ``b`` in
  ``DEFAULT_BANDWIDTHS`` = ``10**j`` for ``j = -4, ..., 9`` (14 powers of ten, 1e-4 to 1e9:
  the reference loops ``for j in range(-4, 10)``). Each class keeps the **maximum** over ``b``
  of the statistic below, floored at 0 (the reference starts its running maximum at 0).
* Unbiased estimate of MMD^2 with the diagonal removed, then its square root:
  ``MMD^2_u = 1/(m(m-1)) sum_{i!=j} k(x_i,x_j) + 1/(n(n-1)) sum_{i!=j} k(y_i,y_j) - 2/(mn) sum_{i,j} k(x_i,y_j)``
  (``cross="full"``, Gretton et al. 2012, eq. 3; any m, n; independent of sample order).
  The reference instead forms ``kxx + kyy - 2 kxy`` element-wise and drops its diagonal, so
  its cross term is ``-2/(m(m-1)) sum_{i!=j} k(x_i,y_j)``: it needs ``m == n`` and leaves out
  the pairs ``(x_i, y_i)`` of equal index (Gretton's h-statistic for m = n). Both estimators
  are unbiased; they differ by O(1/m) noise, and the paired one depends on the order of the
  samples. ``cross="paired"`` reproduces the reference.
* ``mode="avg"`` (the reference's ``'avg'``, "MMD_a"): for every frame ``t`` the MMD between
  the sets of frame-``t`` poses (each flattened to ``J*D``), then the mean over frames (for
  each bandwidth; the maximum over bandwidths is taken of that mean).
  ``mode="seq"`` (the reference's ``'joint'``, "MMD_s"): each whole sequence flattened to one
  vector of ``T*J*D``.
* ``velocity=True``: the same on frame-to-frame differences ``x[:, 1:] - x[:, :-1]``
  (``mmd_vel_avg`` / ``mmd_vel_seq``), which sees motion that the pose statistics miss
  (a frozen pose sequence with the right pose distribution scores well on ``avg``).
* Per class: at most ``max_per_class`` (2000, as in the reference) samples of each side, the
  **first ones in input order** (the reference appends samples in order until a class holds
  2000); then the plain mean over classes. Without labels everything is one class (``"all"``).

Negative estimates
------------------
``MMD^2_u`` is unbiased, so it is negative now and then when the two sets are alike (and
always for identical sets with ``cross="full"``). The reference takes ``sqrt`` of it, which
gives NaN (numpy warns, torch does not); in ``avg`` mode one NaN frame makes that bandwidth's
frame-mean NaN, and ``NaN > best`` is False, so the whole bandwidth is silently dropped from
that class's maximum (a class with every bandwidth dropped scores 0). The final mean over
classes never sees a NaN.

* ``negative="clamp"`` (default): ``MMD^2_u`` is clamped at 0 before the square root, cell by
  cell (class, bandwidth, frame); nothing is dropped.
* ``negative="nan"``: reproduces the reference (drops every bandwidth with a negative frame).

Either way nothing is silent: ``MMDResult.n_negative`` counts the (class, frame) cells that
were negative at the bandwidth each class reports (clamped to 0 in them), ``n_negative_any``
the (class, bandwidth, frame) cells negative at any bandwidth, and ``n_dropped`` the
(class, bandwidth) pairs that ``"nan"`` dropped. ``MMDResult.mmd2`` is the unclamped
counterpart: per class the maximum over bandwidths of the frame-mean of ``MMD^2_u`` (it can
be negative), then the mean over classes.

How it is computed
------------------
In float64 with torch, per class. The pairs ``i < j`` of the pooled set ``Z = (X, Y)`` are
exactly the within-X pairs, the within-Y pairs and all cross pairs, so one squared-distance
matrix of ``Z`` serves the three terms, each pair weighted by its coefficient above (the
i<j half only: symmetric terms are counted once with twice the weight). It is formed once
for all frames and bandwidths by one batched matmul ``[z, |z|^2, 1] . [-2z, 1, |z|^2]``
(the expansion ``|x|^2 + |y|^2 - 2 x.y``), after centring each frame on the pooled mean;
pairs closer than 1e-5 of ``2 max |z|^2``, where that expansion cancels, are recomputed
from exact differences (a duplicate gets exactly 0). Then for each bandwidth a block of
``D [frames, pairs]`` costs one scale, one ``exp`` and one matrix-vector product with the
weights. A pair with ``D/b > 700`` counts as ``k = 0`` (float64 ``exp`` is ~30x slower
where it underflows or goes denormal; the reference has ``k <= exp(-700) ~ 1e-304`` there,
so any MMD^2 moves by less than 4e-304, and a cell whose pairs are all that far is exactly
0; rows of such cells are skipped). The one consequence: with ``negative="nan"``, a cell
whose reference value is a sum of denormals (|MMD^2| < 1e-303) is 0 here, where the
reference's rounding may make it negative and drop that bandwidth. Blocks hold about
``2**17`` pairs (frames x pairs, or rows of one frame for large classes) so that they stay
in cache. The result agrees with a float64 run of the reference to ~1e-15 (bench/metrics.py);
the reference itself computes in the dtype of its input (float32 in its scripts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np
import torch

from ..checks import one_of

__all__ = ["DEFAULT_BANDWIDTHS", "MMDResult", "mmd", "mmd_table"]

DEFAULT_BANDWIDTHS: tuple[float, ...] = tuple(10.0 ** j for j in range(-4, 10))
MODES = ("avg", "seq")
NEGATIVE = ("clamp", "nan")
CROSS = ("full", "paired")
ALL = "all"  # the class key when no labels are given

_FAR = 700.0  # pairs with D/b > 700 count as k = 0 (exactly: exp(-700) ~ 1e-304, denormals are slow)
_EXP_FAR = math.exp(-_FAR) * (1 + 1e-9)  # exp output at the floor, with room for 1 ulp
_BUDGET = 1 << 17  # pairs in one working block: 1 MiB of float64, cache-sized
_NEAR = 1e-5  # squared distances below this fraction of 2 max ||z||^2 are recomputed exactly


@dataclass(frozen=True)
class MMDResult:
    """One MMD figure with what went into it.

    value: mean over classes of each class's max-over-bandwidths MMD (the reported figure).
    mmd2: mean over classes of each class's max-over-bandwidths frame-mean MMD^2_u (unclamped).
    per_class / per_class_mmd2: those per class (keys: the labels, or ``"all"``).
    bandwidth: per class, the bandwidth that gave the maximum (None: every one dropped).
    per_bandwidth: per class, the statistic for each bandwidth (NaN where ``"nan"`` dropped it).
    n_negative: (class, frame) cells with MMD^2_u < 0 at the reported bandwidth.
    n_negative_any: (class, bandwidth, frame) cells with MMD^2_u < 0.
    n_cells: (class, frame) cells (classes x frames; frames is 1 for ``seq``).
    n_dropped: (class, bandwidth) pairs dropped by ``negative="nan"``.
    counts: per class, (real samples used, fake samples used).
    """

    value: float
    mmd2: float
    per_class: dict[Any, float]
    per_class_mmd2: dict[Any, float]
    bandwidth: dict[Any, float | None]
    per_bandwidth: dict[Any, np.ndarray]
    n_negative: int
    n_negative_any: int
    n_cells: int
    n_dropped: int
    counts: dict[Any, tuple[int, int]]
    mode: str
    velocity: bool
    negative: str
    cross: str
    bandwidths: tuple[float, ...]

    def __float__(self) -> float:
        return self.value


# ----------------------------------------------------------------------------- validation


def _as_motion(x: Any, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    x = np.asarray(x)
    if x.dtype.kind not in "fiub":
        raise ValueError(f"{name} must be a numeric array; got dtype {x.dtype}")
    if x.ndim not in (3, 4):
        raise ValueError(f"{name} must have shape [N, T, J, D] or [N, T, F]; got shape {x.shape}")
    if 0 in x.shape:
        raise ValueError(f"{name} is empty: shape {x.shape}")
    bad = ~np.isfinite(x)
    if bad.any():
        i = np.argwhere(bad)[0]
        raise ValueError(f"{name} has {int(bad.sum())} non-finite values (NaN or inf); "
                         f"the first at sample {i[0]}, frame {i[1]}")
    return x


def _as_labels(labels: Any, n: int, name: str, data_name: str) -> np.ndarray:
    if isinstance(labels, torch.Tensor):
        labels = labels.detach().cpu().numpy()
    lab = np.asarray(labels)
    if lab.ndim != 1:
        raise ValueError(f"{name} must be 1-D, one label per sample; got shape {lab.shape}")
    if len(lab) != n:
        raise ValueError(f"{name} has {len(lab)} entries but {data_name} has {n} samples")
    if lab.dtype.kind not in "iubUSOf":
        raise ValueError(f"{name} must hold integers or strings; got dtype {lab.dtype}")
    if lab.dtype.kind == "f":
        if not np.isfinite(lab).all() or (lab != np.round(lab)).any():
            raise ValueError(f"{name} holds non-integer floats (NaN or fractions); use integer or string labels")
        lab = lab.astype(np.int64)
    if lab.dtype.kind == "O" and any(v is None or (isinstance(v, float) and math.isnan(v)) for v in lab):
        raise ValueError(f"{name} holds None or NaN labels")
    return lab


def _key(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v


def _groups(labels: np.ndarray | None, n: int, cap: int | None) -> dict[Any, np.ndarray]:
    """Class -> indices of its first ``cap`` samples in input order."""
    if labels is None:
        idx = np.arange(n)
        return {ALL: idx[:cap] if cap else idx}
    out = {}
    for c in np.unique(labels):
        idx = np.flatnonzero(labels == c)
        out[_key(c)] = idx[:cap] if cap else idx
    return out


@dataclass(frozen=True)
class _Prepared:
    real: np.ndarray  # [N, T, F] float64
    fake: np.ndarray  # [M, T, F] float64
    classes: list[Any]
    real_idx: dict[Any, np.ndarray]
    fake_idx: dict[Any, np.ndarray]


def _prepare(real, fake, real_labels, fake_labels, max_per_class) -> _Prepared:
    r = _as_motion(real, "real")
    f = _as_motion(fake, "fake")
    if r.shape[1:] != f.shape[1:]:
        raise ValueError(f"real and fake must have the same per-sample shape [T, ...]; "
                         f"got {r.shape[1:]} and {f.shape[1:]}")
    if (real_labels is None) != (fake_labels is None):
        raise ValueError("give both real_labels and fake_labels, or neither")
    if max_per_class is not None and (not isinstance(max_per_class, (int, np.integer)) or max_per_class < 2):
        raise ValueError(f"max_per_class must be an integer >= 2 or None; got {max_per_class!r}")
    rl = fl = None
    if real_labels is not None:
        rl = _as_labels(real_labels, len(r), "real_labels", "real")
        fl = _as_labels(fake_labels, len(f), "fake_labels", "fake")
        if (rl.dtype.kind in "US") != (fl.dtype.kind in "US"):
            raise ValueError(f"real_labels and fake_labels are of different kinds ({rl.dtype} and {fl.dtype})")
    ri = _groups(rl, len(r), max_per_class)
    fi = _groups(fl, len(f), max_per_class)
    only_r, only_f = sorted(set(ri) - set(fi), key=str), sorted(set(fi) - set(ri), key=str)
    if only_r or only_f:
        raise ValueError(f"real and fake must hold the same classes; only in real: {only_r}, only in fake: {only_f}")
    classes = list(ri)
    for c in classes:
        if len(ri[c]) < 2 or len(fi[c]) < 2:
            raise ValueError(f"class {c!r} has {len(ri[c])} real and {len(fi[c])} fake samples; "
                             f"the unbiased MMD needs at least 2 of each")
    return _Prepared(r.reshape(len(r), r.shape[1], -1).astype(np.float64, copy=False),
                     f.reshape(len(f), f.shape[1], -1).astype(np.float64, copy=False), classes, ri, fi)


def _check_options(mode, negative, cross, bandwidths) -> tuple[float, ...]:
    one_of(mode, "mode", MODES)
    one_of(negative, "negative", NEGATIVE)
    one_of(cross, "cross", CROSS)
    bw = tuple(float(b) for b in bandwidths)
    if not bw or not all(math.isfinite(b) and b > 0 for b in bw):
        raise ValueError(f"bandwidths must be a non-empty list of positive finite numbers; got {bandwidths!r}")
    return bw


# ----------------------------------------------------------------------------- core


def _layout(r0: int, r1: int, m: int, n: int, cross: str, device) -> tuple:
    """Pairs i < j of the pooled set (X then Y) with i in [r0, r1), as indices into the
    [r1 - r0, N - r0 - 1] block of columns r0+1.. and their weights in MMD^2_u."""
    N = m + n
    c0 = r0 + 1
    gi = torch.arange(r0, r1, device=device)[:, None]
    gj = torch.arange(c0, N, device=device)[None, :]
    mask = gj > gi
    if cross == "paired":
        mask &= gj - m != gi  # the reference leaves out the pairs (x_i, y_i)
    ii, jj = torch.nonzero(mask, as_tuple=True)
    gi, gj = ii + r0, jj + c0
    if cross == "full":
        wxy = -2.0 / (m * n)
    else:
        wxy = -2.0 / (m * (m - 1))
    w = torch.full(ii.shape, wxy, dtype=torch.float64, device=device)
    w[gj < m] = 2.0 / (m * (m - 1))
    w[gi >= m] = 2.0 / (n * (n - 1))
    return r0, r1, c0, ii * (N - c0) + jj, gi, gj, w


def _accumulate(D: torch.Tensor, lo: list[float], hi: list[float], w: torch.Tensor, bw: tuple[float, ...],
                out: torch.Tensor) -> None:
    """Add sum_p w_p exp(-D[t, p] / b) to ``out[k, t]`` for every bandwidth ``b = bw[k]``.

    lo / hi: a lower / upper bound of each row of D.
    """
    buf = torch.empty_like(D)
    res = torch.zeros(len(bw), D.shape[0], dtype=D.dtype, device=D.device)
    for k, b in enumerate(bw):
        rows = [i for i, v in enumerate(lo) if v <= _FAR * b]
        if not rows:
            continue  # every pair is far: MMD^2 is exactly 0
        if len(rows) == len(lo):
            x = torch.mul(D, -1.0 / b, out=buf)
        else:
            sel = torch.tensor(rows, device=D.device)
            x = D.index_select(0, sel).mul_(-1.0 / b)
        far = max(hi[i] for i in rows) > _FAR * b
        if far:  # exp is ~30x slower where it underflows or goes denormal: floor, then zero
            x.clamp_(min=-_FAR)
        torch.exp(x, out=x)
        if far:
            torch.nn.functional.threshold_(x, _EXP_FAR, 0.0)
        if len(rows) == len(lo):
            torch.mv(x, w, out=res[k])
        else:
            res[k, sel] = torch.mv(x, w)
    out += res


def _mmd2_cells(Z: torch.Tensor, m: int, bw: tuple[float, ...], cross: str,
                budget: int | None = None) -> torch.Tensor:
    """MMD^2_u for every bandwidth and frame: Z [T, m + n, F] pools X (the first m) and Y -> [B, T].

    The pairs i < j of the pooled set are exactly the within-X pairs, the within-Y pairs and
    every cross pair, so one distance matrix serves all three terms, each pair weighted by its
    term's coefficient.
    """
    T, N, F = Z.shape
    n = N - m
    if cross == "paired" and m != n:
        raise ValueError(f"cross='paired' (the reference's estimator) needs as many real as fake "
                         f"samples per class; got {m} and {n}")
    budget = budget or _BUDGET
    # [z, |z|^2, 1] . [-2z, 1, |z|^2] = |z_i - z_j|^2: the whole expansion in one batched matmul,
    # after centring each frame (distances do not change; the expansion cancels less).
    Za = torch.ones(T, N, F + 2, dtype=Z.dtype, device=Z.device)
    torch.sub(Z, Z.mean(1, keepdim=True), out=Za[..., :F])
    Z = Za[..., :F]
    torch.sum(Z.square(), -1, out=Za[..., F])
    Zb = torch.ones_like(Za)
    torch.mul(Z, -2.0, out=Zb[..., :F])
    Zb[..., F + 1] = Za[..., F]
    Zb = Zb.transpose(1, 2)
    top = Za[..., F].amax(1)  # [T]
    near, hi = (_NEAR * 2.0 * top).tolist(), (4.0 * top).tolist()  # |x-y|^2 <= 2|x|^2 + 2|y|^2
    pairs = N * (N - 1) // 2
    tc = max(1, min(T, budget // pairs))  # frames per block
    layouts, r0 = [], 0  # rows per block: about ``budget`` pairs (all of them when they fit)
    while r0 < N - 1:
        r1 = N if pairs <= budget else min(N, r0 + max(1, budget // (N - r0 - 1)))
        layouts.append(_layout(r0, r1, m, n, cross, Z.device))
        r0 = r1
    out = torch.zeros(len(bw), T, dtype=Z.dtype, device=Z.device)
    for t0 in range(0, T, tc):
        t1 = min(T, t0 + tc)
        for r0, r1, c0, flat, gi, gj, w in layouts:
            G = torch.bmm(Za[t0:t1, r0:r1], Zb[t0:t1, :, c0:])
            D = G.view(t1 - t0, -1).index_select(1, flat)
            lo = D.amin(1).tolist()
            if any(v < near[t0 + i] for i, v in enumerate(lo)):
                # Pairs much closer than their norms (or below 0): the expansion cancelled;
                # recompute them from exact differences.
                tt, pp = torch.nonzero(D < torch.tensor(near[t0:t1], dtype=D.dtype, device=D.device)[:, None],
                                       as_tuple=True)
                D[tt, pp] = (Z[t0 + tt, gi[pp]] - Z[t0 + tt, gj[pp]]).square().sum(-1)
                lo = [max(v, 0.0) for v in lo]
            _accumulate(D, lo, hi[t0:t1], w, bw, out[:, t0:t1])
    return out


def _features(x: np.ndarray, mode: str, velocity: bool) -> np.ndarray:
    """[N, T, F] -> [N, T', F'] as the mode compares them (seq: one 'frame' of T*F)."""
    if velocity:
        if x.shape[1] < 2:
            raise ValueError(f"velocity needs at least 2 frames; got {x.shape[1]}")
        x = x[:, 1:] - x[:, :-1]
    if mode == "seq":
        x = x.reshape(len(x), 1, -1)
    return x


def _compute(p: _Prepared, mode: str, velocity: bool, bw: tuple[float, ...], negative: str, cross: str,
             device) -> MMDResult:
    dev = torch.device(device) if device is not None else torch.device("cpu")
    per_class, per_class_mmd2, chosen, per_bw, counts = {}, {}, {}, {}, {}
    n_neg = n_neg_any = n_cells = n_dropped = 0
    for c in p.classes:
        ri, fi = p.real_idx[c], p.fake_idx[c]
        Z = np.concatenate([_features(p.real[ri], mode, velocity), _features(p.fake[fi], mode, velocity)])
        Z = torch.from_numpy(np.ascontiguousarray(Z.transpose(1, 0, 2))).to(dev)  # [T', m + n, F']
        m2 = _mmd2_cells(Z, len(ri), bw, cross).cpu().numpy()  # [B, T']
        neg = m2 < 0
        root = np.sqrt(np.maximum(m2, 0.0))
        stat = root.mean(1)  # [B]
        if negative == "nan":
            dropped = neg.any(1)
            stat = np.where(dropped, np.nan, stat)
            n_dropped += int(dropped.sum())
        valid = ~np.isnan(stat)
        if valid.any() and np.nanmax(stat) > 0:
            k = int(np.nanargmax(stat))
            per_class[c], chosen[c] = float(stat[k]), bw[k]
            n_neg += int(neg[k].sum())
        elif valid.any():  # every kept bandwidth gave exactly 0
            k = int(np.flatnonzero(valid)[0])
            per_class[c], chosen[c] = 0.0, bw[k]
            n_neg += int(neg[k].sum())
        else:
            per_class[c], chosen[c] = 0.0, None
        per_class_mmd2[c] = float(m2.mean(1).max())
        per_bw[c] = stat
        counts[c] = (len(ri), len(fi))
        n_neg_any += int(neg.sum())
        n_cells += m2.shape[1]
    return MMDResult(
        value=float(np.mean(list(per_class.values()))), mmd2=float(np.mean(list(per_class_mmd2.values()))),
        per_class=per_class, per_class_mmd2=per_class_mmd2, bandwidth=chosen, per_bandwidth=per_bw,
        n_negative=n_neg, n_negative_any=n_neg_any, n_cells=n_cells, n_dropped=n_dropped, counts=counts,
        mode=mode, velocity=velocity, negative=negative, cross=cross, bandwidths=bw)


# ----------------------------------------------------------------------------- public API


def mmd(real, fake, real_labels=None, fake_labels=None, *, mode: str = "avg", velocity: bool = False,
        max_per_class: int | None = 2000, bandwidths: Iterable[float] = DEFAULT_BANDWIDTHS,
        negative: str = "clamp", cross: str = "full", device: str | torch.device | None = None) -> MMDResult:
    """MMD between real motions [N, T, J, D] (or [N, T, F]) and fake ones [M, T, ...].

    real_labels [N] / fake_labels [M]: class labels (ints or strings), both or neither; the
    figure is the mean over classes. mode: "avg" (per frame, then mean over frames) or "seq"
    (whole sequences). velocity: compare frame-to-frame differences instead of poses.
    max_per_class: the first this many samples of each class and side (None: all).
    negative: "clamp" (MMD^2_u clamped at 0) or "nan" (the reference: drop the bandwidth).
    cross: "full" (standard unbiased estimator) or "paired" (the reference's; needs equal
    counts per class). See the module docstring for the exact definitions.
    """
    bw = _check_options(mode, negative, cross, bandwidths)
    return _compute(_prepare(real, fake, real_labels, fake_labels, max_per_class), mode, velocity, bw,
                    negative, cross, device)


def mmd_table(real, fake, real_labels=None, fake_labels=None, *, return_results: bool = False,
              **kwargs) -> Mapping[str, float] | Mapping[str, MMDResult]:
    """The four figures ``mmd_avg``, ``mmd_seq``, ``mmd_vel_avg``, ``mmd_vel_seq`` (inputs checked once).

    kwargs: as for :func:`mmd` (not mode or velocity). return_results: give the MMDResult
    objects rather than their values.
    """
    for k in ("mode", "velocity"):
        if k in kwargs:
            raise ValueError(f"mmd_table computes every {k}; do not pass {k}=")
    max_per_class = kwargs.pop("max_per_class", 2000)
    negative = kwargs.pop("negative", "clamp")
    cross = kwargs.pop("cross", "full")
    device = kwargs.pop("device", None)
    bw = _check_options("avg", negative, cross, kwargs.pop("bandwidths", DEFAULT_BANDWIDTHS))
    if kwargs:
        raise ValueError(f"unknown arguments: {sorted(kwargs)}")
    p = _prepare(real, fake, real_labels, fake_labels, max_per_class)
    out = {}
    for name, mode, vel in (("mmd_avg", "avg", False), ("mmd_seq", "seq", False),
                            ("mmd_vel_avg", "avg", True), ("mmd_vel_seq", "seq", True)):
        res = _compute(p, mode, vel, bw, negative, cross, device)
        out[name] = res if return_results else res.value
    return out

"""MMD (avg and seq) against the reference algorithm: time, speedup and agreement.

Usage: python bench/metrics.py [--threads 2] [--repeats 7]

Data: 1,000 real vs 1,000 "fake" samples of 50 frames x 15 joints x 2, in 10 classes of 100
each. Real: windows of Human3.6M bench2d clips (data/processed/h36m/bench2d, the first 50
frames of seeded draws from windows_glocal.parquet); fake: a second, disjoint draw of the
same classes plus Gaussian noise of 5% of each coordinate's spread. Without that folder
(a fresh clone before `dvc repro`): seeded random walks, and the JSON lines say so.

The reference is a numpy re-implementation of SA-GCN's evaluation.py (which c-SkeletonGAN
reuses) with its loop structure: samples grouped per class in order (first 2000), then per
class, per bandwidth 10**j (j = -4..9), per frame (avg) the three kernel matrices rebuilt from
explicit differences, ``kxx + kyy - 2 kxy`` with its diagonal removed, sqrt, a running max
that starts at 0 (so NaNs from negative estimates drop out), and the mean over classes. It
runs once, on float64 data. Ours runs with ``cross="paired", negative="nan"`` (the
reference's estimator and NaN handling) for the difference, timed as the median of
``--repeats`` runs after 2 warm-ups on ``--threads`` threads; the default estimator
(``cross="full"``, clamp) is timed and shown beside it. Process CPU seconds are printed
beside the wall times (``cpu_s``): on a busy machine they say what the work costs, and the
2-thread wall time suffers most (an OpenMP team waits for a thread the other load preempts);
``load_avg_1min`` tells how busy it was.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch
from _util import ROOT, emit, median_time

from motionsynth.metrics.mmd import mmd

N_CLASSES, PER_CLASS, FRAMES, JOINTS, DIMS = 10, 100, 50, 15, 2


# ----------------------------------------------------------------------------- data


def bench_data(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(real [1000, 50, 15, 2], fake [1000, 50, 15, 2], labels [1000], description)."""
    rng = np.random.default_rng(seed)
    labels = np.repeat(np.arange(N_CLASSES), PER_CLASS)
    root = ROOT / "data" / "processed" / "h36m" / "bench2d"
    if (root / "pose.npy").exists() and (root / "windows_glocal.parquet").exists():
        import pandas as pd

        pose = np.load(root / "pose.npy", mmap_mode="r")
        meta = pd.read_parquet(root / "meta.parquet")
        win = pd.read_parquet(root / "windows_glocal.parquet")
        win = win[win["length"] >= FRAMES].reset_index(drop=True)
        lab = meta["label"].to_numpy()[win["seq"].to_numpy()]
        real, fake = [], []
        for c in range(N_CLASSES):
            pick = rng.permutation(np.flatnonzero(lab == c))[: 2 * PER_CLASS]
            clips = np.stack([pose[o: o + FRAMES] for o in
                              meta["offset"].to_numpy()[win["seq"].to_numpy()[pick]] + win["start"].to_numpy()[pick]])
            real.append(clips[:PER_CLASS])
            fake.append(clips[PER_CLASS:])
        real = np.concatenate(real).astype(np.float64)
        fake = np.concatenate(fake).astype(np.float64)
        fake += rng.normal(size=fake.shape) * 0.05 * real.reshape(-1, JOINTS, DIMS).std(0)
        return real, fake, labels, "h36m bench2d windows (fake: disjoint draw + 5% noise)"
    shape = (N_CLASSES * PER_CLASS, FRAMES, JOINTS, DIMS)
    offs = np.repeat(rng.normal(size=(N_CLASSES, 1, JOINTS, DIMS)) * 3, PER_CLASS, axis=0)
    real = offs + np.cumsum(rng.normal(size=shape) * 0.1, axis=1)
    fake = offs + np.cumsum(rng.normal(size=shape) * 0.12, axis=1)
    return real, fake, labels, "seeded random walks (h36m bench2d not prepared)"


# ----------------------------------------------------------------------------- reference


def _ref_rkhs(s1: np.ndarray, s2: np.ndarray, bandwidth) -> float:
    """The reference's two-set statistic: explicit differences, paired diagonal removed, sqrt."""
    m = s1.shape[0]

    def kernel(a, b):
        return np.exp(-np.sum((a[:, None, :] - b) ** 2, axis=-1) / bandwidth)

    h = kernel(s1, s1) + kernel(s2, s2) - 2 * kernel(s1, s2)
    return np.sqrt(np.sum(h - np.diag(np.diag(h))) / (m * (m - 1)))


def _ref_sequence(s1: np.ndarray, s2: np.ndarray, bandwidth, mode: str) -> float:
    _, seq_len, dim = s1.shape
    if mode == "avg":
        acc = 0.0
        for t in range(seq_len):
            acc += _ref_rkhs(s1[:, t, :], s2[:, t, :], bandwidth) / seq_len
        return acc
    return _ref_rkhs(s1.reshape(-1, dim * seq_len), s2.reshape(-1, dim * seq_len), bandwidth)


def reference_mmd(gen: np.ndarray, real: np.ndarray, labels: np.ndarray, mode: str) -> tuple[float, list[float]]:
    """gen, real [N, T, F] index-aligned, labels [N] in 0..C-1 (one label array for both)."""
    n_cls = int(labels.max()) + 1
    gen_by, real_by = [[] for _ in range(n_cls)], [[] for _ in range(n_cls)]
    for i in range(len(gen)):
        c = labels[i]
        if len(gen_by[c]) < 2000:
            gen_by[c].append(gen[i])
            real_by[c].append(real[i])
    results = []
    with np.errstate(invalid="ignore"):  # sqrt of a negative estimate: NaN, as in the reference
        for c in range(n_cls):
            g, r = np.asarray(gen_by[c]), np.asarray(real_by[c])
            best = 0
            for j in range(-4, 10):
                v = _ref_sequence(g, r, 10 ** j, mode)
                if v > best:
                    best = v
            results.append(best)
    return float(np.mean(results)), [float(v) for v in results]


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2, help="torch threads for our implementation (default 2)")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs of ours (median reported)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)

    real, fake, labels, source = bench_data()
    r3, f3 = real.reshape(len(real), FRAMES, -1), fake.reshape(len(fake), FRAMES, -1)
    shape = f"{N_CLASSES}x{PER_CLASS} vs {N_CLASSES}x{PER_CLASS}, {FRAMES}x{JOINTS}x{DIMS}"
    for mode in ("avg", "seq"):
        t0, c0 = time.perf_counter(), time.process_time()
        ref_value, ref_per_class = reference_mmd(f3, r3, labels, mode)
        t_ref, c_ref = time.perf_counter() - t0, time.process_time() - c0

        def ours(cross="paired", negative="nan"):
            return mmd(real, fake, labels, labels, mode=mode, cross=cross, negative=negative)

        res = ours()
        diff = max([abs(res.value - ref_value)]
                   + [abs(res.per_class[c] - v) for c, v in enumerate(ref_per_class)])
        t_ours = median_time(ours, repeats=args.repeats, warmup=2)
        c0 = time.process_time()
        ours()
        c_ours = time.process_time() - c0
        default = ours("full", "clamp")
        t_default = median_time(lambda: ours("full", "clamp"), repeats=args.repeats, warmup=2)
        emit(f"mmd_{mode}_reference", t_ref, "s", data=source, shape=shape,
             impl="SA-GCN evaluation.py loops, numpy float64, timed once", cpu_s=round(c_ref, 3),
             load_avg_1min=round(os.getloadavg()[0], 2))
        emit(f"mmd_{mode}", t_ours, "s", threads=args.threads, settings="cross=paired, negative=nan",
             cpu_s_one_run=round(c_ours, 4),
             default_settings_s=round(t_default, 4))
        by_threads = {}
        for th in (1, 2):                                # issue 12: the 1- and 2-thread figures side by side
            torch.set_num_threads(th)
            by_threads[th] = median_time(lambda: ours("full", "clamp"), repeats=args.repeats, warmup=2)
        torch.set_num_threads(args.threads)
        emit(f"mmd_{mode}_by_threads", by_threads[1], "s (1 thread)", two_threads_s=round(by_threads[2], 4),
             settings="cross=full, negative=clamp (the suite's)", load_avg_1min=round(os.getloadavg()[0], 2))
        emit(f"mmd_{mode}_speedup", t_ref / t_ours, "x", target=50, threads=args.threads,
             max_abs_diff=float(f"{diff:.3e}"), diff_target=1e-6, value_reference=ref_value,
             value_ours=res.value, value_default_estimator=default.value,
             n_dropped_bandwidths=res.n_dropped, n_negative_cells_default=default.n_negative_any)


if __name__ == "__main__":
    main()

"""Which reading of GlocalNet's "Euclidean distance per frame" (Table 4) gives acLSTM-sized numbers?

Usage: python bench/acLSTM_units_check.py [--stride 30] [--margin 10] [--seed-frames 10]

The lead to confirm: the error is ONE L2 norm of the whole root-relative pose-vector difference
per frame (all joints flattened), in acLSTM's units (BVH units x 0.01, all 57 joints of the
CMU skeleton including End Sites, 120 fps source). Under that reading a zero-velocity
predictor should score about Indian dance 0.64 ... 2.50 and martial arts 0.36 ... 1.60 at
80 ... 640 ms, the same magnitudes as the published acLSTM rows.

Data: ``data/raw/cmu_aclstm.zip`` (or the team's DVC store), folders ``indian`` and ``martial``
(7 and 8 files, 120 fps). Each file is parsed with :func:`motionsynth.data.bvh.parse_bvh` and its
positions computed with ``.positions()`` (BVH file units, End Sites included), then x 0.01.
All files share ``standard.bvh``'s hierarchy and offsets (checked below), the skeleton
acLSTM's own preparation uses.

acLSTM's own data preparation (papagina/Auto_Conditioned_RNN_motion, ``code/read_bvh.py`` and
``pytorch_train_aclstm.py``; facts only): forward kinematics of the 57-joint standard skeleton
(End Sites included), every joint but the hip stored relative to the hip, the hip itself in
world coordinates with its horizontal mean over the file subtracted (height kept), everything
x 0.01; frames sampled every ``fps / 30`` source frames (it trains at 30 fps), the hip's x/z
fed to the network as frame-to-frame differences; the first and last 10 frames of a file are
never sampled ("sometimes noisy"). Its frame vector is therefore root-relative except for the
hip's own row: variant ``aclstm_vector`` below scores that vector as is.

Zero-velocity prediction and seeds (deterministic, no randomness): in every file, seed windows
end at source frames ``s = margin + seed_frames - 1 + i * stride`` (i = 0, 1, ...) as long as
``s + 77 + margin < T`` (77 = the 640 ms horizon at 120 fps); the seed is the ``seed_frames``
frames ending at ``s``, the prediction repeats frame ``s`` for the next 77 frames, and the
ground truth is the real continuation. Only the last seed frame matters to a zero-velocity
predictor; ``seed_frames`` fixes where the first window may start. Every window counts once
(files contribute in proportion to their length). The Euclidean error is computed with
:func:`motionsynth.metrics.errors.euclidean_per_frame_values` (horizon h = round(h * fps / 1000)
frames after the last seed frame).

Variants printed (rows): ``lead`` (root-relative, flat L2, 57 joints, 120 fps), ``aclstm_vector``
(acLSTM's stored frame vector), ``global`` (no root subtraction), ``mean_per_joint`` (mean of
per-joint distances instead of one flat norm), ``no_end_sites`` (43 joints), ``30fps_round`` /
``30fps_interp`` (source down-sampled by 4 as acLSTM trains), and the seed-sampling
sensitivity of the lead (strides 10/60/120 frames, per-file weighting). Runtime ~5 s, 1 thread.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from motionsynth.data.archive import Archive  # noqa: E402
from motionsynth.data.bvh import parse_bvh  # noqa: E402
from motionsynth.metrics.errors import (  # noqa: E402
    DEFAULT_HORIZONS_MS, euclidean_per_frame_values, horizon_frames, prediction_error_values, summarise,
)

CLASSES = {"indian": "CMU Indian dance", "martial": "CMU martial arts"}
LEAD = {"indian": [0.64, 1.16, 1.62, 1.93, 2.18, 2.35, 2.45, 2.50],
        "martial": [0.36, 0.62, 0.86, 1.03, 1.19, 1.33, 1.46, 1.60]}
SCALE = 0.01  # acLSTM: BVH units x 0.01
FPS = 120.0


def archive_path() -> Path:
    local = ROOT / "data" / "raw" / "cmu_aclstm.zip"
    if local.exists():
        return local
    import yaml

    md5 = yaml.safe_load((ROOT / "data" / "raw" / "cmu_aclstm.zip.dvc").read_text())["outs"][0]["md5"]
    path = ROOT.parent / "shared" / "dvc-store" / "files" / "md5" / md5[:2] / md5[2:]
    if not path.exists():
        raise SystemExit(f"cmu_aclstm.zip is neither in data/raw nor in the DVC store ({path}); run `dvc pull`")
    return path


def published(dataset: str, method: str = "acLSTM") -> list[float] | None:
    path = ROOT.parent / "shared" / "papers" / "published_results.csv"
    if not path.exists():
        return None
    rows = {r["column"]: float(r["value"]) for r in csv.DictReader(path.open())
            if r["paper"] == "battan2021_glocalnet" and r["table"] == "Table 4"
            and r["dataset"] == dataset and r["method"] == method}
    try:
        return [rows[f"{h}ms"] for h in DEFAULT_HORIZONS_MS]
    except KeyError:
        return None


def load(arch: Archive, cls: str) -> tuple[list[np.ndarray], np.ndarray, list[str]]:
    """Positions [T, 57, 3] x 0.01 per file, the is_end mask, the member names."""
    template = parse_bvh(arch.read("standard.bvh"), "standard.bvh")
    out, names = [], []
    for m in sorted(n for n in arch.names if n.startswith(cls + "/") and n.endswith(".bvh")):
        b = parse_bvh(arch.read(m), m)
        if b.names != template.names or not np.allclose(b.offsets, template.offsets):
            raise SystemExit(f"{m}: hierarchy differs from standard.bvh (acLSTM assumes one skeleton)")
        if abs(b.fps - FPS) > 1e-3:
            raise SystemExit(f"{m}: {b.fps:g} fps, expected {FPS:g}")
        out.append(b.positions(dtype=np.float64) * SCALE)
        names.append(m)
    return out, template.is_end.copy(), names


def aclstm_vector(p: np.ndarray) -> np.ndarray:
    """acLSTM's stored frame: joints relative to the hip, the hip itself world minus its
    horizontal mean over the file (height kept)."""
    q = p - p[:, :1]
    c = p[:, 0].mean(0)
    c[1] = 0.0
    q[:, 0] = p[:, 0] - c
    return q


def windows(seqs: list[np.ndarray], fps: float, seed_frames: int, stride: int,
            margin: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-velocity (pred, gt) windows ``[N, seed_frames + K, J, D]`` and the file id of each
    window. ``pred`` is a read-only broadcast view (the last seed frame repeated), not a copy."""
    K = int(horizon_frames(DEFAULT_HORIZONS_MS, fps)[-1]) + 1  # +1 frame for interpolation
    gts, ids = [], []
    for f, p in enumerate(seqs):
        ends = np.arange(margin + seed_frames - 1, len(p) - K - margin, stride)
        if ends.size:
            gts.append(p[ends[:, None] + np.arange(-seed_frames + 1, K + 1)[None]])   # [N, S + K, J, D]
            ids.append(np.full(len(ends), f))
    gt = np.concatenate(gts)
    last = gt[:, seed_frames - 1:seed_frames]
    pred = np.concatenate([gt[:, :seed_frames], np.broadcast_to(last, (len(gt), K) + gt.shape[2:])], axis=1)
    return pred, gt, np.concatenate(ids)


def score(seqs, fps, *, root_index, seed_frames, stride, margin, joints=None,
          frame_mapping="round", per_file=False, mean_per_joint=False):
    """(mean over windows [H], per-window values [N, H], N) of the zero-velocity error."""
    pred, gt, ids = windows(seqs, fps, seed_frames, stride, margin)
    if mean_per_joint:  # contrast: the mean of per-joint distances (not the lead's definition)
        idx = seed_frames - 1 + horizon_frames(DEFAULT_HORIZONS_MS, fps)
        v = prediction_error_values(pred, gt, idx.tolist(), "pose", root_index=root_index,
                                    reduction="mpjpe", frame_base=0)
    else:
        v = euclidean_per_frame_values(pred, gt, fps, root_index=root_index, seed_frames=seed_frames,
                                       joints=joints, frame_mapping=frame_mapping)
    if per_file:
        return np.stack([v[ids == f].mean(0) for f in np.unique(ids)]).mean(0), v, len(v)
    return v.mean(0), v, len(v)


def fmt(xs) -> str:
    return " ".join(f"{x:5.2f}" for x in xs)


def rel_dev(a, b) -> float:
    return float(np.mean(np.abs(np.asarray(a) / np.asarray(b) - 1)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stride", type=int, default=30, help="source frames between seed windows (120 fps)")
    ap.add_argument("--margin", type=int, default=10, help="frames skipped at each end of a file")
    ap.add_argument("--seed-frames", type=int, default=10, help="seed length in source frames")
    args = ap.parse_args()
    t0 = time.perf_counter()
    arch = Archive(archive_path())
    common = dict(seed_frames=args.seed_frames, stride=args.stride, margin=args.margin)
    summary = {}
    print(f"zero-velocity, Euclidean error per frame at {', '.join(map(str, DEFAULT_HORIZONS_MS))} ms; "
          f"seeds every {args.stride} frames, {args.margin}-frame margins, {args.seed_frames}-frame seeds")
    for cls, dataset in CLASSES.items():
        seqs, is_end, names = load(arch, cls)
        J = seqs[0].shape[1]
        no_end = np.flatnonzero(~is_end)
        sub4 = [p[::4] for p in seqs]                                      # acLSTM's 30 fps
        c30 = dict(seed_frames=max(1, args.seed_frames // 4), stride=max(1, args.stride // 4),
                   margin=max(1, args.margin // 4))
        lead_m, lead_v, n = score(seqs, FPS, root_index=0, **common)
        rows = [
            ("lead: root-rel, flat L2, 57 j, 120 fps", lead_m),
            ("aclstm_vector (hip row = centred world)", score([aclstm_vector(p) for p in seqs], FPS,
                                                             root_index=None, **common)[0]),
            ("global positions (no root subtraction)", score(seqs, FPS, root_index=None, **common)[0]),
            ("mean_per_joint (root-rel)", score(seqs, FPS, root_index=0, mean_per_joint=True, **common)[0]),
            (f"no_end_sites ({len(no_end)} joints)", score(seqs, FPS, root_index=0, joints=no_end, **common)[0]),
            ("30fps_round (source[::4])", score(sub4, 30.0, root_index=0, **c30)[0]),
            ("30fps_interp (source[::4])", score(sub4, 30.0, root_index=0, frame_mapping="interpolate", **c30)[0]),
        ]
        for st in (10, 60, 120):
            rows.append((f"lead, stride {st}", score(seqs, FPS, root_index=0, seed_frames=args.seed_frames,
                                                      stride=st, margin=args.margin)[0]))
        rows.append(("lead, per-file weighting", score(seqs, FPS, root_index=0, per_file=True, **common)[0]))
        pub = published(dataset)
        ci = summarise(lead_v)
        print(f"\n== {dataset}: {len(names)} files, {J} joints, {n} seed windows (lead recipe) ==")
        print(f"{'horizon (ms)':44s} {' '.join(f'{h:5d}' for h in DEFAULT_HORIZONS_MS)}   vs lead")
        print(f"{'lead values (to confirm)':44s} {fmt(LEAD[cls])}")
        if pub:
            print(f"{'published acLSTM (GlocalNet Table 4)':44s} {fmt(pub)}")
        for name, vals in rows:
            print(f"{name:44s} {fmt(vals)}   {100 * rel_dev(vals, LEAD[cls]):5.1f}%")
        print(f"{'lead 95% CI half-width (windows overlap)':44s} {fmt(ci['ci_high'] - ci['mean'])}")
        summary[cls] = dict(lead=lead_m, pub=pub, rows=dict(rows))
    print("\n== verdict ==")
    names = list(summary["indian"]["rows"])
    both = {nm: np.mean([rel_dev(summary[c]["rows"][nm], LEAD[c]) for c in summary]) for nm in names}
    for nm in sorted(both, key=both.get)[:3]:
        print(f"closest to the lead values over both classes: {nm!r}: mean |relative deviation| "
              f"{100 * both[nm]:.1f}%")
    ok = True
    for cls, s in summary.items():
        d = rel_dev(s["lead"], LEAD[cls])
        ok &= d < 0.10
        r = s["rows"]
        mpj = r["mean_per_joint (root-rel)"][-1] / s["lead"][-1]
        glo = r["global positions (no root subtraction)"][-1] / s["lead"][-1]
        line = (f"{CLASSES[cls]}: lead recipe {100 * d:.1f}% from the lead values; at 640 ms mean-per-joint "
                f"is {mpj:.2f}x and global {glo:.2f}x the lead recipe")
        if s["pub"]:
            line += (f"; published acLSTM / our zero-velocity = {fmt(np.asarray(s['pub']) / s['lead'])} "
                     f"(same magnitude: acLSTM is about as good as a frozen pose here)")
        print(line)
    print("CONFIRMED (same magnitudes, within 10%): one flat L2 norm per frame of the root-relative "
          "57-joint pose difference in BVH units x 0.01, horizons counted in 120-fps frames after the last "
          "seed frame" if ok else "NOT CONFIRMED: the lead recipe is more than 10% from the lead values")
    print(f"runtime {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()

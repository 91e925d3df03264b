"""The ``csgan`` protocol of ``h36m`` is the c-SkeletonGAN / SA-GCN reference, pinned against an
independent implementation of the reference's steps written here.

The reference (SA-GCN ``util/data_utils.py: create_2d_data_corrected``) on the 3-D positions:

2. project every frame of every sequence through camera ``55011271`` alone (3d-pose-baseline's
   radial + tangential model) and keep the hip's camera-frame depth;
3. centre every frame on the hip's 2-D position;
4. ``avg_z`` = the mean hip depth over every 50 Hz frame of every training subject (S1, S5, S7, S8, S9);
5. scale every frame by ``z_hip / avg_z``;
6. mean and ``np.std`` (ddof 0) per dimension over every 50 Hz frame of the training subjects, the
   15 joints (17 named minus Hip and Neck/Nose); normalise by ``(x - mean) / std``.

Below, that is done from the archive's raw HDF5 files with h5py and plain numpy loops, sharing no
code with the library (the camera file is parsed here too, the camera picked by its name), on real
items: two takes of each of S1 and S5 (one becomes the validation carve-out, which the statistics
must include), S6's (unused) and S11's (test, never in the statistics).
"""

from __future__ import annotations

import io
import zipfile

import h5py
import numpy as np
import pandas as pd
import pytest
from conftest import archive_path, dataset_cfg

from motionsynth.data.ingest import ingest
from motionsynth.data.normalise import Normaliser
from motionsynth.data.prepare import prepare
from motionsynth.data.splits import split_dataset

CAMERA = "55011271"
TRAIN_SUBJECTS = (1, 5, 7, 8, 9)
SUBJECTS = [1, 5, 6, 11]
ACTION = "Posing"                       # the smallest files: 8 takes of 992 to 2,000-odd frames
NAMED = {0: "Hip", 1: "RHip", 2: "RKnee", 3: "RFoot", 6: "LHip", 7: "LKnee", 8: "LFoot", 12: "Spine",
         13: "Thorax", 14: "Neck/Nose", 15: "Head", 17: "LShoulder", 18: "LElbow", 19: "LWrist",
         25: "RShoulder", 26: "RElbow", 27: "RWrist"}
KEPT = [j for j, n in NAMED.items() if n not in ("Hip", "Neck/Nose")]   # 15 source joints, in source order
RTOL = 1e-6                             # the statistics: the target
RTOL_FRAME = 1e-5                       # single frames: float32 storage (test_normalised_frames_equal_the_reference)


def reference_camera(z: zipfile.ZipFile, subject: int) -> dict[str, np.ndarray]:
    """The subject's camera named ``CAMERA``: R world-to-camera (cameras.h5 stores its transpose), T, f, c, k, p."""
    with h5py.File(io.BytesIO(z.read("h36m/cameras.h5")), "r") as hf:
        for c in range(1, 5):
            g = hf[f"subject{subject}/camera{c}"]
            if "".join(chr(int(x)) for x in np.ravel(g["Name"][()])) == CAMERA:
                cam = {k: np.ravel(g[k][()]).astype(np.float64) for k in ("T", "f", "c", "k", "p")}
                cam["R"] = np.asarray(g["R"][()], np.float64).T
                return cam
    raise AssertionError(f"no camera {CAMERA} for S{subject}")


def reference_project(frame_mm: np.ndarray, cam: dict[str, np.ndarray]) -> tuple[np.ndarray, float]:
    """One frame ``[32, 3]`` (world mm) -> pixels ``[32, 2]`` and the hip's camera depth (mm), joint by joint."""
    uv = np.empty((len(frame_mm), 2))
    hip_depth = None
    k1, k2, k3 = cam["k"]
    p1, p2 = cam["p"]
    for j, P in enumerate(frame_mm):
        X = cam["R"] @ (P - cam["T"])
        x, y = X[0] / X[2], X[1] / X[2]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        tan = p1 * y + p2 * x
        uv[j, 0] = cam["f"][0] * (x * (radial + tan) + p2 * r2) + cam["c"][0]
        uv[j, 1] = cam["f"][1] * (y * (radial + tan) + p1 * r2) + cam["c"][1]
        if j == 0:
            hip_depth = X[2]
    return uv, hip_depth


@pytest.fixture(scope="module")
def reference():
    """``{take: (centred uv [T, 32, 2], hip depth [T])}`` of every take of ``ACTION`` of ``SUBJECTS``, camera ``CAMERA``."""
    out = {}
    with zipfile.ZipFile(archive_path("h36m")) as z:
        for s in SUBJECTS:
            cam = reference_camera(z, s)
            for name in sorted(z.namelist()):
                stem = name.rsplit("/", 1)[-1][:-3]
                if not (name.startswith(f"h36m/S{s}/MyPoses/3D_positions/") and stem.split(" ")[0] == ACTION):
                    continue
                with h5py.File(io.BytesIO(z.read(name)), "r") as hf:
                    frames = np.asarray(hf["3D_positions"][()], np.float64).T.reshape(-1, 32, 3)
                uv = np.empty((len(frames), 32, 2))
                depth = np.empty(len(frames))
                for t, f in enumerate(frames):
                    uv[t], depth[t] = reference_project(f, cam)
                take = f"S{s}_{ACTION}" + ("_" + stem.split(" ")[1] if " " in stem else "")
                out[take] = (uv - uv[:, :1], depth)                  # step 3: centred on the hip
    return out


@pytest.fixture(scope="module")
def ours(tmp_path_factory):
    """The pipeline's ingest -> prepare -> split of the same items, with the dataset's own config."""
    tmp = tmp_path_factory.mktemp("csgan")
    cfg = dataset_cfg("h36m")
    cfg["reader"] = {**cfg["reader"], "actions": [ACTION], "subjects": SUBJECTS}
    ingest(cfg, archive_path("h36m"), tmp / "i", progress=False)
    prepare(tmp / "i", tmp / "p", {"bench2d": cfg["prepare"]["representations"]["bench2d"]})
    summary = split_dataset(tmp / "p", tmp / "s", cfg["split"], seed=0)
    return tmp / "p/bench2d", tmp / "s/bench2d", summary


def test_statistics_equal_the_reference(reference, ours):
    rep, spl, summary = ours
    train = [k for k in reference if int(k.split("_")[0][1:]) in TRAIN_SUBJECTS]
    avg_z = np.mean(np.concatenate([reference[k][1] for k in train]))                        # step 4
    scaled = np.concatenate([reference[k][0] * (reference[k][1] / avg_z)[:, None, None] for k in train])  # step 5
    mean, std = scaled[:, KEPT].mean(0), scaled[:, KEPT].std(0)                                # step 6
    stats = np.load(spl / "csgan_stats.npz")
    # the val carve-out is in the statistics: every 50 Hz frame of the four S1 / S5 takes
    table = pd.read_csv(spl / "csgan.csv")
    assert set(table.split[table.sequence_id.str.contains(f"@{CAMERA}")]) == {"train", "val", "test", "unused"}
    assert list(stats["stats_over"]) == ["train", "val"]
    assert int(stats["stats_frames"]) == len(scaled) == sum(len(reference[k][1]) for k in train)
    rel = {"avg_z": abs(float(stats["mean_depth"]) * 1000 / avg_z - 1),                      # ours in metres
           "mean": np.max(np.abs(stats["pose_mean"] / mean - 1)),
           "std": np.max(np.abs(stats["pose_std"] / std - 1))}
    print(f"\ncsgan statistics against the reference: avg_z {avg_z:.3f} mm, max relative difference {rel}")
    assert max(rel.values()) < RTOL, rel
    # the other cameras are unused, and say so
    reasons = summary["bench2d/csgan"]["unused_reasons"]
    assert reasons["subject S6 is in neither train nor test"] == 4 * 2 * 3      # S6: 2 takes x 4 cameras x 3 phases
    assert sum(n for r, n in reasons.items() if r.startswith("view ")) == 3 * 6 * 3   # 3 cameras x 6 takes x 3 phases


def test_normalised_frames_equal_the_reference(reference, ours):
    rep, spl, _ = ours
    train = [k for k in reference if int(k.split("_")[0][1:]) in TRAIN_SUBJECTS]
    avg_z = np.mean(np.concatenate([reference[k][1] for k in train]))
    scaled = {k: uv * (d / avg_z)[:, None, None] for k, (uv, d) in reference.items()}
    all_train = np.concatenate([scaled[k] for k in train])[:, KEPT]
    mean, std = all_train.mean(0), all_train.std(0)
    norm = Normaliser.load(spl / "csgan_stats.npz")
    meta = pd.read_parquet(rep / "meta.parquet").set_index("sequence_id")
    pose, root = np.load(rep / "pose.npy"), np.load(rep / "root.npy")
    worst = px = 0.0
    for take, t in [("S1_Posing", 0), ("S1_Posing", 301), ("S5_Posing_1", 452), ("S11_Posing", 1000),
                    ("S11_Posing_1", 763)]:
        ref = (scaled[take][t, KEPT] - mean) / std                    # the reference's normalised frame
        row = meta.loc[f"{take}@{CAMERA}+{t % 3}"]                    # 50 Hz frame t: phase t mod 3, pose t // 3
        i = int(row.offset) + t // 3
        got = norm(pose[i].astype(np.float64), root[i].astype(np.float64))
        worst = max(worst, np.abs(got - ref).max() / np.abs(ref).max())
        px = max(px, np.abs((got - ref) * std).max())
    print(f"\nnormalised frames against the reference: max |difference| / max |value| per frame {worst:.2e}, "
          f"{px:.1e} px")
    # The frames are stored as float32 pixels (views2d in the store, pose in the representation): each
    # coordinate is rounded to half a float32 ulp, 3.1e-5 px below 1,024 px, twice (projection, centring).
    # That is the difference left (5e-6 of a frame's largest normalised value, where the statistics, means
    # over thousands of frames, agree to 2e-7): RTOL_FRAME, not RTOL, is what float32 storage allows.
    assert px < 1e-4 and worst < RTOL_FRAME         # 1e-4 px: two half-ulps (6.1e-5 px) times the depth scale

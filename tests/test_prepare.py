"""Prepare: control signals on trajectories with known answers, facing normalisation, resampling, clips."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import archive_path, dataset_cfg

from motionsynth.data.clips import gather, resample, windows
from motionsynth.data.controls import controls_from_root, integrate_controls, root_and_controls
from motionsynth.data.ingest import ingest
from motionsynth.data.prepare import prepare

FPS = 60.0


def body(path_xz: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A 5-joint body [T, 5, 3]: root, hip L/R, shoulder L/R, facing heading ``theta`` (0 = +Z)."""
    T = len(theta)
    left = np.stack([np.cos(theta), np.zeros(T), -np.sin(theta)], -1)   # up x facing
    root = np.stack([path_xz[:, 0], np.full(T, 0.9), path_xz[:, 1]], -1)
    up = np.array([0, 0.5, 0])
    return np.stack([root, root + 0.1 * left, root - 0.1 * left,
                     root + up + 0.2 * left, root + up - 0.2 * left], 1)


def controls_of(pos):
    return root_and_controls(pos, 0, (1, 2), (3, 4), FPS, sigma_s=0.0)


def test_straight_walk_along_x():
    t = np.arange(120) / FPS
    pos = body(np.stack([1.5 * t, np.zeros_like(t)], -1), np.full(120, np.pi / 2))  # facing +X
    pose, root, c = controls_of(pos)
    np.testing.assert_allclose(c[:, 0], 1.5, atol=1e-4)       # forward m/s
    np.testing.assert_allclose(c[:, 1:], 0, atol=1e-4)        # no sideways, no turn
    np.testing.assert_allclose(root[:, 2], np.pi / 2, atol=1e-6)
    # facing-normalised: the body faces +Z, left hip on +X, root at the ground origin
    np.testing.assert_allclose(pose[:, 0], [[0, 0.9, 0]] * 120, atol=1e-5)
    np.testing.assert_allclose(pose[:, 1], [[0.1, 0.9, 0]] * 120, atol=1e-5)


def test_circle_gives_constant_turn_and_forward_speed():
    w, R = 0.5, 2.0                        # rad/s, metres
    t = np.arange(600) / FPS
    th = w * t                             # heading turns towards +X: tangent of the circle below
    path = np.stack([R - R * np.cos(w * t), R * np.sin(w * t)], -1)
    _, _, c = controls_of(body(path, th))
    np.testing.assert_allclose(c[:, 2], w, atol=1e-6)
    np.testing.assert_allclose(c[:, 0], R * w, rtol=1e-3)
    # forward differences measure the chord, which leans inwards by half a step's turn
    np.testing.assert_allclose(c[:, 1], 0, atol=R * w * np.sin(w / FPS / 2) + 1e-6)


def test_strafing_to_the_left_is_positive_sideways():
    t = np.arange(60) / FPS
    pos = body(np.stack([0.8 * t, np.zeros_like(t)], -1), np.zeros(60))  # faces +Z, moves +X (its left)
    _, _, c = controls_of(pos)
    np.testing.assert_allclose(c[:, 1], 0.8, atol=1e-5)
    np.testing.assert_allclose(c[:, [0, 2]], 0, atol=1e-5)


def test_heading_wraps_without_spikes():
    th = np.linspace(0, 6 * np.pi, 400)
    _, _, c = controls_of(body(np.zeros((400, 2)), th))
    np.testing.assert_allclose(c[:, 2], (th[1] - th[0]) * FPS, rtol=1e-4)


def test_controls_integrate_back_to_the_real_root_trajectory(tmp_path):
    ingest(dataset_cfg("bandai2_locomotion"), archive_path("bandai2_locomotion"), tmp_path / "i",
           max_items=4, progress=False)
    reps = dataset_cfg("bandai2_locomotion")["prepare"]["representations"]
    s = prepare(tmp_path / "i", tmp_path / "p", reps)["representations"]["pos3d"]
    assert s["joints"] == 21 and s["fps"] == 60
    root = np.load(tmp_path / "p/pos3d/root.npy")
    ctrl = np.load(tmp_path / "p/pos3d/controls.npy")
    meta = pd.read_parquet(tmp_path / "p/pos3d/meta.parquet")
    o, n = int(meta.offset[0]), int(meta.frames[0])
    r, c = root[o:o + n].astype(np.float64), ctrl[o:o + n].astype(np.float64)
    back = integrate_controls(c, 60.0, r[0])
    np.testing.assert_allclose(back[:, :2], r[:, :2], atol=2e-3)
    assert np.abs(c[:, 0]).max() < 10  # forward speed of walking/running in m/s


def test_controls_from_root_handles_one_frame():
    assert controls_from_root(np.zeros((1, 2)), np.zeros(1), 30).shape == (1, 3)


def test_resample_integer_ratio_is_exact_and_other_ratios_interpolate():
    x = np.arange(12, dtype=np.float32)[:, None]
    np.testing.assert_array_equal(resample(x, 120, 30)[:, 0], [0, 4, 8])
    up = resample(x, 30, 60)[:, 0]
    np.testing.assert_allclose(up, np.arange(23) / 2)
    assert resample(x, 50, 50 / 3).shape[0] == 4


def test_windows_pad_with_edge_poses_and_keep_tails():
    frames = np.array([100, 300, 240])
    w = windows(frames, 240, 120)
    assert w[["seq", "start"]].values.tolist() == [[0, 0], [1, 0], [1, 60], [2, 0]]
    data = np.arange(640, dtype=np.float32)[:, None]
    offsets = np.array([0, 100, 400])
    clips = gather(data, offsets, frames, w)
    assert clips.shape == (4, 240, 1)
    assert clips[0, 99, 0] == 99 and (clips[0, 100:, 0] == 99).all()  # padded with the last pose
    assert clips[2, 0, 0] == 160 and clips[2, -1, 0] == 399
    start_pad = windows(np.array([100]), 240, 120, pad="start")
    assert gather(data, offsets, frames, start_pad)[0, 0, 0] == 0 and gather(data, offsets, frames, start_pad)[0, -1, 0] == 99


def test_sparse_windows_every_k():
    w = windows(np.array([30, 10]), 16, 5, pad="none")
    assert w["seq"].tolist() == [0, 0, 0, 0] and w["start"].tolist() == [0, 5, 10, 14]
    data = np.arange(40, dtype=np.float32)[:, None]
    sparse = gather(data, np.array([0, 30]), np.array([30, 10]), w, every=5)
    assert sparse.shape == (4, 4, 1) and sparse[1, :, 0].tolist() == [5, 10, 15, 20]


def test_prepare_h36m_benchmark_variant(tmp_path):
    cfg = dataset_cfg("h36m")
    ingest(cfg, archive_path("h36m"), tmp_path / "i", max_items=3, progress=False)
    s = prepare(tmp_path / "i", tmp_path / "p", cfg["prepare"]["representations"])["representations"]
    b = s["bench2d"]
    assert b["joints"] == 15 and b["dims"] == 2 and abs(b["fps"] - 50 / 3) < 1e-9
    meta = pd.read_parquet(tmp_path / "p/bench2d/meta.parquet")
    assert len(meta) == 3 * 4 * 3 and meta["view"].nunique() == 4   # every camera and every phase is a sequence
    root = np.load(tmp_path / "p/bench2d/root.npy")
    assert (root[:, 2] > 1).all()                                # camera depth of the hip, metres
    w = pd.read_parquet(tmp_path / "p/bench2d/windows_glocal.parquet")
    assert (w["length"] == 60).all() and (w["every"] == 1).all()
    # all_phases: phase p holds the 50 Hz frames p, p + 3, ...; together every frame once
    store = pd.read_parquet(tmp_path / "i/meta.parquet").set_index("sequence_id")
    views = np.load(tmp_path / "i/views2d.npy", mmap_mode="r")
    pose = np.load(tmp_path / "p/bench2d/pose.npy")
    for (src, view), g in meta.groupby(["source_id", "view"]):
        assert g["phase"].tolist() == [0, 1, 2] and g["sequence_id"].tolist() == [f"{src}@{view}+{p}" for p in range(3)]
        assert g["frames"].sum() == store.loc[src, "frames"] and set(g["source_id"]) == {src}
    row = meta.iloc[4]                                  # rows: take, then camera, then phase: camera 2, phase 1
    src = store.loc[row.source_id]
    assert row.phase == 1
    uv = views[src.offset + 1:src.offset + src.frames:3, 1]                    # 50 Hz frames 1, 4, 7, ...
    keep = [1, 2, 3, 4, 5, 6, 7, 8, 10, 11, 12, 13, 14, 15, 16]               # the 17 stored minus Hip, Neck/Nose
    np.testing.assert_array_equal(pose[row.offset:row.offset + row.frames], (uv - uv[:, :1])[:, keep])


def test_unknown_joint_in_representation_is_rejected(tmp_path):
    cfg = dataset_cfg("ntu_samples")
    ingest(cfg, archive_path("ntu_samples"), tmp_path / "i", max_items=1, progress=False)
    with pytest.raises(KeyError, match="Elbw"):
        prepare(tmp_path / "i", tmp_path / "p", {"x": {"space": "3d", "fps": 30, "joints": ["Elbw"]}})


def test_gather_fills_padded_frames_with_pad_value():
    import numpy as np
    import pandas as pd

    from motionsynth.data.clips import gather

    data = np.arange(10, dtype=np.float32)[:, None] + 1            # two sequences of 4 and 6 frames
    win = pd.DataFrame({"seq": [0, 1], "start": [0, -2], "length": [6, 6]})
    offsets, frames = np.array([0, 4]), np.array([4, 6])
    edge = gather(data, offsets, frames, win)[..., 0]
    assert edge.tolist() == [[1, 2, 3, 4, 4, 4], [5, 5, 5, 6, 7, 8]]       # clamped: the edge pose repeats
    zero = gather(data, offsets, frames, win, pad_value=0.0)[..., 0]
    assert zero.tolist() == [[1, 2, 3, 4, 0, 0], [0, 0, 5, 6, 7, 8]]       # controls of padding: standing still

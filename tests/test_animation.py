"""Animations (motionsynth.viz.animation): the animate stage's side-by-side GIF + MP4 from a samples file
the test writes itself (a walking stick figure), the camera geometry, and clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from motionsynth.data.types import MissingDataError
from motionsynth.viz.animation import (AnimationError, animate_samples, bone_pairs, camera_basis, frame_indices,
                                       project, read_gif, read_mp4)

# a 16-joint stick figure, Y up, metres: 0 hips, 1 spine, 2 neck, 3 head, 4-6 left arm, 7-9 right arm, 10-15 legs
PARENTS = [-1, 0, 1, 2, 2, 4, 5, 2, 7, 8, 0, 10, 11, 0, 13, 14]
REST = np.array([[0, 1.0, 0], [0, 1.25, 0], [0, 1.5, 0], [0, 1.7, 0], [0.2, 1.45, 0], [0.25, 1.2, 0],
                 [0.28, 0.95, 0], [-0.2, 1.45, 0], [-0.25, 1.2, 0], [-0.28, 0.95, 0], [0.1, 0.95, 0], [0.1, 0.5, 0],
                 [0.1, 0.05, 0], [-0.1, 0.95, 0], [-0.1, 0.5, 0], [-0.1, 0.05, 0]])
FAST = {"dpi": 40, "panel_in": [1.6, 2.0]}  # small frames: the test is about counts and content, not looks


def walk(T: int, fps: float, speed: float = 1.2, phase: float = 0.0) -> np.ndarray:
    """``[T, 16, 3]``: legs and arms swinging at 1 Hz, walking along +Z at ``speed`` m/s."""
    t = np.arange(T) / fps
    p = np.repeat(REST[None], T, 0)
    s = np.sin(2 * np.pi * t + phase)[:, None]
    p[:, [11, 12], 2] += 0.25 * s * [0.5, 1]
    p[:, [14, 15], 2] -= 0.25 * s * [0.5, 1]
    p[:, [5, 6], 2] -= 0.2 * s * [0.5, 1]
    p[:, [8, 9], 2] += 0.2 * s * [0.5, 1]
    p[..., 2] += speed * t[:, None]
    return p.astype(np.float32)


def write_samples(path: Path, n: int = 2, T: int = 120, fps: float = 60.0, space: str = "3d", **meta) -> Path:
    gt = np.stack([walk(T, fps, phase=k) for k in range(n)])
    arrays = {"m:ground truth": gt, "m:VAE-LSTM": np.stack([walk(T, fps, 1.0, k + 0.5) for k in range(n)]),
              "m:ERD": gt[:, :T // 2] + np.float32(0.05)}                          # shorter: holds its last pose
    if space == "2d":                                                                 # image pixels, y down
        arrays = {k: np.stack([v[..., 0] * 200 + 320, 480 - v[..., 1] * 200], -1) for k, v in arrays.items()}
    m = {"dataset": "toy", "fps": fps, "parents": PARENTS, "space": space, "title": "toy walk",
         "seed_frames": {"ground truth": T, "VAE-LSTM": 4, "ERD": 60}, **meta}
    np.savez_compressed(path, **arrays, meta=np.array(json.dumps(m)))
    return path


def test_animate_writes_gif_and_mp4_per_sequence(tmp_path):
    samples = write_samples(tmp_path / "toy.npz")
    out = tmp_path / "anim"
    index = animate_samples(samples, out, {**FAST, "fps": 15, "max_seconds": 10})
    assert sorted(p.name for p in out.iterdir()) == ["index.json", "seq0.gif", "seq0.mp4", "seq1.gif", "seq1.mp4"]
    assert json.loads((out / "index.json").read_text())["sequences"][1]["frames"] == 30
    s = index["sequences"][0]
    assert s["panels"] == ["ground truth", "VAE-LSTM (seed 4)", "ERD (seed 60)"]       # ground truth first
    # GIF: 120 frames at 60 fps shown at 15 fps = every 4th frame = 30 frames, not blank, and moving
    n, first = read_gif(out / "seq0.gif")
    assert n == 30 and s["frames"] == 30 and s["fps"] == 15
    dark = (first.max(-1) < 80).mean()                                                 # black ground-truth bones
    coloured = ((first.max(-1).astype(int) - first.min(-1)) > 80).mean()               # the methods' colours
    assert 0.001 < dark < 0.2 and coloured > 0.001
    # MP4: an ISO media file (ftyp box) that ffmpeg decodes back to the same 30 frames, which change over time
    raw = (out / "seq0.mp4").read_bytes()
    assert raw[4:8] == b"ftyp"
    meta, frames = read_mp4(out / "seq0.mp4")
    assert meta["codec"] == "h264" and len(frames) == 30
    assert frames[0].shape == first.shape                                              # same (even) size
    assert np.abs(frames[0].astype(int) - frames[15]).mean() > 0.5                     # the figure walks


def test_length_cap_subsampling_and_2d(tmp_path):
    samples = write_samples(tmp_path / "toy2d.npz", n=1, T=300, fps=50.0, space="2d")
    index = animate_samples(samples, tmp_path / "a", {**FAST, "fps": 10, "max_seconds": 4, "formats": ["gif"]})
    assert [p.name for p in sorted((tmp_path / "a").iterdir())] == ["index.json", "seq0.gif"]
    assert index["sequences"][0]["frames"] == 40 and read_gif(tmp_path / "a/seq0.gif")[0] == 40   # 4 s x 10 fps
    idx, step = frame_indices(300, 50.0, 10.0, 4)
    assert step == 5 and idx[0] == 0 and idx[-1] == 195


def test_camera_geometry():
    # image coordinates: y points down, so the screen (y up) gets -y
    assert np.allclose(project(np.array([[3.0, 10.0]]), "2d"), [[3.0, -10.0]])
    # azimuth 0, elevation 0: from +Z, screen right = +X, up = +Y; azimuth 90: from the character's left (+X)
    r, u = camera_basis(0, 0)
    assert np.allclose(r, [1, 0, 0]) and np.allclose(u, [0, 1, 0])
    r, u = camera_basis(90, 30)
    assert np.allclose(r, [0, 0, -1]) and abs(r @ u) < 1e-12 and np.isclose(np.linalg.norm(u), 1)
    assert u[1] == pytest.approx(np.cos(np.radians(30)))                              # looking down tilts up
    assert bone_pairs([-1, 0, 1]).tolist() == [[1, 0], [2, 1]]


def test_bad_inputs_are_clear_errors(tmp_path):
    with pytest.raises(MissingDataError, match=r"none.npz is missing: .*`dvc repro evaluate@none`"):
        animate_samples(tmp_path / "none.npz", tmp_path / "o")
    np.savez(tmp_path / "nometa.npz", **{"m:ground truth": walk(10, 30.0)[None]}, meta=np.array(json.dumps({})))
    with pytest.raises(AnimationError, match=r"lacks \['fps', 'parents'\]"):
        animate_samples(tmp_path / "nometa.npz", tmp_path / "o")
    samples = write_samples(tmp_path / "toy.npz", n=1, T=20)
    with pytest.raises(AnimationError, match="gif and/or mp4"):
        animate_samples(samples, tmp_path / "o", {"formats": ["avi"]})
    with pytest.raises(AnimationError, match="3 coordinates"):
        project(np.zeros((2, 2)), "3d")


def test_no_samples_writes_an_empty_index(tmp_path):
    np.savez(tmp_path / "empty.npz", meta=np.array(json.dumps({"dataset": "toy"})))
    index = animate_samples(tmp_path / "empty.npz", tmp_path / "o")
    assert index["sequences"] == [] and (tmp_path / "o/index.json").exists()

"""Error metrics (GlocalNet Euclidean per frame, VAE-LSTM motion/pose error) and physical
metrics (foot skating, bone length) on synthetic motion with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from motionsynth.data.types import Skeleton
from motionsynth.metrics.errors import (
    DEFAULT_HORIZONS_MS, VAE_LSTM_FRAMES, euclidean_per_frame, euclidean_per_frame_values,
    frames_to_ms, horizon_frames, ms_to_frames, prediction_error, prediction_error_values,
    remove_facing, root_relative, summarise,
)
from motionsynth.metrics.physical import (
    bone_length_error, default_smooth_window, foot_skating_ratio,
)

RNG = np.random.default_rng(0)


def motion(B=3, T=100, J=5, D=3, seed=0):
    return np.random.default_rng(seed).normal(size=(B, T, J, D))


# ----------------------------------------------------------------------------- horizons

def test_horizon_frames_at_120_60_30_fps():
    assert horizon_frames(DEFAULT_HORIZONS_MS, 120).tolist() == [10, 19, 29, 38, 48, 58, 67, 77]
    assert horizon_frames(DEFAULT_HORIZONS_MS, 60).tolist() == [5, 10, 14, 19, 24, 29, 34, 38]
    assert horizon_frames(DEFAULT_HORIZONS_MS, 30).tolist() == [2, 5, 7, 10, 12, 14, 17, 19]
    assert ms_to_frames(250, 30) == 8          # 7.5 rounds half up
    assert ms_to_frames(1000, 120) == 120 and isinstance(ms_to_frames(1000, 120), int)
    assert frames_to_ms(10, 120) == pytest.approx(83.333333)
    assert np.allclose(frames_to_ms(np.array([30, 60]), 60), [500, 1000])


@pytest.mark.parametrize("bad", [dict(horizons_ms=[10], fps=30), dict(horizons_ms=[], fps=30),
                                 dict(horizons_ms=[-80], fps=120), dict(horizons_ms=[80], fps=0),
                                 dict(horizons_ms=[80], fps=float("nan"))])
def test_horizon_frames_rejects(bad):
    with pytest.raises(ValueError):
        horizon_frames(**bad)


def test_horizon_indexing_with_and_without_seed():
    """Horizon h is frame seed_frames - 1 + k: a marker placed exactly there is found."""
    fps, S, T = 120, 20, 100
    gt = np.zeros((1, T, 2, 3))
    k = horizon_frames([80, 160], fps)
    pred = gt.copy()
    pred[0, S - 1 + k[0], 1, 0] = 3.0
    pred[0, S - 1 + k[1], 1, 0] = 4.0
    e = euclidean_per_frame(pred, gt, fps, [80, 160], root_index=0, seed_frames=S)
    assert np.allclose(e, [3.0, 4.0])
    # the same continuation without its seed: index k - 1
    e0 = euclidean_per_frame(pred[:, S:], gt[:, S:], fps, [80, 160], root_index=0, seed_frames=0)
    assert np.allclose(e0, [3.0, 4.0])


# ----------------------------------------------------------------------------- Euclidean per frame

def test_constant_offset_gives_its_norm_at_every_horizon():
    gt = motion(T=90)
    off = RNG.normal(size=(5, 3))
    off[0] = 0.0                                 # root unchanged: root-relative offset == off
    pred = gt + off
    e = euclidean_per_frame(pred, gt, 120, root_index=0)
    assert e.shape == (8,)
    assert np.allclose(e, np.linalg.norm(off))


def test_norm_is_flat_l2_not_mean_per_joint():
    gt = np.zeros((1, 20, 4, 3))
    pred = gt.copy()
    pred[:, :, 1:, 1] = 1.0                      # 3 non-root joints 1 unit off
    e = euclidean_per_frame(pred, gt, 60, [80], root_index=0)
    assert e[0] == pytest.approx(math.sqrt(3))   # not 1 (mean per joint) or 0.75


def test_root_translation_is_ignored_but_not_without_root():
    gt = motion(T=90)
    pred = gt + np.array([5.0, -2.0, 1.0])       # whole body shifted: root-relative error 0
    assert np.allclose(euclidean_per_frame(pred, gt, 120, root_index=0), 0.0)
    glob = euclidean_per_frame(pred, gt, 120, root_index=None)
    assert np.allclose(glob, math.sqrt(5) * np.linalg.norm([5, -2, 1]))


def test_linear_drift_grows_linearly():
    fps, S, T = 120, 10, 100
    gt = np.zeros((2, T, 3, 3))
    pred = gt.copy()
    v = 0.01                                      # per frame, on one non-root joint
    pred[:, S:, 2, 0] = v * np.arange(1, T - S + 1)   # 0 at the last seed frame
    e = euclidean_per_frame(pred, gt, fps, root_index=0, seed_frames=S)
    assert np.allclose(e, v * horizon_frames(DEFAULT_HORIZONS_MS, fps))
    # interpolated horizons: exactly v * h * fps / 1000
    ei = euclidean_per_frame(pred, gt, fps, root_index=0, seed_frames=S, frame_mapping="interpolate")
    assert np.allclose(ei, v * np.array(DEFAULT_HORIZONS_MS) * fps / 1000)
    at30 = euclidean_per_frame(pred[:, ::4], gt[:, ::4], 30, [80], root_index=0, seed_frames=3,
                               frame_mapping="interpolate")
    assert at30[0] == pytest.approx(v * (8 + 9.6 - 9))  # seed ends at 120-fps frame 8; 80 ms = 9.6 frames


def test_values_per_sequence_samples_and_torch():
    gt = np.zeros((2, 30, 3, 3))
    pred = np.zeros((3, 2, 30, 3, 3))            # 3 samples
    pred[0, :, :, 1, 0] = 1.0
    pred[1, :, :, 1, 0] = 2.0
    pred[2, :, :, 1, 0] = 6.0
    pred[:, 1] *= 2                               # sequence 1 twice the error
    v = euclidean_per_frame_values(pred, gt, 60, [80, 160], root_index=0)
    assert v.shape == (2, 2)
    assert np.allclose(v[:, 0], [3.0, 6.0])      # mean over samples
    vmin = euclidean_per_frame_values(pred, gt, 60, [80], root_index=0, samples="min")
    assert np.allclose(vmin[:, 0], [1.0, 2.0])
    t = euclidean_per_frame(torch.tensor(pred), torch.tensor(gt), 60, [80], root_index=0)
    assert isinstance(t, np.ndarray) and t[0] == pytest.approx(4.5)
    s = summarise(v)
    assert np.allclose(s["mean"], [4.5, 4.5]) and np.allclose(s["std"], [2.12132034] * 2)
    assert np.all(s["ci_low"] < s["mean"]) and int(s["n"]) == 2


def test_joint_subset_and_scale():
    gt = np.zeros((1, 20, 4, 3))
    pred = gt.copy()
    pred[:, :, 2, 2] = 3.0
    pred[:, :, 3, 2] = 4.0
    assert euclidean_per_frame(pred, gt, 60, [80], root_index=0, joints=[2])[0] == pytest.approx(3)
    assert euclidean_per_frame(pred, gt, 60, [80], root_index=0, scale=100)[0] == pytest.approx(500)


@pytest.mark.parametrize("case", ["rank", "shape", "nan", "short", "root", "seed", "samples", "mapping",
                                  "joints", "scale"])
def test_euclidean_rejects_bad_input(case):
    gt = np.zeros((2, 30, 3, 3))
    pred = gt.copy()
    kw = dict(root_index=0)
    hz = [80]
    if case == "rank":
        pred, gt = pred[0], gt[0]
    elif case == "shape":
        pred = pred[:, :, :2]
    elif case == "nan":
        pred[0, 3, 1, 1] = np.nan
    elif case == "short":
        hz = [640]                                # 77 frames at 120 fps > 30
    elif case == "root":
        kw["root_index"] = 3
    elif case == "seed":
        kw["seed_frames"] = -1
    elif case == "samples":
        kw["samples"] = "max"
    elif case == "mapping":
        kw["frame_mapping"] = "nearest"
    elif case == "joints":
        kw["joints"] = [5]
    elif case == "scale":
        kw["scale"] = 0
    with pytest.raises(ValueError):
        euclidean_per_frame(pred, gt, 120, hz, **kw)


def test_root_index_is_required():
    with pytest.raises(TypeError):
        euclidean_per_frame(np.zeros((1, 20, 2, 3)), np.zeros((1, 20, 2, 3)), 60, [80])


# ----------------------------------------------------------------------------- VAE-LSTM errors

def test_prediction_error_frames_are_one_based_clip_frames():
    T = 240
    gt = np.zeros((1, T, 3, 3))
    pred = gt.copy()
    for f in VAE_LSTM_FRAMES:
        pred[0, f - 1, 1, 0] = f / 10            # marker at 1-based frame f (index f-1)
    e = prediction_error(pred, gt, kind="motion", reduction="mpjpe")
    assert np.allclose(e, np.array(VAE_LSTM_FRAMES) / 10 / 3)   # one of 3 joints off
    e0 = prediction_error(pred, gt, [69, 89], kind="motion", reduction="mpjpe", frame_base=0)
    assert np.allclose(e0, [7 / 3, 9 / 3])


def test_prediction_error_reductions():
    gt = np.zeros((2, 240, 4, 3))
    pred = gt.copy()
    pred[..., 1, :] = [1.0, 2.0, 2.0]             # joint 1: distance 3
    pred[..., 2, :] = [0.0, 0.0, 1.0]             # joint 2: distance 1
    red = {r: prediction_error(pred, gt, kind="motion", reduction=r)[0]
           for r in ("mse", "mse_coord", "rmse", "mpjpe", "l2")}
    assert red["mse"] == pytest.approx((9 + 1) / 4)
    assert red["mse_coord"] == pytest.approx((9 + 1) / 12)
    assert red["rmse"] == pytest.approx(math.sqrt(2.5))
    assert red["mpjpe"] == pytest.approx(1.0)
    assert red["l2"] == pytest.approx(math.sqrt(10))
    assert prediction_error(pred, gt, kind="motion", scale=10)[0] == pytest.approx(250)


def test_motion_vs_pose_error_translation_and_rotation():
    B, T, J = 3, 240, 6
    gt = motion(B, T, J)
    # rotate every frame about +Y by its own angle, then translate: a different global motion
    ang = RNG.uniform(-np.pi, np.pi, size=(B, T, 1))
    c, s = np.cos(ang), np.sin(ang)
    x, y, z = gt[..., 0], gt[..., 1], gt[..., 2]
    rot = np.stack([c * x + s * z, y, -s * x + c * z], axis=-1)
    pred = rot + RNG.normal(size=(B, T, 1, 3)) * 3
    assert np.all(prediction_error(pred, gt, kind="motion") > 0.1)
    # root-relative only: rotation still counts
    assert np.all(prediction_error(pred, gt, kind="pose", root_index=0) > 0.1)
    # root-relative and facing-normalised (hips = joints 1, 2): both removed
    e = prediction_error(pred, gt, kind="pose", root_index=0, facing_joints=(1, 2))
    assert np.allclose(e, 0.0, atol=1e-20)
    # constant root-relative offset: pose error = mean squared joint distance
    off = np.zeros((J, 3))
    off[3] = [0.0, 0.3, 0.4]
    e2 = prediction_error(gt + off + 7.0, gt, kind="pose", root_index=0)
    assert np.allclose(e2, 0.25 / J)


def test_remove_facing_convention():
    pose = np.zeros((1, 3, 3))
    pose[0, 1] = [0.0, 0.0, 0.2]                  # left hip along +Z ...
    pose[0, 2] = [0.0, 0.0, -0.2]                 # ... right along -Z: faces -X
    out = remove_facing(pose, (1, 2))
    assert np.allclose(out[0, 1], [0.2, 0.0, 0.0]) and np.allclose(out[0, 2], [-0.2, 0.0, 0.0])
    assert np.allclose(root_relative(pose + 1.0, 0), pose)


@pytest.mark.parametrize("case", ["kind", "reduction", "frame", "motion_root", "pose_noroot", "base",
                                  "float_frames", "facing_2d", "nan"])
def test_prediction_error_rejects_bad_input(case):
    gt = np.zeros((2, 240, 3, 3))
    pred = gt.copy()
    args, kw = (VAE_LSTM_FRAMES, "motion"), {}
    if case == "kind":
        args = (VAE_LSTM_FRAMES, "global")
    elif case == "reduction":
        kw["reduction"] = "mae"
    elif case == "frame":
        args = ((70, 241), "motion")
    elif case == "motion_root":
        kw["root_index"] = 0
    elif case == "pose_noroot":
        args = (VAE_LSTM_FRAMES, "pose")
    elif case == "base":
        kw["frame_base"] = 2
    elif case == "float_frames":
        args = ((70.5,), "motion")
    elif case == "facing_2d":
        gt, pred = gt[..., :2], pred[..., :2]
        args, kw = (VAE_LSTM_FRAMES, "pose"), dict(root_index=0, facing_joints=(1, 2))
    elif case == "nan":
        pred[1, 100, 0, 0] = np.inf
    with pytest.raises(ValueError):
        prediction_error(pred, gt, *args, **kw)


def test_prediction_error_values_shape_with_samples():
    gt = np.zeros((4, 240, 3, 3))
    pred = np.ones((5, 4, 240, 3, 3))
    v = prediction_error_values(pred, gt, kind="pose", root_index=0)
    assert v.shape == (4, 5) and np.allclose(v, 0.0)   # uniform shift: root-relative 0


# ----------------------------------------------------------------------------- foot skating

def feet_motion(T=60, fps=30.0, speed=2.0, height=0.01, B=2):
    """Two feet (joints 1, 2) at ``height``; joint 1 slides along X at ``speed`` m/s."""
    x = np.zeros((B, T, 3, 3))
    x[:, :, 0, 1] = 1.0
    x[:, :, 1:, 1] = height
    x[:, :, 1, 0] = speed * np.arange(T) / fps
    x[:, :, 2, 2] = 0.3
    return x


def test_sliding_foot_on_ground_has_ratio_one():
    r = foot_skating_ratio(feet_motion(), 30.0, [1, 2])
    assert r.ratio == 1.0 and np.allclose(r.per_sequence, 1.0)
    assert r.contact_ratio == 1.0 and r.mean_contact_speed == pytest.approx(1.0)  # mean of 2 and 0 m/s
    assert r.smooth_window == 7


def test_foot_skating_zero_cases():
    assert foot_skating_ratio(feet_motion(speed=0.0), 30.0, [1, 2]).ratio == 0.0         # planted
    lifted = foot_skating_ratio(feet_motion(height=0.2), 30.0, [1, 2])                   # in the air
    assert lifted.ratio == 0.0 and lifted.contact_ratio == 0.0
    assert foot_skating_ratio(feet_motion(speed=0.4), 30.0, [1, 2]).ratio == 0.0         # slow


def test_foot_skating_ground_vertical_axis_and_half():
    x = feet_motion(height=-0.30)                # floor at -0.30 m, feet on it
    assert foot_skating_ratio(x, 30.0, [1, 2]).ratio == 1.0      # below 0 counts as contact anyway
    x2 = feet_motion(height=0.50)
    assert foot_skating_ratio(x2, 30.0, [1, 2]).ratio == 0.0
    assert foot_skating_ratio(x2, 30.0, [1, 2], ground="min").ratio == 1.0
    assert foot_skating_ratio(x2, 30.0, [1, 2], ground=0.5).ratio == 1.0
    # Z up: swap Y and Z
    z = feet_motion()[..., [0, 2, 1]]
    assert foot_skating_ratio(z, 30.0, [1, 2], vertical_axis=2).ratio == 1.0
    # the foot lifts for the second half: about half the transitions skate
    h = feet_motion(T=61)
    h[:, 31:, 1, 1] = 0.3
    r = foot_skating_ratio(h, 30.0, [1, 2], smooth_window=1)
    assert r.ratio == pytest.approx(30 / 60)


def test_default_smooth_window():
    assert [default_smooth_window(f) for f in (20, 30, 60, 120)] == [5, 7, 15, 31]


@pytest.mark.parametrize("case", ["rank", "d2", "fps", "feet", "one_frame", "ground", "window", "thr"])
def test_foot_skating_rejects(case):
    x, fps, feet, kw = feet_motion(), 30.0, [1, 2], {}
    if case == "rank":
        x = x[0]
    elif case == "d2":
        x = x[..., :2]
    elif case == "fps":
        fps = -1
    elif case == "feet":
        feet = [3]
    elif case == "one_frame":
        x = x[:, :1]
    elif case == "ground":
        kw["ground"] = "floor"
    elif case == "window":
        kw["smooth_window"] = 0
    elif case == "thr":
        kw["height_threshold"] = 0
    with pytest.raises(ValueError):
        foot_skating_ratio(x, fps, feet, **kw)


# ----------------------------------------------------------------------------- bone length

def chain_skeleton():
    return Skeleton(names=["root", "a", "b", "c"], parents=[-1, 0, 1, 1],
                    offsets=[[0, 0, 0], [0, 0.5, 0], [0.3, 0, 0], [0, 0, 0.2]])


def test_rest_pose_has_zero_bone_error():
    sk = chain_skeleton()
    x = np.broadcast_to(sk.rest_positions(), (2, 10, 4, 3)) + RNG.normal(size=(2, 10, 1, 3))
    r = bone_length_error(x, skeleton=sk)
    assert r.abs_error < 1e-6 and r.rel_error < 1e-5 and r.std_over_time < 1e-6
    assert r.bones.tolist() == [1, 2, 3] and np.allclose(r.rest_lengths, [0.5, 0.3, 0.2])


def test_bone_stretched_by_one_cm():
    sk = chain_skeleton()
    x = np.broadcast_to(sk.rest_positions(), (2, 10, 4, 3)).copy()
    x[:, :, 2, 0] += 0.01                        # bone a->b: 0.30 -> 0.31 m
    r = bone_length_error(x, sk.parents, sk.offsets)
    assert np.allclose(r.per_bone_abs, [0.0, 0.01, 0.0], atol=1e-7)
    assert r.abs_error == pytest.approx(0.01 / 3, abs=1e-7)
    assert r.per_bone_rel[1] == pytest.approx(0.01 / 0.3, rel=1e-5)
    assert r.std_over_time == pytest.approx(0.0, abs=1e-7)   # stretched, but constantly


def test_bone_length_std_over_time_and_zero_rest_bones():
    parents = np.array([-1, 0, 0])
    offsets = np.array([[0, 0, 0], [0, 1.0, 0], [0, 0, 0]])   # joint 2: zero-length bone
    x = np.zeros((1, 4, 3, 3))
    x[0, :, 1, 1] = [1.0, 1.2, 1.0, 0.8]          # length oscillates: std = sqrt(0.02)
    r = bone_length_error(x, parents, offsets)
    assert r.per_bone_std[0] == pytest.approx(math.sqrt(0.02))
    assert math.isnan(r.per_bone_rel[1]) and r.rel_error == pytest.approx(0.1)
    assert r.abs_error == pytest.approx(0.1 / 2)  # zero-length bone: 0 error, still counted


@pytest.mark.parametrize("case", ["rank", "parents_len", "parents_self", "offsets_shape", "both", "none",
                                  "no_bones", "nan"])
def test_bone_length_rejects(case):
    sk = chain_skeleton()
    x = np.zeros((1, 5, 4, 3))
    kw = dict(parents=sk.parents, offsets=sk.offsets)
    if case == "rank":
        x = x[0]
    elif case == "parents_len":
        kw["parents"] = [-1, 0, 1]
    elif case == "parents_self":
        kw["parents"] = [-1, 1, 1, 1]
    elif case == "offsets_shape":
        kw["offsets"] = np.zeros((4, 2))
    elif case == "both":
        kw["skeleton"] = sk
    elif case == "none":
        kw = {}
    elif case == "no_bones":
        kw["parents"] = [-1, -1, -1, -1]
    elif case == "nan":
        x[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError):
        bone_length_error(x, **kw)

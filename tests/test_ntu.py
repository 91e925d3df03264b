"""NTU RGB+D ``.skeleton`` reader: the 5 real sample files and hand-written fixtures."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from motionsynth.data.archive import Archive
from motionsynth.data.ntu import (
    DEFAULT_JOINT_NAMES, DEFAULT_PARENTS, KINECT_JOINTS, KINECT_PARENT, NTUReader, parse_name,
    parse_skeleton,
)
from motionsynth.data.types import InputError

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared/dvc-store/files/md5/ee/8f0798068579973730148c2c305577"
CONF = ROOT / "conf/dataset/ntu_samples.yaml"
TWO_PERSON = "S001C003P008R002A058"


def config_reader() -> NTUReader:
    cfg = yaml.safe_load(CONF.read_text())
    kw = dict(cfg["reader"])
    assert kw.pop("_target_") == "motionsynth.data.ntu.NTUReader"
    return NTUReader(**kw)


# ----------------------------------------------------------------------------- fixtures

def body_lines(body_id: int, joints: np.ndarray, state: int = 2) -> list[str]:
    """One body block: header, joint count, 25 joint lines (x y z + derived columns)."""
    out = [f"{body_id} 0 1 1 1 1 0 -0.1 0.1 2", str(len(joints))]
    for x, y, z in joints:
        out.append(f"{x:.6f} {y:.6f} {z:.6f} {250 + 100 * x:.3f} {200 - 100 * y:.3f} "
                   f"{960 + 300 * x:.3f} {540 - 300 * y:.3f} 1 0 0 0 {state}")
    return out


def pose(shift=(0.0, 0.0, 3.0), seed: int = 0, jitter: float = 0.01) -> np.ndarray:
    """A rough standing body [25, 3] (file order) around ``shift``."""
    rng = np.random.default_rng(seed)
    base = np.zeros((25, 3))
    base[:, 1] = np.linspace(-0.8, 0.8, 25)
    return base + np.asarray(shift) + rng.normal(0, jitter, (25, 3))


def skeleton_text(frames: list[list[tuple[int, np.ndarray]]], header: int | None = None) -> str:
    lines = [str(len(frames) if header is None else header)]
    for bodies in frames:
        lines.append(str(len(bodies)))
        for bid, joints in bodies:
            lines += body_lines(bid, joints)
    return "\r\n".join(lines) + "\r\n"


def make_zip(tmp_path: Path, files: dict[str, str]) -> Path:
    path = tmp_path / "ntu.zip"
    with zipfile.ZipFile(path, "w") as z:
        for name, text in files.items():
            z.writestr(name, text)
    return path


def one_body_frames(n: int, bid: int = 7, seed: int = 0) -> list[list[tuple[int, np.ndarray]]]:
    return [[(bid, pose(seed=seed + f))] for f in range(n)]


def expect_error(text: str, *words: str, member: str = "X/S001C001P001R001A001.skeleton"):
    with pytest.raises(InputError) as ei:
        parse_skeleton(text, member)
    err = ei.value
    assert err.member == member and member in str(err)
    for w in words:
        assert w in err.problem, (w, err.problem)
    return err


# ----------------------------------------------------------------------------- names, config

def test_parse_name():
    assert parse_name("nested/dir/S001C003P008R002A058.skeleton") == dict(
        setup=1, camera=3, performer=8, replication=2, action=58)
    assert parse_name("S017C002P040R001A120")["action"] == 120
    for bad in ["S01C003P008R002A058.skeleton", "foo.skeleton", "S001C003P008R002A058x.skeleton",
                "S000C003P008R002A058.skeleton"]:
        with pytest.raises(InputError) as ei:
            parse_name(bad)
        assert ei.value.member == bad


def test_config_joint_order_and_parents():
    cfg = yaml.safe_load(CONF.read_text())["reader"]
    names, parents = cfg["joint_names"], cfg["parents"]
    assert names == DEFAULT_JOINT_NAMES and parents == DEFAULT_PARENTS
    assert sorted(names) == sorted(KINECT_JOINTS)
    assert all(p < j for j, p in enumerate(parents)) and parents.count(-1) == 1
    for j, n in enumerate(names):  # the Kinect SDK hierarchy, by name
        assert (names[parents[j]] if parents[j] >= 0 else None) == KINECT_PARENT[n]
    assert names.index("SpineShoulder") < names.index("Neck")
    assert names[parents[names.index("Neck")]] == "SpineShoulder"
    acts = cfg["action_names"]
    assert len(acts) == 60 and acts[58] == "handshaking" and acts[3] == "brushing teeth"


# ----------------------------------------------------------------------------- real archive

def test_real_archive():
    reader = config_reader()
    with Archive(REAL) as arc:
        items, rejected = reader.list_items(arc)
        assert rejected == [] and len(items) == 5
        by_key = {it.key: it for it in items}
        m = by_key[TWO_PERSON].meta
        assert (m["setup"], m["camera"], m["performer"], m["replication"], m["action"]) == (1, 3, 8, 2, 58)
        assert (m["subject"], m["view"], m["label"], m["label_name"]) == ("P008", "C003", 57, "handshaking")
        assert by_key["S003C001P015R001A034"].meta["label_name"] == "rub two hands together"
        two = []
        for it in items:
            seq, sk = reader.read(arc, it)
            T = seq.num_frames
            assert T > 30 and seq.fps == 30.0
            assert seq.positions.shape == (T, 50, 3) and seq.positions.dtype == np.float32
            assert seq.views2d.shape == (T, 1, 50, 2) and seq.body_mask.shape == (T, 2)
            assert seq.view_depth.shape == (T, 1) and seq.view_depth.dtype == np.float32
            assert sk.names[:3] == ["b0_SpineBase", "b0_SpineMid", "b0_SpineShoulder"]
            assert sk.names[25] == "b1_SpineBase" and sk.parents[25] == -1 and sk.parents[0] == -1
            assert sk.root == "b0_SpineBase" and sk.feet == ["b0_FootLeft", "b0_FootRight"]
            sb = sk.index("b0_SpineBase")
            np.testing.assert_array_equal(seq.view_depth[:, 0], seq.positions[:, sb, 2])
            assert 1.0 < np.median(seq.view_depth) < 5.0  # metres from the sensor
            # columns follow the config order: compare with the raw file order
            raw = parse_skeleton(arc.text(it.member), it.member)
            for name in ("SpineShoulder", "Neck", "HandTipRight"):
                np.testing.assert_array_equal(seq.positions[:, sk.index("b0_" + name)],
                                              raw["positions"][:, 0, KINECT_JOINTS.index(name)])
            assert seq.body_mask[:, 0].all() and seq.meta["frames_without_body"] == 0
            # body size: head -> pelvis -> left foot along the bones, in metres
            p = seq.positions[seq.body_mask[:, 0]]
            chain = ["Head", "Neck", "SpineShoulder", "SpineMid", "SpineBase", "HipLeft",
                     "KneeLeft", "AnkleLeft", "FootLeft"]
            idx = [sk.index("b0_" + c) for c in chain]
            length = np.linalg.norm(np.diff(p[:, idx], axis=1), axis=-1).sum(1)
            assert 1.2 < np.median(length) < 2.0, (it.key, np.median(length))
            femur = np.linalg.norm(sk.offsets[sk.index("b0_KneeLeft")])
            assert 0.25 < femur < 0.6
            # Y is up: the head is above the feet in (almost) every frame
            assert (p[:, sk.index("b0_Head"), 1] > p[:, sk.index("b0_FootLeft"), 1]).mean() > 0.95
            if seq.meta["bodies"] == 2:
                two.append(it.key)
                assert seq.body_mask.all()
                gap = np.linalg.norm(seq.positions[:, 0] - seq.positions[:, 25], axis=-1)
                assert np.median(gap) > 0.3  # two different people
            else:
                assert seq.meta["bodies"] == 1 and not seq.body_mask[:, 1].any()
                assert not seq.positions[:, 25:].any()
        assert two == [TWO_PERSON]


# ----------------------------------------------------------------------------- fixtures: accepted

def test_zero_body_frame_in_middle(tmp_path):
    frames = one_body_frames(5)
    frames[2] = []
    name = "S001C002P003R001A010.skeleton"
    reader = NTUReader()
    with Archive(make_zip(tmp_path, {name: skeleton_text(frames)})) as arc:
        (item,), rej = reader.list_items(arc)
        seq, _ = reader.read(arc, item)
    assert rej == []
    assert seq.body_mask[:, 0].tolist() == [True, True, False, True, True]
    assert not seq.positions[2].any() and seq.positions[1].any()
    assert seq.meta["frames_without_body"] == 1 and seq.meta["bodies"] == 1
    assert item.meta["label_name"] == "A010" and item.meta["label"] == 9


def test_two_bodies_consistent_slots():
    a, b = 111, 72057594037944738  # a 64-bit Kinect ID must survive exactly
    frames = []
    for f in range(6):
        pa, pb = pose((-0.5, 0, 3), seed=f), pose((0.5, 0, 3), seed=100 + f)
        # the file lists the bodies in either order; the slot follows the ID
        frames.append([(a, pa), (b, pb)] if f % 2 == 0 else [(b, pb), (a, pa)])
    frames[5] = [(b, pose((0.5, 0, 3), seed=200))]
    out = parse_skeleton(skeleton_text(frames), "two.skeleton")
    assert out["body_ids"] == [[a], [b]]
    assert out["positions"].shape == (6, 2, 25, 3) and out["color2d"].shape == (6, 2, 25, 2)
    assert (out["positions"][:5, 0, :, 0] < 0).all() and (out["positions"][:, 1, :, 0] > 0).all()
    assert out["body_mask"][:, 0].tolist() == [True] * 5 + [False]
    assert out["body_mask"][:, 1].all() and out["bodies"] == 2 and out["warnings"] == []
    np.testing.assert_allclose(out["color2d"][0, 1, :, 0], 960 + 300 * out["positions"][0, 1, :, 0], atol=1e-2)


def test_three_bodies_keeps_two_most_moving():
    frames = []
    for f in range(8):
        frames.append([
            (1, pose((-1, 0, 3), seed=f, jitter=0.001)),          # nearly still
            (2, pose((0, 0.05 * f, 3), seed=10 + f)),               # moving
            (3, pose((1 + 0.05 * f, 0, 3), seed=20 + f)),           # moving
        ])
    out = parse_skeleton(skeleton_text(frames), "three.skeleton")
    assert out["positions"].shape == (8, 2, 25, 3)
    assert out["body_ids"] == [[2], [3]] and out["dropped_ids"] == [1]
    assert out["bodies"] == 3 and out["body_mask"].all()
    assert len(out["warnings"]) == 1 and "dropped body 1" in out["warnings"][0]
    assert "three.skeleton" in out["warnings"][0]
    np.testing.assert_allclose(out["positions"][:, 0, :, 0].mean(), 0, atol=0.01)
    assert out["positions"][:, 1, :, 0].mean() > 1


def test_new_body_id_after_lost_tracking_continues_a_slot():
    # 3 IDs but never more than 2 at once: ID 9 replaces ID 5 after frame 3
    frames = [[(5, pose((-0.5, 0, 3), seed=f)), (6, pose((0.5, 0, 3), seed=50 + f))] for f in range(4)]
    frames += [[(6, pose((0.5, 0, 3), seed=60 + f)), (9, pose((-0.5, 0, 3), seed=70 + f))] for f in range(4)]
    out = parse_skeleton(skeleton_text(frames), "swap.skeleton")
    assert out["dropped_ids"] == [] and out["body_mask"].all()
    slots = {b: s for s, ids in enumerate(out["body_ids"]) for b in ids}
    assert slots[5] == slots[9] != slots[6]


def test_nested_layout_and_bad_names(tmp_path):
    good = skeleton_text(one_body_frames(3))
    files = {
        "nturgb+d_skeletons/S001C001P001R001A001.skeleton": good,
        "part2/deeper/S002C002P002R002A002.skeleton": good,
        "part2/not_an_ntu_name.skeleton": good,
        "S1C1P1R1A1.skeleton": good,
        "README.txt": "hello",
    }
    reader = NTUReader(action_names={1: "drink water"})
    with Archive(make_zip(tmp_path, files)) as arc:
        items, rejected = reader.list_items(arc)
        assert [it.key for it in items] == ["S001C001P001R001A001", "S002C002P002R002A002"]
        assert items[0].meta["label_name"] == "drink water" and items[1].meta["label_name"] == "A002"
        assert items[1].meta["subject"] == "P002" and items[1].meta["view"] == "C002"
        assert sorted(r.member for r in rejected) == ["S1C1P1R1A1.skeleton", "part2/not_an_ntu_name.skeleton"]
        assert all("not an NTU name" in r.reason for r in rejected)
        seq, sk = reader.read(arc, items[1])
        assert seq.meta["member"] == "part2/deeper/S002C002P002R002A002.skeleton"
        assert sk.num_joints == 50


# ----------------------------------------------------------------------------- fixtures: rejected

def test_truncated_file():
    text = skeleton_text(one_body_frames(4))
    lines = text.split("\r\n")
    expect_error("\r\n".join(lines[:-20]), "truncated")                 # cut inside a body
    expect_error(skeleton_text(one_body_frames(4), header=6), "truncated", "6 frames")


def test_frame_count_smaller_than_data():
    expect_error(skeleton_text(one_body_frames(4), header=3), "3 frames", "more line")


def test_body_count_mismatch():
    frames = [[(1, pose()), (2, pose((1, 0, 3)))] for _ in range(3)]
    text = skeleton_text(frames)
    # frame 1 says 2 bodies but only one body's lines follow before frame 2
    lines = text.split("\r\n")
    f1 = 1 + 1 + 2 * 27            # index of frame 1's body-count line
    bad = lines[:f1] + ["2"] + lines[f1 + 1:f1 + 1 + 27] + lines[f1 + 1 + 54:]
    bad[0] = "3"
    expect_error("\r\n".join(bad), "body count", "does not match")
    # the last frame says 2 bodies but the file ends after one
    expect_error("\r\n".join(lines[:-28]) + "\r\n", "body count says 2", "ends after 1")
    # a frame says 1 body but two bodies' lines follow
    one = lines[:1] + ["1"] + lines[2:]
    expect_error("\r\n".join(one), "does not match")


def test_joint_count_not_25():
    frames = one_body_frames(2)
    frames[1] = [(7, pose()[:24])]
    expect_error(skeleton_text(frames), "joint count 24", "expected 25")


def test_non_numeric_token():
    text = skeleton_text(one_body_frames(3))
    lines = text.split("\r\n")
    lines[40] = lines[40].replace(" 1 0 0 0 ", " 1 abc 0 0 ", 1)
    err = expect_error("\r\n".join(lines), "non-numeric", "'abc'", "line 41")
    assert err.problem.startswith("line 41")
    expect_error("x12\r\n" + "\r\n".join(lines[1:]), "non-numeric", "frame count")


def test_nan_and_inf():
    text = skeleton_text(one_body_frames(3))
    lines = text.split("\r\n")
    parts = lines[33].split()
    parts[1] = "nan"
    lines[33] = " ".join(parts)
    expect_error("\r\n".join(lines), "NaN", "line 34", "frame 1")
    parts[1] = "inf"
    lines[33] = " ".join(parts)
    expect_error("\r\n".join(lines), "Inf")


def test_empty_and_bodiless_files():
    expect_error("", "empty file")
    expect_error("\r\n  \r\n", "empty file")
    expect_error("3\r\n0\r\n0\r\n0\r\n", "no frame has any body")
    expect_error("0\r\n", "no frames")


def test_reader_reports_member_on_bad_file(tmp_path):
    name = "nested/S001C001P001R001A001.skeleton"
    text = skeleton_text(one_body_frames(4), header=5)
    reader = NTUReader()
    with Archive(make_zip(tmp_path, {name: text})) as arc:
        (item,), _ = reader.list_items(arc)
        with pytest.raises(InputError) as ei:
            reader.read(arc, item)
    assert ei.value.member == name and "truncated" in ei.value.problem


def test_reader_rejects_bad_config():
    with pytest.raises(ValueError):
        NTUReader(joint_names=KINECT_JOINTS[:-1])
    with pytest.raises(ValueError):  # Kinect file order is not topological
        NTUReader(joint_names=KINECT_JOINTS)

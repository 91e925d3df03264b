"""BVH reader/writer: hand-computed FK, round trip, real members, and every bad-input case."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from conftest import archive_path

from motionsynth.data.bvh import BvhData, euler_to_matrix, parse_bvh
from motionsynth.data.types import InputError

# A small hierarchy: non-trivial offsets, a different Euler order on each joint,
# position channels on a non-root joint, an End Site, tabs and CRLF.
HAND = (
    "HIERARCHY\r\n"
    "ROOT root\r\n{\r\n\tOFFSET 1 2 3\r\n\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\r\n"
    "\tJOINT a\r\n\t{\r\n\t\tOFFSET 0 10 0\r\n\t\tCHANNELS 3 Xrotation Yrotation Zrotation\r\n"
    "\t\tJOINT b\r\n\t\t{\r\n\t\t\tOFFSET 5 0 0\r\n"
    "\t\t\tCHANNELS 6 Xposition Yposition Zposition Yrotation Zrotation Xrotation\r\n"
    "\t\t\tEnd Site\r\n\t\t\t{\r\n\t\t\t\tOFFSET 0 0 2\r\n\t\t\t}\r\n\t\t}\r\n\t}\r\n}\r\n"
    "MOTION\r\nFrames:\t2\r\nFrame Time:\t0.5\r\n"
    "0 0 0 0 0 0  0 0 0  5 0 0 0 0 0\r\n"
    "10 20 30 90 0 0\t90 0 0  7 0 0 0 0 90\r\n"
)


def test_fk_matches_hand_computed_positions():
    b = parse_bvh(HAND, "hand.bvh")
    assert b.names == ["root", "a", "b", "b_End"] and list(b.parents) == [-1, 0, 1, 2]
    assert b.fps == 2.0 and b.num_frames == 2
    p = b.positions(dtype=np.float64)
    # frame 0: identity rotations; root at its position channels (0,0,0), children add offsets
    np.testing.assert_allclose(p[0], [[0, 0, 0], [0, 10, 0], [5, 10, 0], [5, 10, 2]], atol=1e-9)
    # frame 1, by hand: root at (10,20,30), rotated 90 deg about Z: R0 maps x->y, y->-x.
    #   a = root + R0 @ (0,10,0) = (10-10, 20, 30) = (0, 20, 30)
    #   a's rotation: 90 deg about X (order XYZ, X first): R1 maps y->z, z->-y; world Ra = R0 @ R1
    #   b = a + Ra @ (7,0,0) [position channels replace b's OFFSET] = a + R0 @ (7,0,0) = (0, 27, 30)
    #   b's rotation: Y 0, Z 0, X 90: Rb_local = Rx(90); world Rb = R0 @ R1 @ Rx(90)
    #   End = b + Rb @ (0,0,2): Rx(90) @ (0,0,2) = (0,-2,0); R1 @ (0,-2,0) = (0,0,-2); R0 @ (0,0,-2) = (0,0,-2)
    np.testing.assert_allclose(p[1], [[10, 20, 30], [0, 20, 30], [0, 27, 30], [0, 27, 28]], atol=1e-9)
    # float32 (the default) agrees far below a millimetre
    np.testing.assert_allclose(b.positions(), p, atol=1e-4)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_matches_matrix_product(order):
    rng = np.random.default_rng(0)
    ang = rng.uniform(-180, 180, (4, 3))

    def rot(axis, deg):
        c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
        return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
                "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]

    ref = [rot(order[0], a[0]) @ rot(order[1], a[1]) @ rot(order[2], a[2]) for a in ang]
    np.testing.assert_allclose(euler_to_matrix(ang, order), ref, atol=1e-12)


def test_round_trip_write_then_read():
    b = parse_bvh(HAND, "hand.bvh")
    rng = np.random.default_rng(1)
    motion = rng.uniform(-90, 90, (50, b.num_channels))
    b2 = BvhData(b.names, b.parents, b.offsets, b.channels, motion, 1 / 30, b.is_end)
    back = parse_bvh(b2.to_text(precision=8), "rt.bvh")
    assert back.names == b.names and back.channels == b.channels
    np.testing.assert_allclose(back.motion, motion, atol=1e-7)
    np.testing.assert_allclose(back.positions(dtype=np.float64), b2.positions(dtype=np.float64), atol=1e-6)
    assert abs(back.fps - 30) < 1e-4


def test_real_cmu_member():
    with zipfile.ZipFile(archive_path("cmu_aclstm")) as z:
        b = parse_bvh(z.read("martial/04.bvh"), "martial/04.bvh")
    assert b.num_frames == 1317 and abs(b.fps - 120) < 1e-3
    p = b.positions() * 0.01
    assert p.shape == (1317, 57, 3)
    assert len(b.skeleton(end_sites=False).names) == 43
    height = p[0, :, 1].max() - p[0, :, 1].min()
    assert 1.2 < height < 2.0, height
    assert np.isfinite(p).all()


def test_real_bandai_member_with_position_channels_everywhere():
    with zipfile.ZipFile(archive_path("bandai1")) as z:
        b = parse_bvh(z.read("data/dataset-1_bye_feminine_001.bvh"), "bye")
    assert all(len(c) == 6 for c in b.channels if c)  # every joint has 6 channels
    p = b.positions(end_sites=False) * 0.01
    assert p.shape == (328, 22, 3)
    np.testing.assert_allclose(p[:, 0], 0, atol=1e-6)  # joint_Root is static at the origin
    names = b.skeleton(end_sites=False).names
    head, foot = names.index("Head"), names.index("Toes_L")
    assert 1.2 < (p[:, head, 1] - p[:, foot, 1]).mean() < 2.0  # Y up, metres


def _bad(text: str, *words: str):
    with pytest.raises(InputError) as e:
        parse_bvh(text, "bad/member.bvh")
    msg = str(e.value)
    assert msg.startswith("bad/member.bvh: "), msg
    for w in words:
        assert w in msg, msg
    return msg


GOOD_HEAD = HAND.split("MOTION")[0]


@pytest.mark.parametrize("text,words", [
    ("", ["empty file"]),
    ("   \n\n", ["empty file"]),
    (GOOD_HEAD, ["no MOTION"]),
    (GOOD_HEAD.replace("}\r\n}\r\n}", "}\r\n"), ["no MOTION"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0.5\n" + "0 " * 15 + "\n" + "0 " * 7, ["truncated", "last frame 1", "7 of 15"]),
    (GOOD_HEAD + "MOTION\nFrames: 3\nFrame Time: 0.5\n" + ("0 " * 15 + "\n") * 2, ["truncated", "3 frames", "holds 2"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0.5\n" + "0 " * 15 + "\n" + "0 x " + "0 " * 13 + "\n", ["non-numeric"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0.5\n" + "0 " * 15 + "\n" + "0 nan " + "0 " * 13 + "\n", ["NaN or Inf", "frame 1"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0.5\n" + "0 " * 15 + "\n" + "inf " + "0 " * 14 + "\n", ["NaN or Inf"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0.5\n" + ("0 " * 16 + "\n") * 2, ["channel count", "16", "15"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0.5\n" + "0 " * 15 + "\n" + "0 " * 17 + "\n", ["channel count"]),
    (GOOD_HEAD + "MOTION\nFrames: two\nFrame Time: 0.5\n", ["non-numeric"]),
    (GOOD_HEAD + "MOTION\nFrames: 2\nFrame Time: 0\n" + ("0 " * 15 + "\n") * 2, ["Frame Time"]),
    (GOOD_HEAD.replace("Xrotation Yrotation Zrotation", "Xrotation Yrotation Wrotation")
     + "MOTION\nFrames: 1\nFrame Time: 0.5\n" + "0 " * 15, ["bad CHANNELS", "'a'"]),
    (GOOD_HEAD.replace("OFFSET 0 10 0", "OFFSET 0 ten 0") + "MOTION\nFrames: 1\nFrame Time: 0.5\n" + "0 " * 15, ["malformed hierarchy"]),
])
def test_bad_bvh_inputs(text, words):
    _bad(text, *words)


def test_irregular_whitespace_is_accepted():
    b = parse_bvh(HAND.replace(" 0 0 0 0 0 0  0", "   0\t0 0 0 0 0 \t 0"), "ws.bvh")
    np.testing.assert_allclose(b.positions(dtype=np.float64), parse_bvh(HAND).positions(dtype=np.float64))

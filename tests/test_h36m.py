"""Tests of the Human3.6M reader: camera model, the real archive, and bad inputs."""

from __future__ import annotations

import io
import json
import math
import re
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from motionsynth.data.archive import Archive
from motionsynth.data.h36m import (
    H36M_ACTIONS, H36M_JOINTS, H36M_PARENTS, H36MReader, load_cameras, project_point_radial,
)
from motionsynth.data.types import InputError, Item

REPO = Path(__file__).resolve().parents[1]
H36M_ZIP = REPO.parent / "shared" / "dvc-store" / "files" / "md5" / "74" / "0fb0c967095eedb8cb2e189ca4bfb8"
SMALL = "h36m/S1/MyPoses/3D_positions/Posing.h5"  # the smallest file (992 frames)


# ----------------------------------------------------------------------------- camera model

def test_projection_hand_computed():
    # R: 90 degrees about Z. P - T = (-0.2, 0.4, 2) -> X = R @ (P - T) = (-0.4, -0.2, 2)
    R = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    T = [[1.0], [2.0], [3.0]]  # (3, 1) as stored in cameras.h5
    P = [0.8, 2.4, 5.0]
    f, c = [[1000.0], [1100.0]], [[500.0], [400.0]]
    k, p = [0.1, 0.2, 0.3], [0.01, 0.02]
    # x = -0.2, y = -0.1, r2 = 0.05
    # radial = 1 + 0.1*0.05 + 0.2*0.0025 + 0.3*0.000125 = 1.0055375
    # tan = p1*y + p2*x = -0.001 - 0.004 = -0.005
    # x' = -0.2 * 1.0005375 + p2*r2 = -0.1991075 ; y' = -0.1 * 1.0005375 + p1*r2 = -0.09955375
    # u = 1000 * x' + 500 = 300.8925 ; v = 1100 * y' + 400 = 290.490875
    uv, depth = project_point_radial(np.array(P), R, T, f, c, k, p)
    assert uv.shape == (2,) and depth.shape == ()
    np.testing.assert_allclose(uv, [300.8925, 290.490875], rtol=0, atol=1e-9)
    np.testing.assert_allclose(depth, 2.0, atol=1e-12)


def _scalar_projection(P, R, T, f, c, k, p):
    """Plain-Python reference of the 3d-pose-baseline formula, one point at a time."""
    d = [P[i] - T[i] for i in range(3)]
    X = [sum(R[r][i] * d[i] for i in range(3)) for r in range(3)]
    x, y = X[0] / X[2], X[1] / X[2]
    r2 = x * x + y * y
    radial = 1 + k[0] * r2 + k[1] * r2 ** 2 + k[2] * r2 ** 3
    tan = p[0] * y + p[1] * x
    xd = x * (radial + tan) + p[1] * r2
    yd = y * (radial + tan) + p[0] * r2
    return (f[0] * xd + c[0], f[1] * yd + c[1]), X[2]


def test_projection_matches_scalar_reference_on_any_leading_shape():
    a, b, g = 0.3, -0.7, 1.1  # a general rotation R = Rz(g) Ry(b) Rx(a)
    Rx = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    Ry = [[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]]
    Rz = [[math.cos(g), -math.sin(g), 0], [math.sin(g), math.cos(g), 0], [0, 0, 1]]
    mul = lambda A, B: [[sum(A[i][m] * B[m][j] for m in range(3)) for j in range(3)] for i in range(3)]  # noqa: E731
    R = mul(Rz, mul(Ry, Rx))
    T, f, c = [100.0, -250.0, 30.0], [1145.0, 1143.8], [512.5, 515.4]
    k, p = [-0.207, 0.248, -0.0031], [-0.0014, -0.00098]
    rng = np.random.default_rng(0)
    cam_dir = np.array(R)[2]  # points in front of the camera: T + depth * optical axis + jitter
    P = T + 4000.0 * cam_dir + rng.normal(scale=600.0, size=(2, 3, 5, 3))
    uv, depth = project_point_radial(P, R, T, f, c, k, p)
    assert uv.shape == (2, 3, 5, 2) and depth.shape == (2, 3, 5)
    for idx in np.ndindex(2, 3, 5):
        (u, v), z = _scalar_projection(P[idx].tolist(), R, T, f, c, k, p)
        np.testing.assert_allclose(uv[idx], [u, v], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(depth[idx], z, rtol=1e-12)


def test_zero_distortion_is_pinhole():
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))
    T = np.array([10.0, 20.0, -30.0])
    P = T + (R.T @ np.array([0.0, 0.0, 5.0])) + rng.normal(scale=0.5, size=(7, 3))
    f, c = np.array([900.0, 950.0]), np.array([480.0, 500.0])
    uv, depth = project_point_radial(P, R, T, f, c, np.zeros(3), np.zeros(2))
    X = (P - T) @ R.T
    np.testing.assert_allclose(depth, X[:, 2], rtol=1e-12)
    np.testing.assert_allclose(uv, f * X[:, :2] / X[:, 2:] + c, rtol=1e-12)


# ----------------------------------------------------------------------------- real archive

@pytest.fixture(scope="module")
def archive():
    with Archive(H36M_ZIP) as a:
        yield a


@pytest.fixture(scope="module")
def reader():
    return H36MReader(actions=list(H36M_ACTIONS))


@pytest.fixture(scope="module")
def items(archive, reader):
    return reader.list_items(archive)


@pytest.fixture(scope="module")
def small(archive, reader, items):
    item = next(it for it in items[0] if it.member == SMALL)
    return item, *reader.read(archive, item)


def test_config_instantiates_the_reader():
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(REPO / "conf" / "dataset" / "h36m.yaml")
    assert cfg.name == "h36m" and cfg.archive == "h36m.zip" and "research use only" in cfg.licence
    r = instantiate(cfg.reader)
    assert isinstance(r, H36MReader)
    assert r.actions == H36M_ACTIONS and r.joints == H36M_JOINTS and r.parent_names == H36M_PARENTS
    assert r.names[0] == "Hip" and len(r.names) == 17 and r.fps == 50.0


def test_list_items_real(items):
    its, rejected = items
    assert rejected == []
    assert len(its) == 135
    assert len({it.key for it in its}) == 135
    assert {it.meta["action"] for it in its} == set(H36M_ACTIONS)
    assert {it.meta["subject"] for it in its} == {f"S{s}" for s in (1, 5, 6, 7, 8, 9, 11)}
    by_key = {it.key: it for it in its}
    d1 = by_key["S1_Directions_1"]
    assert d1.member == "h36m/S1/MyPoses/3D_positions/Directions 1.h5"
    assert d1.meta == {"subject": "S1", "subject_id": 1, "action": "Directions", "label_name": "Directions",
                       "label": 0, "trial": "1", "view": "all", "member": d1.member}
    sd = by_key["S1_SittingDown"]
    assert sd.meta["action"] == "SittingDown" and sd.meta["label"] == 7 and sd.meta["trial"] == ""
    for it in its:
        assert it.meta["label"] == H36M_ACTIONS.index(it.meta["action"])
    assert "S5_Discussion" not in by_key and "S7_Discussion" not in by_key


def test_read_real_file(small):
    item, seq, skel = small
    T = seq.num_frames
    assert T == 992
    assert seq.positions.shape == (T, 17, 3) and seq.positions.dtype == np.float32
    assert seq.views2d.shape == (T, 4, 17, 2) and seq.views2d.dtype == np.float32
    assert seq.view_depth.shape == (T, 4) and seq.view_depth.dtype == np.float32
    assert seq.fps == 50.0
    assert seq.meta["sequence_id"] == item.key and seq.meta["member"] == SMALL
    assert seq.meta["subject"] == "S1" and seq.meta["label_name"] == "Posing"
    # metres, Y up: the head is 1.3 to 2.0 m above the feet
    y = seq.positions[..., 1]
    head, feet = skel.index("Head"), skel.indices(["LFoot", "RFoot"])
    height = np.median(y[:, head] - y[:, feet].min(axis=1))
    assert 1.3 < height < 2.0
    assert np.abs(seq.positions).max() < 10.0  # metres, not millimetres
    # the projections lie inside the 1000 x 1002 images
    u, v = seq.views2d[..., 0], seq.views2d[..., 1]
    inside = (u >= 0) & (u < 1000) & (v >= 0) & (v < 1002)
    assert inside.mean() > 0.99
    # the subject stands 3 to 8 m in front of every camera
    assert 3.0 < seq.view_depth.min() and seq.view_depth.max() < 8.0
    # head above hip in every image (image v grows downwards)
    hip = skel.index("Hip")
    assert (np.median(v[:, :, head] - v[:, :, hip], axis=0) < -50).all()


def test_views_are_projections_of_the_positions(archive, small):
    _, seq, skel = small
    # back to the source frame: project (x, y, z) = (x, z, -y) in mm  =>  world = (x, -z, y) * 1000
    pos = seq.positions.astype(np.float64)
    world = np.stack([pos[..., 0], -pos[..., 2], pos[..., 1]], axis=-1) * 1000.0
    cams = load_cameras(archive)
    for v, cid in enumerate((1, 2, 3, 4)):
        cam = cams[(1, cid)]
        uv, depth = project_point_radial(world, cam["R"], cam["T"], cam["f"], cam["c"], cam["k"], cam["p"])
        np.testing.assert_allclose(seq.views2d[:, v], uv, atol=0.05)
        np.testing.assert_allclose(seq.view_depth[:, v], depth[:, skel.index("Hip")] / 1000.0, atol=1e-4)


def test_skeleton_real(archive, reader, items, small):
    _, seq, skel = small
    assert skel.names == list(H36M_JOINTS.values())
    assert skel.root == "Hip" and skel.hips == ("LHip", "RHip") and skel.shoulders == ("LShoulder", "RShoulder")
    assert set(skel.feet) == {"LFoot", "RFoot"}
    assert skel.parents[0] == -1 and (skel.parents[1:] >= 0).all()
    np.testing.assert_array_equal(skel.offsets[0], 0)
    thigh = np.linalg.norm(skel.offsets[skel.index("RKnee")])
    assert 0.3 < thigh < 0.6
    # same subject -> same skeleton, whichever file is read
    other = next(it for it in items[0] if it.key == "S1_Greeting")
    _, skel2 = reader.read(archive, other)
    np.testing.assert_array_equal(skel.offsets, skel2.offsets)


def test_cameras_real(archive):
    cams = load_cameras(archive)
    assert sorted(cams) == [(s, c) for s in (1, 5, 6, 7, 8, 9, 11) for c in (1, 2, 3, 4)]
    assert [cams[(1, c)]["name"] for c in (1, 2, 3, 4)] == ["54138969", "55011271", "58860488", "60457274"]
    for cam in cams.values():
        np.testing.assert_allclose(cam["R"] @ cam["R"].T, np.eye(3), atol=1e-6)
        assert cam["T"].shape == (3,) and cam["f"].shape == (2,) and cam["k"].shape == (3,)


def test_extras_and_notes_real(archive, reader):
    extras = json.loads(json.dumps(reader.extras(archive)))
    cams = extras["cameras"]
    assert sorted(cams) == sorted(f"S{s}" for s in (1, 5, 6, 7, 8, 9, 11))
    assert sorted(cams["S1"]) == ["1", "2", "3", "4"]
    c1 = cams["S1"]["1"]
    assert c1["name"] == "54138969" and np.array(c1["R"]).shape == (3, 3) and len(c1["T"]) == 3
    notes = reader.notes(archive)
    got = {" ".join(n.split(":")[0].split()): int(re.search(r"\((\d+) missing in source\)", n).group(1))
           for n in notes}
    assert got == {"S5 Discussion": 2, "S7 Discussion": 1, "S7 SittingDown": 1, "S9 Discussion": 1}
    assert sum(got.values()) == 5


# ----------------------------------------------------------------------------- synthetic archives

DIR = "h36m/S1/MyPoses/3D_positions/"


def _h5(build) -> bytes:
    bio = io.BytesIO()
    with h5py.File(bio, "w") as f:
        build(f)
    return bio.getvalue()


def _cameras_h5() -> bytes:
    def build(f):
        for c in (1, 2, 3, 4):
            g = f.create_group(f"subject1/camera{c}")
            g["R"] = np.eye(3)
            g["T"] = np.array([[0.0], [0.0], [-5000.0 - 100.0 * c]])
            g["f"] = np.array([[1000.0], [1000.0]])
            g["c"] = np.array([[500.0], [500.0]])
            g["k"] = np.zeros((3, 1))
            g["p"] = np.zeros((2, 1))
            g["Name"] = np.array([[float(ord(ch))] for ch in f"1000000{c}"])
    return _h5(build)


def _positions(rows: int = 96, frames: int = 10, nan_at: int | None = None) -> np.ndarray:
    rng = np.random.default_rng(rows * 1000 + frames)
    data = rng.normal(scale=300.0, size=(rows, frames))
    if nan_at is not None:
        data[5, nan_at] = np.nan
    return data


@pytest.fixture()
def synthetic(tmp_path):
    members = {
        "h36m/cameras.h5": _cameras_h5(),
        DIR + "Directions.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions())),
        DIR + "Directions 1.h5": _h5(lambda f: f.create_dataset("positions", data=_positions())),
        DIR + "Eating.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions(rows=95))),
        DIR + "Eating 1.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions(nan_at=3))),
        DIR + "Greeting.h5": np.random.default_rng(7).bytes(4096),
        DIR + "Greeting 1.h5": _h5(lambda f: f.create_dataset("3D_positions", data=np.zeros((96, 0)))),
        DIR + "Walking 1.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions())),
        DIR + "WalkDog.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions())),
        DIR + "WalkDog 1.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions())),
        DIR + "SittingDown 2.h5": _h5(lambda f: f.create_dataset("3D_positions", data=_positions())),
    }
    path = tmp_path / "h36m_synthetic.zip"
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    with Archive(path) as a:
        yield a


def _item(reader, archive, key):
    return next(it for it in reader.list_items(archive)[0] if it.key == key)


def test_synthetic_items_and_names(synthetic, reader):
    its, rejected = reader.list_items(synthetic)
    assert rejected == []
    keys = {it.key: it.meta for it in its}
    assert "S1_WalkDog" not in keys and "S1_WalkDog_1" not in keys  # another action, not an item
    assert keys["S1_Walking_1"]["action"] == "Walking" and keys["S1_Walking_1"]["trial"] == "1"
    assert keys["S1_SittingDown_2"]["action"] == "SittingDown" and keys["S1_SittingDown_2"]["label"] == 7
    assert len(its) == 8  # Directions + 5 bad + Walking 1 + SittingDown 2; WalkDog is not an item


def test_synthetic_good_file(synthetic, reader):
    seq, skel = reader.read(synthetic, _item(reader, synthetic, "S1_Directions"))
    world = _positions().T.reshape(10, 32, 3)[:, list(H36M_JOINTS)]
    expect = np.stack([world[..., 0], world[..., 2], -world[..., 1]], axis=-1) / 1000.0
    np.testing.assert_allclose(seq.positions, expect, atol=1e-6)
    # camera c: R = I, T = (0, 0, -5000 - 100 c) -> depth = z + 5000 + 100 c, uv = 1000 xy / depth + 500
    for v, cid in enumerate((1, 2, 3, 4)):
        depth = world[..., 2] + 5000.0 + 100.0 * cid
        np.testing.assert_allclose(seq.views2d[:, v], 1000.0 * world[..., :2] / depth[..., None] + 500.0,
                                   rtol=1e-5)
        np.testing.assert_allclose(seq.view_depth[:, v], depth[:, 0] / 1000.0, rtol=1e-6)
    assert skel.num_joints == 17
    assert reader.extras(synthetic)["cameras"]["S1"]["4"]["name"] == "10000004"


@pytest.mark.parametrize("name, problem", [
    ("Directions 1.h5", r"no dataset '3D_positions'"),
    ("Eating.h5", r"must be \(96, T\).*got shape \(95, 10\)"),
    ("Eating 1.h5", r"NaN or Inf in 1 frame\(s\).*first at frame 3"),
    ("Greeting.h5", r"not a readable HDF5 file"),
    ("Greeting 1.h5", r"no frames"),
])
def test_bad_inputs_raise_input_error(synthetic, reader, name, problem):
    member = DIR + name
    item = next(it for it in reader.list_items(synthetic)[0] if it.member == member)
    with pytest.raises(InputError) as err:
        reader.read(synthetic, item)
    assert err.value.member == member
    assert member in str(err.value)
    assert re.search(problem, err.value.problem), err.value.problem


def test_corrupt_camera_file_names_the_member():
    with pytest.raises(InputError) as err:
        load_cameras(b"this is not hdf5", member="h36m/cameras.h5")
    assert err.value.member == "h36m/cameras.h5" and "HDF5" in err.value.problem
    bad = _h5(lambda f: f.create_dataset("subject1/camera1/R", data=np.eye(2)))
    with pytest.raises(InputError, match=r"subject1/camera1/R must hold 9 values"):
        load_cameras(bad)


def test_missing_camera_file(tmp_path, reader):
    path = tmp_path / "nocam.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(DIR + "Directions.h5", _h5(lambda f: f.create_dataset("3D_positions", data=_positions())))
    with Archive(path) as a:
        with pytest.raises(InputError) as err:
            reader.read(a, _item(reader, a, "S1_Directions"))
    assert err.value.member == "h36m/cameras.h5" and "missing" in err.value.problem


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="must come before"):
        H36MReader(actions=["Walking"], joints={1: "RHip", 0: "Hip"}, parents={"RHip": "Hip"})
    with pytest.raises(ValueError, match="outside"):
        H36MReader(actions=["Walking"], joints={0: "Hip", 40: "X"}, parents={"X": "Hip"})
    with pytest.raises(ValueError, match="not in reader.joints"):
        H36MReader(actions=["Walking"], joints={0: "Hip"}, parents={"Knee": "Hip"})


def test_hand_made_item_outside_the_listing(synthetic, reader):
    item = Item("custom", {"motion": DIR + "Walking 1.h5"}, {})
    seq, skel = reader.read(synthetic, item)
    assert seq.meta["sequence_id"] == "custom" and skel.num_joints == 17

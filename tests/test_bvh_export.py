"""BVH export of joint positions: real-data round trips through our own reader, bone
lengths on positions that did not come from a BVH, the solver's edge cases, and errors.

The acceptance criterion: an exported file, re-read by ``parse_bvh(...).positions()``
(and by the ingest reader), gives back the input joint positions within 1 mm.
``test_acceptance_check_can_fail`` shows the same check rejecting broken files.
"""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from conftest import archive_path, dataset_cfg, make_zip

from motionsynth.data.archive import Archive
from motionsynth.data.bvh import BvhData, BvhReader, euler_to_matrix, parse_bvh
from motionsynth.data.types import Skeleton
from motionsynth.viz.bvh_export import (
    ORDERS, dataset_scale, matrix_to_euler, positions_to_bvh, read_back_positions,
    solve_rotations, write_bvh,
)

MM = 1e-3  # metres
CM = 100.0  # file units per metre of the CMU and Bandai sources (reader.scale 0.01)


def load(dataset: str, member: str) -> BvhData:
    with zipfile.ZipFile(archive_path(dataset)) as z:
        return parse_bvh(z.read(member), member)


def reread(text: str, skel: Skeleton, scale: float = CM) -> np.ndarray:
    """The acceptance path, spelled out: parse_bvh -> FK positions -> metres, joints by name
    (End Sites are named '<parent>_End' by the reader)."""
    b = parse_bvh(text, "exported.bvh")
    pos = b.positions(dtype=np.float64) / scale
    ends = set(skel.end_sites)
    idx = [b.names.index(f"{skel.names[skel.parents[j]]}_End" if n in ends else n)
           for j, n in enumerate(skel.names)]
    return pos[:, idx]


def max_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b, axis=-1).max())


def bone_lengths(pos: np.ndarray, skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    js = np.flatnonzero((skel.parents >= 0) & (np.linalg.norm(skel.offsets, axis=1) > 0))
    obs = np.linalg.norm(pos[:, js] - pos[:, skel.parents[js]], axis=-1)
    return obs, np.linalg.norm(skel.offsets[js].astype(np.float64), axis=-1)


@pytest.fixture(scope="module")
def cmu():
    """CMU martial/04 (120 fps, 57 nodes with End Sites, fingers, eyes), 400 frames."""
    b = load("cmu_aclstm", "martial/04.bvh")
    return b, b.skeleton(end_sites=True, scale=0.01), b.positions(dtype=np.float64)[200:600] * 0.01


# ----------------------------------------------------------------------------- real data

@pytest.mark.parametrize("order", ["ZXY", "ZYX"])
def test_cmu_round_trip_within_1mm(cmu, order):
    b, skel, pos = cmu
    out = positions_to_bvh(pos, skel, fps=b.fps, order=order, scale=CM)
    text = out.to_text()
    back = reread(text, skel)
    err = max_err(back, pos)
    print(f"CMU {order}: max per-joint error {err * 1e3:.2e} mm over {len(pos)} frames x {skel.num_joints} joints")
    assert err < 1 * MM
    assert err < 1e-3 * MM  # in fact exact to the text's 6 decimals

    # Layout: root 6 channels, joints 3 rotations in `order`, End Sites none; source units (cm).
    r = parse_bvh(text)
    assert r.channels[0] == ["Xposition", "Yposition", "Zposition"] + [f"{a}rotation" for a in order]
    assert all(c == [f"{a}rotation" for a in order] for c, e in zip(r.channels[1:], r.is_end[1:]) if not e)
    assert all(c == [] for c, e in zip(r.channels, r.is_end) if e)
    assert r.names == b.names and list(r.parents) == list(b.parents)  # same hierarchy as the source
    np.testing.assert_allclose(r.offsets, b.offsets, atol=1e-5)        # same OFFSETs, in cm
    assert abs(r.fps - b.fps) < 1e-2 and r.num_frames == len(pos)
    assert np.isfinite(r.motion).all()


def test_cmu_round_trip_through_the_ingest_reader(tmp_path, cmu):
    """The exported file, read the way `ingest` reads the dataset (conf/dataset/cmu_aclstm.yaml),
    gives the same Sequence and Skeleton as the source file, i.e. it overlays the original."""
    b, skel, pos = cmu
    cfg = dataset_cfg("cmu_aclstm")
    reader = BvhReader(**{k: v for k, v in cfg["reader"].items() if k != "_target_"})
    scale = dataset_scale(cfg)
    assert scale == pytest.approx(CM)
    path = write_bvh(tmp_path / "out" / "gen.bvh", pos, skel, b.fps, scale=scale)
    with Archive(make_zip(tmp_path / "gen.zip", {"martial/gen.bvh": path.read_bytes()})) as arc:
        items, rejected = reader.list_items(arc)
        assert not rejected and len(items) == 1
        seq, skel_back = reader.read(arc, items[0])
    assert skel_back.names == skel.names
    np.testing.assert_allclose(skel_back.offsets, skel.offsets, atol=1e-6)
    assert seq.positions.shape == pos.shape
    assert max_err(seq.positions.astype(np.float64), pos) < 1 * MM  # float32 FK: ~1e-6 m


def test_bandai_prepared_skeleton_round_trip():
    """Bandai-2 locomotion on the skeleton the models see (joint_Root dropped, Hips is the root,
    as in conf/dataset/bandai2_locomotion.yaml's prepare), every frame of a short take."""
    b = load("bandai2_locomotion", "data/dataset-2_run_feminine_021.bvh")
    full = b.skeleton(end_sites=False, scale=0.01)
    keep = [n for n in full.names if n != "joint_Root"]
    skel = full.subset(keep)
    pos = b.positions(end_sites=False, dtype=np.float64)[:, full.indices(keep)] * 0.01
    text = positions_to_bvh(pos, skel, fps=b.fps, scale=CM).to_text()
    err = max_err(reread(text, skel), pos)
    print(f"Bandai-2 (21 joints): max per-joint error {err * 1e3:.2e} mm")
    assert err < 1 * MM
    r = parse_bvh(text)
    assert r.names[0] == "Hips" and r.channels[0][:3] == ["Xposition", "Yposition", "Zposition"]
    # leaf joints (Head, Hands, Toes) end in a zero-length End Site, as in the source file
    assert sorted(n for n, e in zip(r.names, r.is_end) if e) == sorted(
        f"{n}_End" for n in ("Head", "Hand_L", "Hand_R", "Toes_L", "Toes_R"))


@pytest.mark.parametrize("end_sites", [False, True])
def test_bandai_full_hierarchy_with_translated_hips(end_sites):
    """Bandai-1's full hierarchy: a static joint_Root at the origin and a moving Hips below it,
    whose distance to joint_Root is no bone: Hips gets position channels (translate=).
    With end_sites=True the skeleton has zero-length End Sites (no direction information)."""
    b = load("bandai1", "data/dataset-1_bye_feminine_001.bvh")
    skel = b.skeleton(end_sites=end_sites, scale=0.01)
    pos = b.positions(end_sites=end_sites, dtype=np.float64)[::2] * 0.01
    out = positions_to_bvh(pos, skel, fps=b.fps / 2, scale=CM, translate=["Hips"])
    err = max_err(reread(out.to_text(), skel), pos)
    assert err < 1 * MM
    hips = out.names.index("Hips")
    assert out.channels[hips][:3] == ["Xposition", "Yposition", "Zposition"]


# ------------------------------------------------------------------ positions not from a BVH

def test_noisy_positions_get_the_skeletons_bone_lengths(cmu):
    """Generated-motion-like input: bones stretched 3 % and 1 mm noise per coordinate.
    The re-read file has exactly the skeleton's bone lengths and stays close to the input."""
    b, skel, clean = cmu
    rng = np.random.default_rng(0)
    root = clean[:, :1]
    gen = root + (clean - root) * 1.03 + rng.normal(0, 1 * MM, clean.shape)
    text = positions_to_bvh(gen, skel, fps=b.fps, scale=CM).to_text()
    back = reread(text, skel)
    obs, rest = bone_lengths(back, skel)
    rel = np.abs(obs / rest - 1).max()
    err = np.linalg.norm(back - gen, axis=-1)
    print(f"noisy input: bone-length rel. error {rel:.1e}; distance to input mean {err.mean() * 1e3:.2f} mm, "
          f"max {err.max() * 1e3:.2f} mm (input bones are off by 3 % + noise)")
    assert rel < 1e-6
    # Directions are kept, lengths are the skeleton's: the gap is the input's own bone error.
    assert err.mean() < 30 * MM and err.max() < 100 * MM
    assert np.isfinite(back).all()
    np.testing.assert_allclose(back[:, 0], gen[:, 0], atol=1e-6)  # the root is where it was asked to be
    # ... and the re-read file is what the solver intended, to the text's precision
    _, _, fit = solve_rotations(gen, skel)
    assert max_err(back, fit) < 1e-6


def test_directions_are_kept_on_a_single_chain():
    """One-child joints: the re-read bone directions equal the input's, whatever their length."""
    skel = Skeleton(["r", "a", "b", "c"], [-1, 0, 1, 2], [[0, 0, 0], [0, 0.5, 0], [0.3, 0, 0], [0, 0, 0.2]])
    rng = np.random.default_rng(1)
    pos = np.cumsum(rng.normal(0, 0.3, (50, 4, 3)), axis=1)
    back = read_back_positions(positions_to_bvh(pos, skel, 30, bone_tolerance=None), skel)
    for j in (1, 2, 3):
        d_in = pos[:, j] - pos[:, j - 1]
        d_out = back[:, j] - back[:, j - 1]
        cos = np.sum(d_in * d_out, -1) / np.linalg.norm(d_in, axis=-1) / np.linalg.norm(d_out, axis=-1)
        assert np.all(cos > 1 - 1e-9)
        np.testing.assert_allclose(np.linalg.norm(d_out, axis=-1), np.linalg.norm(skel.offsets[j]), rtol=1e-6)


def test_degenerate_bones_give_no_nan():
    """A bone flipped exactly against its rest direction (180 deg, no unique minimal rotation),
    an observed bone of zero length, and zero-length rest offsets."""
    skel = Skeleton(["r", "a", "b", "c", "e"], [-1, 0, 1, 2, 3],
                    [[0, 0, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 0, 0]], end_sites=["e"])
    pos = np.array([[[0, 0, 0], [0, 1, 0], [0, 2, 0], [1, 2, 0], [1, 2, 0]],    # rest pose
                    [[0, 0, 0], [0, 1, 0], [0, 0, 0], [0, 0, 1], [0, 0, 1]],    # b folded back on r
                    [[0, 0, 0], [0, 1, 0], [0, 1, 0], [1, 1, 0], [1, 1, 0]]],   # b on top of a
                   dtype=float)
    out = positions_to_bvh(pos, skel, 30, bone_tolerance=None)
    assert np.isfinite(out.motion).all()
    back = read_back_positions(out, skel)
    assert np.isfinite(back).all()
    np.testing.assert_allclose(back[:2], pos[:2], atol=1e-6)  # the flip is solved exactly
    np.testing.assert_allclose(np.linalg.norm(back[2, 2] - back[2, 1]), 1.0, atol=1e-6)  # length kept


def test_several_children_best_fit_rotation():
    """Kabsch on a 3-child joint: an exact rotation is recovered (det +1), and a mirrored
    pose (improper) still gives a proper rotation."""
    off = [[0, 0, 0], [0, 1, 0], [0.3, -0.1, 0], [-0.3, -0.1, 0.05]]
    skel = Skeleton(["hips", "spine", "l", "r"], [-1, 0, 0, 0], off)
    ang = np.random.default_rng(2).uniform(-180, 180, (64, 3))
    R = euler_to_matrix(ang, "YXZ")
    pos = np.einsum("tij,kj->tki", R, skel.offsets.astype(float)) + 5.0
    local, glob, fit = solve_rotations(pos, skel)
    np.testing.assert_allclose(local[:, 0], R, atol=1e-9)
    np.testing.assert_allclose(fit, pos, atol=1e-9)
    mirrored = pos * np.array([-1, 1, 1])
    local, _, _ = solve_rotations(mirrored, skel)
    np.testing.assert_allclose(np.linalg.det(local[:, 0]), 1.0, atol=1e-9)


def test_skeleton_order_need_not_be_depth_first():
    """Motion columns must follow the hierarchy text (depth-first); a breadth-first skeleton
    is reordered on export and still reads back to the right joints."""
    bfs = Skeleton(["root", "a", "b", "a1", "b1", "a2"], [-1, 0, 0, 1, 2, 3],
                   [[0, 0, 0], [0, 1, 0], [0.5, 0, 0], [0, 0.7, 0.1], [0.4, -0.2, 0], [0, 0, 0.3]])
    # ground truth from our FK on the depth-first equivalent
    dfs_order = [0, 1, 3, 5, 2, 4]
    inv = np.argsort(dfs_order)
    parents_dfs = [-1 if bfs.parents[j] < 0 else int(inv[bfs.parents[j]]) for j in dfs_order]
    chans = [["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]] + \
        [["Zrotation", "Xrotation", "Yrotation"]] * 5
    motion = np.random.default_rng(3).uniform(-60, 60, (20, 3 + 3 * 6))
    ref = BvhData([bfs.names[j] for j in dfs_order], parents_dfs, bfs.offsets[dfs_order], chans, motion, 1 / 30)
    pos = ref.positions(dtype=np.float64)[:, inv]  # back to the skeleton's (BFS) order
    out = positions_to_bvh(pos, bfs, 30)
    assert out.names[:4] == ["root", "a", "a1", "a2"]
    assert max_err(reread(out.to_text(), bfs, 1.0), pos) < 1e-6


def test_single_frame_and_write_bvh(tmp_path, cmu):
    b, skel, pos = cmu
    path = write_bvh(tmp_path / "one.bvh", pos[:1], skel, 30.0, scale=CM)
    r = parse_bvh(path.read_bytes())
    assert r.num_frames == 1 and abs(r.fps - 30) < 1e-3
    assert max_err(reread(path.read_text(), skel), pos[:1]) < 1 * MM


# ----------------------------------------------------------------------------- Euler

@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_inverts_euler_to_matrix_even_at_gimbal_lock(order):
    rng = np.random.default_rng(4)
    ang = rng.uniform(-180, 180, (500, 3))
    ang[:100, 1] = 90.0   # exact gimbal lock, both signs
    ang[100:200, 1] = -90.0
    ang[200:250, 1] = 90.0 - 1e-7  # nearly locked
    M = euler_to_matrix(ang, order)
    e = matrix_to_euler(M, order)
    assert np.isfinite(e).all()
    assert np.all(np.abs(e[:, 1]) <= 90.0 + 1e-9)
    np.testing.assert_allclose(euler_to_matrix(e, order), M, atol=1e-9)

    # Locked rotations as a solver produces them (products like G_p^T @ G_j): the zero
    # entries are cancellations of O(1) terms, ~1e-16 of noise far above cos(90 deg).
    Q = euler_to_matrix(rng.uniform(-180, 180, (100, 3)), "XYZ")
    noisy = (M[:100] @ Q) @ np.swapaxes(Q, 1, 2)
    e = matrix_to_euler(noisy, order)
    assert np.isfinite(e).all()
    np.testing.assert_allclose(euler_to_matrix(e, order), noisy, atol=1e-9)


def test_angles_are_continuous_over_time():
    """A root spinning past 180 deg: unwrapped channels have no 360 deg jumps."""
    skel = Skeleton(["r", "a", "b"], [-1, 0, 0], [[0, 0, 0], [0, 1, 0], [1, 0, 0]])
    t = np.linspace(0, 4 * np.pi, 200)
    R = euler_to_matrix(np.stack([np.zeros_like(t), np.rad2deg(t), np.zeros_like(t)], -1), "XYZ")
    pos = np.einsum("tij,kj->tki", R, skel.offsets.astype(float))
    out = positions_to_bvh(pos, skel, 30)
    assert np.abs(np.diff(out.motion, axis=0)).max() < 10
    assert max_err(read_back_positions(out, skel), pos) < 1e-6


# ----------------------------------------------------------------------------- errors

@pytest.fixture(scope="module")
def small(cmu):
    b, skel, pos = cmu
    return skel, pos[:10]


def test_bad_inputs_raise_clear_errors(small):
    skel, pos = small
    nan = pos.copy()
    nan[3, 7, 1] = np.nan
    with pytest.raises(ValueError, match=r"NaN or Inf in 1 frame\(s\), first at frame 3 \(joint 'rightEye'\)"):
        positions_to_bvh(nan, skel, 30)
    with pytest.raises(ValueError, match="positions have 56 joints but the skeleton has 57"):
        positions_to_bvh(pos[:, :-1], skel, 30)
    with pytest.raises(ValueError, match=r"positions must be \[T, J, 3\], got shape \(10, 171\)"):
        positions_to_bvh(pos.reshape(10, -1), skel, 30)
    with pytest.raises(ValueError, match=r"must be \[T, J, 3\], got shape \(10, 57, 2\)"):
        positions_to_bvh(pos[..., :2], skel, 30)
    with pytest.raises(ValueError, match="no frames"):
        positions_to_bvh(pos[:0], skel, 30)
    with pytest.raises(ValueError, match="fps must be a positive"):
        positions_to_bvh(pos, skel, 0)
    with pytest.raises(ValueError, match="scale must be a positive"):
        positions_to_bvh(pos, skel, 30, scale=-1)
    with pytest.raises(ValueError, match="Euler order must be one of"):
        positions_to_bvh(pos, skel, 30, order="ZZY")
    with pytest.raises(ValueError, match="translate: unknown joint 'pelvis'"):
        positions_to_bvh(pos, skel, 30, translate=["pelvis"])


def test_positions_that_do_not_match_the_skeleton(small, cmu):
    skel, pos = small
    # centimetres instead of metres
    with pytest.raises(ValueError, match=r"do not match the skeleton.*100x the skeleton's overall \(units"):
        positions_to_bvh(pos * 100, skel, 30)
    # the right joint count, but the joints in another order (another dataset's layout)
    perm = np.random.default_rng(5).permutation(skel.num_joints)
    with pytest.raises(ValueError, match="do not match the skeleton"):
        positions_to_bvh(pos[:, perm], skel, 30)
    # the right joint count on another skeleton (Bandai, 27 nodes) is a count mismatch
    bandai = load("bandai1", "data/dataset-1_bye_feminine_001.bvh").skeleton(end_sites=True, scale=0.01)
    with pytest.raises(ValueError, match="57 joints but the skeleton has 27"):
        positions_to_bvh(pos, bandai, 30)
    # a moving joint under a static root is not a bone: rejected unless translated
    b = load("bandai2_locomotion", "data/dataset-2_run_feminine_021.bvh")
    full = b.skeleton(end_sites=False, scale=0.01)
    with pytest.raises(ValueError, match=r"joint_Root->Hips.*translate="):
        positions_to_bvh(b.positions(end_sites=False, dtype=np.float64) * 0.01, full, 30)


def test_bad_skeletons_raise():
    pos = np.zeros((2, 3, 3))
    pos[:, 1, 1] = 1
    pos[:, 2, 1] = 2
    with pytest.raises(ValueError, match="end site 'a' has children"):
        positions_to_bvh(pos, Skeleton(["r", "a", "b"], [-1, 0, 1], [[0, 0, 0], [0, 1, 0], [0, 1, 0]],
                                       end_sites=["a"]), 30)
    with pytest.raises(ValueError, match="cannot be written to BVH"):
        positions_to_bvh(pos, Skeleton(["r", "left arm", "b"], [-1, 0, 1], [[0, 0, 0], [0, 1, 0], [0, 1, 0]]), 30)
    with pytest.raises(ValueError, match="names would repeat"):
        positions_to_bvh(pos, Skeleton(["r", "r_End", "x"], [-1, 0, 0], [[0, 0, 0], [0, 1, 0], [0, 2, 0]],
                                       end_sites=["x"]), 30)


# ----------------------------------------------------------------------------- the check can fail

def test_acceptance_check_can_fail(cmu):
    """The 1 mm round-trip check catches broken exports: angles labelled with the wrong Euler
    order, a 1 deg error on one shoulder, global instead of local rotations, and a
    joint-order mix-up in the columns."""
    b, skel, pos = cmu
    pos = pos[:50]
    good = positions_to_bvh(pos, skel, fps=b.fps, scale=CM)
    assert max_err(reread(good.to_text(), skel), pos) < 1 * MM

    def err_of(motion=None, channels=None):
        bad = BvhData(good.names, good.parents, good.offsets, channels or good.channels,
                      good.motion if motion is None else motion, good.frame_time, good.is_end)
        return max_err(reread(bad.to_text(), skel), pos)

    wrong_order = [[c.replace("Z", "_").replace("Y", "Z").replace("_", "Y") if "rotation" in c else c
                    for c in ch] for ch in good.channels]  # ZXY angles read as YXZ
    assert err_of(channels=wrong_order) > 1 * MM

    start = good.channel_offsets()[good.names.index("rShldr")]
    m = good.motion.copy()
    m[:, start] += 1.0  # 1 degree on one joint
    assert err_of(motion=m) > 1 * MM

    _, glob, _ = solve_rotations(pos, skel)  # global rotations written as if local
    m = good.motion.copy()
    ge = matrix_to_euler(glob, "ZXY")
    starts = good.channel_offsets()
    for j, name in enumerate(skel.names):
        if j > 0 and name not in skel.end_sites:
            k = starts[good.names.index(name)]
            m[:, k:k + 3] = ge[:, j]
    assert err_of(motion=m) > 1 * MM

    a, c = starts[good.names.index("lShldr")], starts[good.names.index("rShldr")]
    m = good.motion.copy()
    m[:, [a, a + 1, a + 2, c, c + 1, c + 2]] = m[:, [c, c + 1, c + 2, a, a + 1, a + 2]]
    assert err_of(motion=m) > 1 * MM

"""MMD metrics: agreement with a literal implementation, ordering, negative estimates, bad input, real data."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
from conftest import REPO, archive_path

from motionsynth.metrics import mmd as M
from motionsynth.metrics.mmd import DEFAULT_BANDWIDTHS, mmd, mmd_table

# ----------------------------------------------------------------------------- literal reference


def _k(a: np.ndarray, c: np.ndarray, b: float) -> float:
    return float(np.exp(-np.sum((a - c) ** 2) / b))


def _mmd2_literal(X, Y, b, paired=False) -> float:
    """MMD^2_u by the formula, one pair at a time. paired: the SA-GCN code's cross term (m == n)."""
    m, n = len(X), len(Y)
    xx = sum(_k(X[i], X[j], b) for i in range(m) for j in range(m) if i != j) / (m * (m - 1))
    yy = sum(_k(Y[i], Y[j], b) for i in range(n) for j in range(n) if i != j) / (n * (n - 1))
    if paired:
        xy = sum(_k(X[i], Y[j], b) for i in range(m) for j in range(n) if i != j) / (m * (m - 1))
    else:
        xy = sum(_k(X[i], Y[j], b) for i in range(m) for j in range(n)) / (m * n)
    return xx + yy - 2 * xy


def _cells_literal(X, Y, mode, velocity=False, paired=False) -> np.ndarray:
    """[bandwidth, frame] table of MMD^2_u for one class."""
    X = X.reshape(len(X), X.shape[1], -1)
    Y = Y.reshape(len(Y), Y.shape[1], -1)
    if velocity:
        X, Y = X[:, 1:] - X[:, :-1], Y[:, 1:] - Y[:, :-1]
    if mode == "seq":
        X, Y = X.reshape(len(X), 1, -1), Y.reshape(len(Y), 1, -1)
    return np.array([[_mmd2_literal(X[:, t], Y[:, t], b, paired) for t in range(X.shape[1])]
                     for b in DEFAULT_BANDWIDTHS])


def _class_value(cells: np.ndarray, negative: str) -> float:
    """Max over bandwidths of the frame-mean of sqrt(MMD^2_u), as the reference loops do."""
    best = 0.0
    for row in cells:
        if negative == "nan" and (row < 0).any():
            continue  # the reference: sqrt(negative) is NaN, and NaN > best is False
        v = sum(np.sqrt(max(x, 0.0)) for x in row) / len(row)
        if v > best:
            best = v
    return best


@pytest.fixture(scope="module")
def tiny():
    """12 real vs 9 fake samples x 4 frames x 3 joints x 2, two classes, the fake slightly off."""
    rng = np.random.default_rng(7)
    real = rng.normal(size=(12, 4, 3, 2))
    fake = rng.normal(size=(9, 4, 3, 2)) * 1.2 + 0.3
    real_labels = np.array([0, 1] * 6)
    fake_labels = np.array([0, 1, 1, 0, 1, 0, 0, 1, 1])
    return real, fake, real_labels, fake_labels


# ----------------------------------------------------------------------------- agreement


@pytest.mark.parametrize("mode", ["avg", "seq"])
@pytest.mark.parametrize("velocity", [False, True])
def test_matches_literal_formula(tiny, mode, velocity):
    real, fake, rl, fl = tiny
    want = {c: _class_value(_cells_literal(real[rl == c], fake[fl == c], mode, velocity), "clamp") for c in (0, 1)}
    got = mmd(real, fake, rl, fl, mode=mode, velocity=velocity)
    assert got.per_class == pytest.approx(want, abs=1e-9)
    assert got.value == pytest.approx(np.mean(list(want.values())), abs=1e-9)
    assert got.counts == {0: (6, 4), 1: (6, 5)}
    assert got.n_cells == 2 * (1 if mode == "seq" else 4 - velocity)


@pytest.mark.parametrize("mode", ["avg", "seq"])
def test_paired_matches_reference_estimator(tiny, mode):
    """cross='paired', negative='nan' is the SA-GCN code: kxx + kyy - 2 kxy without its diagonal."""
    real, fake, rl, _ = tiny
    fake = fake[:8]  # 4 + 4 per class, as many as real's first 4 of each class
    fl = np.array([0, 1, 1, 0, 1, 0, 0, 1])
    want = [_class_value(_cells_literal(real[rl == c][:4], fake[fl == c], mode, paired=True), "nan") for c in (0, 1)]
    got = mmd(real, fake, rl, fl, mode=mode, cross="paired", negative="nan", max_per_class=4)
    assert [got.per_class[0], got.per_class[1]] == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("budget", [1, 5, 40, 1000])
def test_blocking_does_not_change_the_result(tiny, monkeypatch, budget):
    """Classes too large for one block are cut into frame and row blocks: same numbers."""
    real, fake, rl, fl = tiny
    want = mmd(real, fake, rl, fl, mode="avg", cross="full")
    monkeypatch.setattr(M, "_BUDGET", budget)
    for cross in ("full", "paired"):
        got = mmd(real, fake, rl, fl, mode="avg", cross=cross, max_per_class=4)
        monkeypatch.setattr(M, "_BUDGET", 1 << 23)
        ref = mmd(real, fake, rl, fl, mode="avg", cross=cross, max_per_class=4)
        monkeypatch.setattr(M, "_BUDGET", budget)
        assert got.value == pytest.approx(ref.value, abs=1e-12)
    assert mmd(real, fake, rl, fl, mode="avg").value == pytest.approx(want.value, abs=1e-12)


def test_duplicates_get_exact_zero_distance():
    """Near-identical pairs are recomputed from differences: at a tiny bandwidth a duplicated
    sample still counts fully (the expansion |x|^2 + |y|^2 - 2xy alone would lose it)."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 2, 4)) * 1e3 + 1e4  # large norms: the expansion cancels badly
    y = rng.normal(size=(5, 2, 4)) * 1e3 + 1e4
    y[0] = x[0]
    got = mmd(x, y, mode="seq", bandwidths=[1e-6], negative="clamp").per_class_mmd2["all"]
    assert got == pytest.approx(_mmd2_literal(x.reshape(5, -1), y.reshape(5, -1), 1e-6), abs=1e-15)
    assert got == pytest.approx(-2 / 25, abs=1e-15)  # only the cross pair (x0, y0) has k = 1


# ----------------------------------------------------------------------------- behaviour


@pytest.mark.parametrize("mode", ["avg", "seq"])
def test_identical_sets_give_zero(mode):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(30, 6, 4, 3))
    labels = np.arange(30) % 3
    res = mmd(x, x.copy(), labels, labels, mode=mode)
    assert res.value == 0.0  # MMD^2_u of a set against itself is <= 0, clamped
    assert res.n_negative_any > 0
    assert mmd(x, x.copy(), labels, labels, mode=mode, cross="paired").value < 1e-7


@pytest.mark.parametrize("mode", ["avg", "seq"])
def test_known_shifts_rank_in_order(mode):
    rng = np.random.default_rng(1)
    real = rng.normal(size=(80, 5, 3, 2))
    values = [mmd(real, rng.normal(size=(70, 5, 3, 2)) + s, mode=mode).value for s in (0.0, 0.25, 0.5, 1.0, 2.0)]
    assert values == sorted(values) and len(set(values)) == len(values), values


def test_velocity_sees_a_frozen_pose():
    """Poses with the right distribution per frame but no motion: avg barely sees it, velocity does."""
    rng = np.random.default_rng(2)
    t = np.arange(8)[None, :, None]

    def waves(n):
        phase = rng.uniform(0, 2 * np.pi, size=(n, 1, 4))
        return np.sin(0.8 * t + phase)

    real, moving = waves(60), waves(60)
    frozen = np.repeat(waves(60)[:, :1], 8, axis=1)
    table_moving, table_frozen = mmd_table(real, moving), mmd_table(real, frozen)
    assert set(table_moving) == {"mmd_avg", "mmd_seq", "mmd_vel_avg", "mmd_vel_seq"}
    assert table_frozen["mmd_vel_avg"] > 5 * table_moving["mmd_vel_avg"]
    assert table_frozen["mmd_vel_avg"] > 5 * table_frozen["mmd_avg"]


def test_negative_estimates_clamp_versus_nan():
    """Same distribution, 6 vs 6: some (bandwidth, frame) cells have MMD^2_u < 0."""
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=(6, 3, 2)), rng.normal(size=(6, 3, 2))
    cells = _cells_literal(x, y, "avg")
    negative_rows = (cells < 0).any(1)
    assert negative_rows.any() and not negative_rows.all()  # the case mixes both

    clamp = mmd(x, y, mode="avg", negative="clamp")
    nan = mmd(x, y, mode="avg", negative="nan")
    assert clamp.value == pytest.approx(_class_value(cells, "clamp"), abs=1e-12)
    assert nan.value == pytest.approx(_class_value(cells, "nan"), abs=1e-12)
    assert nan.value < clamp.value - 0.1  # the reference's NaN rule drops the best bandwidth here
    assert clamp.n_negative_any == nan.n_negative_any == int((cells < 0).sum())
    assert nan.n_dropped == int(negative_rows.sum()) and clamp.n_dropped == 0
    k = DEFAULT_BANDWIDTHS.index(clamp.bandwidth["all"])
    assert clamp.n_negative == int((cells[k] < 0).sum()) > 0
    assert nan.n_negative == 0
    assert np.isnan(nan.per_bandwidth["all"][negative_rows]).all()
    assert clamp.mmd2 == pytest.approx(cells.mean(1).max(), abs=1e-12)


def test_all_bandwidths_dropped_scores_zero():
    x = np.random.default_rng(4).normal(size=(5, 3, 2))
    res = mmd(x, x.copy(), mode="seq", negative="nan")
    assert res.value == 0.0 and res.bandwidth == {"all": None}
    # every bandwidth, even 1e-4: the duplicated cross pairs (x_i, x_i) keep k = 1 there
    assert res.n_dropped == len(DEFAULT_BANDWIDTHS) == res.n_negative_any


def test_max_per_class_takes_the_first_samples():
    rng = np.random.default_rng(5)
    real, fake = rng.normal(size=(20, 3, 4)), rng.normal(size=(20, 3, 4)) + 1
    labels = np.array(["walk", "run"] * 10)
    res = mmd(real, fake, labels, labels, max_per_class=4)
    first = mmd(real[[0, 2, 4, 6, 1, 3, 5, 7]], fake[[0, 2, 4, 6, 1, 3, 5, 7]],
                labels[[0, 2, 4, 6, 1, 3, 5, 7]], labels[[0, 2, 4, 6, 1, 3, 5, 7]])
    assert res.per_class == first.per_class
    assert res.counts == {"run": (4, 4), "walk": (4, 4)}


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("kwargs, message", [
    (dict(real=np.full((4, 3, 2), np.nan)), "real has 24 non-finite values"),
    (dict(fake=np.zeros((4, 5, 2))), "same per-sample shape"),
    (dict(real=np.zeros((4, 6))), r"\[N, T, J, D\] or \[N, T, F\]"),
    (dict(real_labels=[0, 1, 0]), "real_labels has 3 entries but real has 4 samples"),
    (dict(fake_labels=None), "both real_labels and fake_labels, or neither"),
    (dict(fake_labels=[0, 0, 0, 0]), r"only in real: \[1\]"),
    (dict(real_labels=[0, 1, 1, 1], fake_labels=[0, 1, 1, 1]), "class 0 has 1 real and 1 fake"),
    (dict(real_labels=[[0], [1], [0], [1]]), "must be 1-D"),
    (dict(real_labels=[0.5, 1, 0, 1]), "non-integer"),
    (dict(mode="joint"), "mode must be one of"),
    (dict(negative="drop"), "negative must be one of"),
    (dict(bandwidths=[1.0, -1.0]), "positive finite"),
    (dict(fake=np.zeros((5, 3, 2)), fake_labels=[0, 1, 0, 1, 1], cross="paired"), "as many real as fake"),
    (dict(max_per_class=1), "max_per_class"),
])
def test_bad_input_is_a_clear_value_error(kwargs, message):
    args = dict(real=np.zeros((4, 3, 2)), fake=np.ones((4, 3, 2)), real_labels=[0, 1, 0, 1],
                fake_labels=[0, 1, 0, 1])
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        mmd(**args)


def test_velocity_needs_two_frames():
    with pytest.raises(ValueError, match="at least 2 frames"):
        mmd(np.zeros((3, 1, 2)), np.ones((3, 1, 2)), velocity=True)


# ----------------------------------------------------------------------------- real data


def _h36m_windows(n_windows: int, frames: int, seed: int) -> tuple[np.ndarray, np.ndarray, str]:
    """Two disjoint seeded draws of windows [n, frames, J, D] of real Human3.6M poses.

    From the prepared 2-D bench (data/processed/h36m/bench2d) when it is there, else from the
    3-D positions of one file of the raw archive (as the reader tests use it)."""
    rng = np.random.default_rng(seed)
    root = REPO / "data" / "processed" / "h36m" / "bench2d"
    if (root / "pose.npy").exists():
        pose = np.load(root / "pose.npy", mmap_mode="r")[:20000]  # the first sequences: S11
        source = "bench2d"
    else:
        try:
            with zipfile.ZipFile(archive_path("h36m")) as z:
                blob = z.read("h36m/S1/MyPoses/3D_positions/Posing.h5")
        except FileNotFoundError as e:
            pytest.skip(str(e))
        import h5py

        with h5py.File(io.BytesIO(blob)) as f:
            pose = f["3D_positions"][()].T.reshape(-1, 32, 3) / 1000.0
        source = "archive"
    starts = rng.permutation(len(pose) - frames)[: 2 * n_windows]
    clips = np.stack([pose[s: s + frames] for s in starts]).astype(np.float64)
    return clips[:n_windows], clips[n_windows:], source


def test_real_h36m_other_draw_is_closer_than_noise():
    a, b, source = _h36m_windows(40, 16, seed=0)
    rng = np.random.default_rng(1)
    noise = a.mean(0) + rng.normal(size=a.shape) * a.std(0)  # same per-coordinate mean and spread
    same, other = mmd_table(a, b, return_results=True), mmd_table(a, noise, return_results=True)
    for name in same:
        assert same[name].value < other[name].value, (source, name, same[name].value, other[name].value)
    assert mmd_table(a, b) == {k: v.value for k, v in same.items()}

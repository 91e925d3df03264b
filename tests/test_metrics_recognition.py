"""Classifier-based generative metrics: FID against closed forms, diversity / multimodality on
hand-checkable point sets, input validation, and the action classifier learning real data."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import dataset_cfg

from motionsynth.metrics.recognition import (ActionClassifier, accuracy, confusion_matrix, diversity,
                                             feature_stats, features, fid, frechet_distance, generative_metrics,
                                             load_classifier, multimodality, multimodality_per_class, predict,
                                             recognition_accuracy, save_classifier, train_classifier,
                                             window_arrays)
from motionsynth.training.data import open_split, real_batch

DS = "bandai1"


def rot(theta: float) -> np.ndarray:
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


# --------------------------------------------------------------------------- FID

def test_frechet_distance_diagonal_closed_form():
    # ||(0,0)-(3,4)||^2 = 25; sum(a + b - 2 sqrt(ab)) = (1 + 4 - 4) + (4 + 9 - 12) = 2
    d = frechet_distance([0, 0], np.diag([1.0, 4.0]), [3, 4], np.diag([4.0, 9.0]))
    assert d == pytest.approx(27.0, abs=1e-12)


def test_frechet_distance_rotated_commuting_covariances():
    # S_i = R diag(.) R^T share eigenvectors: the distance is the diagonal one, here non-diagonal matrices
    r = rot(0.7)
    s1, s2 = r @ np.diag([1.0, 4.0]) @ r.T, r @ np.diag([4.0, 9.0]) @ r.T
    assert abs(s1[0, 1]) > 0.5
    assert frechet_distance([1, 2], s1, [1, 2], s2) == pytest.approx(2.0, abs=1e-12)


def test_frechet_distance_non_commuting_2x2_closed_form():
    # for a 2x2 matrix M with non-negative eigenvalues, Tr(M^{1/2}) = sqrt(Tr M + 2 sqrt(det M))
    rng = np.random.default_rng(3)
    for _ in range(5):
        a, b = rng.normal(size=(2, 2)), rng.normal(size=(2, 2))
        s1, s2 = a @ a.T + 0.1 * np.eye(2), b @ b.T + 0.1 * np.eye(2)
        assert not np.allclose(s1 @ s2, s2 @ s1)
        mu1, mu2 = rng.normal(size=2), rng.normal(size=2)
        tr_sqrt = np.sqrt(np.trace(s1 @ s2) + 2 * np.sqrt(np.linalg.det(s1) * np.linalg.det(s2)))
        want = ((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2 * tr_sqrt
        assert frechet_distance(mu1, s1, mu2, s2) == pytest.approx(want, rel=1e-10)


def test_frechet_distance_singular_covariances():
    # disjoint supports: S1 S2 = 0, so FID = ||mu||^2 + Tr S1 + Tr S2 = 0 + 2 + 3
    assert frechet_distance([0, 0], np.diag([2.0, 0.0]), [0, 0], np.diag([0.0, 3.0])) == pytest.approx(5.0)
    # rank-1 equal covariances: distance 0
    v = np.array([[1.0], [2.0]])
    assert frechet_distance([0, 0], v @ v.T, [0, 0], v @ v.T) == pytest.approx(0.0, abs=1e-12)


def test_fid_identical_sets_is_zero_and_stats_match_numpy():
    f = np.random.default_rng(0).normal(size=(400, 30)) * np.linspace(0.1, 3, 30)
    assert fid(f, f) == pytest.approx(0.0, abs=1e-9)
    mu, cov = feature_stats(f)
    np.testing.assert_allclose(mu, f.mean(0), rtol=1e-12)
    np.testing.assert_allclose(cov, np.cov(f, rowvar=False), rtol=1e-10, atol=1e-12)
    # fewer samples than dimensions: singular covariance, still exactly 0 against itself
    assert fid(f[:10], f[:10]) == pytest.approx(0.0, abs=1e-9)


def test_fid_of_samples_approaches_the_gaussians_distance():
    rng = np.random.default_rng(1)
    mu1, mu2 = np.array([0.0, 1.0, -1.0]), np.array([0.5, 1.0, 0.0])
    a, b = np.array([1.0, 0.25, 4.0]), np.array([2.0, 1.0, 1.0])
    x = mu1 + rng.normal(size=(40000, 3)) * np.sqrt(a)
    y = mu2 + rng.normal(size=(40000, 3)) * np.sqrt(b)
    want = ((mu1 - mu2) ** 2).sum() + (a + b - 2 * np.sqrt(a * b)).sum()    # 1.25 + 1.8431 = 3.0931
    assert fid(x, y) == pytest.approx(want, rel=0.03)


def test_fid_rejects_bad_inputs():
    f = np.zeros((5, 3))
    with pytest.raises(ValueError, match="different feature sizes"):
        fid(f, np.zeros((5, 4)))
    with pytest.raises(ValueError, match="non-finite"):
        fid(f, np.full((5, 3), np.nan))
    with pytest.raises(ValueError, match="at least 2 samples"):
        fid(f, np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"\[N, K\]"):
        fid(np.zeros(5), f)
    with pytest.raises(ValueError, match="not symmetric"):
        frechet_distance([0, 0], [[1, 1], [0, 1]], [0, 0], np.eye(2))
    with pytest.raises(ValueError, match="to match the means"):
        frechet_distance([0, 0], np.eye(3), [0, 0], np.eye(2))


# --------------------------------------------------------------------------- diversity / multimodality

def two_clusters(n0: int, n1: int) -> np.ndarray:
    """``n0`` points at (0, 0) and ``n1`` at (3, 4), interleaved: distance 5 across, 0 within."""
    f = np.zeros((n0 + n1, 2))
    f[np.random.default_rng(0).permutation(n0 + n1)[:n1]] = [3.0, 4.0]
    return f


def test_diversity_hand_checkable():
    assert diversity(np.array([[0.0, 0.0], [3.0, 4.0]]), distinct=True, seed=5) == pytest.approx(5.0)
    assert diversity(np.ones((7, 3)), seed=1) == 0.0
    # with replacement: P(the two draws fall in different clusters) = 2 * 10 * 30 / 40^2 = 0.375
    f = two_clusters(10, 30)
    assert diversity(f, pairs=200_000, seed=0) == pytest.approx(5 * 0.375, abs=0.03)
    # distinct pairs: P = 2 * 10 * 30 / (40 * 39)
    assert diversity(f, pairs=200_000, seed=0, distinct=True) == pytest.approx(5 * 600 / 1560, abs=0.03)
    # Action2Motion's S_d = 200 pairs: a seeded draw, between 0 and the largest distance
    d = diversity(f, seed=0)
    assert d == diversity(f, seed=0) and 0 < d < 5 and d != diversity(f, seed=1)


def test_multimodality_hand_checkable():
    labels = np.array([0, 1, 0, 2, 1, 2, 1, 0])
    f = np.array([[0, 0], [10, 0], [3, 0], [7, 7], [10, 5], [7, 7], [10, 5], [0, 0]], dtype=float)
    # class 0 = {(0,0), (3,0), (0,0)}: distinct pair distances 3, 0, 3 -> mean 2
    # class 1 = {(10,0), (10,5), (10,5)}: 5, 5, 0 -> mean 10/3;  class 2 = {(7,7), (7,7)}: 0
    per = multimodality_per_class(f, labels, pairs=60_000, seed=0, distinct=True)
    assert per.keys() == {0, 1, 2}
    assert per[0] == pytest.approx(2.0, abs=0.03)
    assert per[1] == pytest.approx(10 / 3, abs=0.03)
    assert per[2] == 0.0
    assert multimodality(f, labels, pairs=60_000, seed=0, distinct=True) == pytest.approx(
        (2.0 + 10 / 3) / 3, abs=0.02)
    # with replacement (the reference): each class's mean is (1 - 1/n) times the distinct one
    assert multimodality(f, labels, pairs=60_000, seed=0) == pytest.approx((2 * 2 / 3 + 10 / 3 * 2 / 3) / 3,
                                                                            abs=0.02)


def test_multimodality_two_point_classes_are_exact():
    f = np.array([[0, 0], [0, 0], [3, 0], [0, 5]], dtype=float)
    labels = [0, 1, 0, 1]                                    # class 0 pair 3 apart, class 1 pair 5 apart
    assert multimodality_per_class(f, labels, seed=7, distinct=True) == {0: 3.0, 1: 5.0}
    assert multimodality(f, labels, seed=7, distinct=True) == 4.0


def test_multimodality_small_classes():
    f = np.arange(10, dtype=float).reshape(5, 2)
    labels = np.array([0, 0, 1, 2, 2])
    with pytest.raises(ValueError, match=r"classes \[1\] have \[1\]"):
        multimodality(f, labels)
    per = multimodality_per_class(f, labels, skip_small=True, distinct=True)
    assert per == {0: pytest.approx(np.sqrt(8)), 2: pytest.approx(np.sqrt(8))}
    with pytest.raises(ValueError, match=r"classes \[1, 3\]"):
        multimodality(f, labels, num_classes=4)             # class 3 has no sample at all
    with pytest.raises(ValueError, match="no class has >= 2"):
        multimodality(f[:3], [0, 1, 2], skip_small=True)


def test_diversity_multimodality_reject_bad_inputs():
    f = np.zeros((4, 2))
    with pytest.raises(ValueError, match="at least 2 samples"):
        diversity(f[:1])
    with pytest.raises(ValueError, match="non-finite"):
        diversity(np.array([[0.0, np.nan], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="pairs must be an integer"):
        diversity(f, pairs=0)
    with pytest.raises(ValueError, match="outside"):
        multimodality(f, [0, 1, 2, 2], num_classes=2)
    with pytest.raises(ValueError, match="outside"):
        multimodality(f, [0, -1, 0, -1])
    with pytest.raises(ValueError, match="4 samples"):
        multimodality(f, [0, 0, 1])
    with pytest.raises(ValueError, match="non-integer"):
        multimodality(f, [0, 0.5, 1, 1])


# --------------------------------------------------------------------------- the classifier

def test_classifier_shapes_and_deterministic_features():
    torch.manual_seed(0)
    model = ActionClassifier(input_size=12, num_classes=5).eval()
    assert model.recurrent.hidden_size == 128 and model.recurrent.num_layers == 2
    x = torch.randn(3, 20, 12)
    assert model(x).shape == (3, 5)
    f = model.features(x)
    assert f.shape == (3, 30) and bool((f.abs() < 1).all())                   # tanh features
    np.testing.assert_array_equal(features(model, x.numpy()), features(model, x.numpy()))
    # [N, T, J, D] is flattened; batching does not change the features
    np.testing.assert_allclose(features(model, x.numpy().reshape(3, 20, 4, 3), batch_size=2),
                               model.features(x).detach().double().numpy(), rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="F = 12"):
        features(model, np.zeros((2, 5, 13), np.float32))
    with pytest.raises(ValueError, match="non-finite"):
        features(model, np.full((2, 5, 12), np.nan, np.float32))
    with pytest.raises(ValueError, match=r"\[N, T, F\]"):
        features(model, np.zeros((5, 12), np.float32))
    with pytest.raises(ValueError, match="outside"):
        accuracy(model, np.zeros((2, 5, 12), np.float32), [0, 5])
    with pytest.raises(ValueError, match="3 entries"):
        recognition_accuracy(model, np.zeros((2, 5, 12), np.float32), [0, 1, 2])
    with pytest.raises(ValueError, match="num_classes must be >= 2"):
        ActionClassifier(12, 1)


@pytest.fixture(scope="module")
def real(tmp_path_factory, one_thread):
    """bandai1 train / val / test windows of 60 real items, prepared and split by the dataset's config."""
    cfg = dataset_cfg(DS)["training"]
    tmp = tmp_path_factory.mktemp("bandai1")
    real_batch(DS, cfg["family"], 1, tmp, max_items=60)               # ingest + prepare + split into tmp
    split = {s: open_split(tmp / "processed", tmp / "splits", DS, cfg, cfg["family"], s)
             for s in ("train", "val", "test")}
    train = split["train"]
    idx = np.unique(np.linspace(0, len(train) - 1, min(300, len(train))).round().astype(int))
    out = {"train": window_arrays(train, idx), "val": window_arrays(split["val"]),
           "test": window_arrays(split["test"]), "C": cfg["num_classes"]}
    # no sequence of the test split is in the training windows
    seqs = {s: set(split[s].windows["sequence_id"]) for s in split}
    assert not seqs["train"] & seqs["test"] and not seqs["train"] & seqs["val"]
    return out


@pytest.fixture(scope="module")
def trained(real):
    (x, y), (vx, vy) = real["train"], real["val"]
    return train_classifier(x, y, vx, vy, real["C"], epochs=6, batch_size=32, lr=2e-3, seed=0, threads=1,
                            select="last")


def test_classifier_learns_real_actions(real, trained):
    model, hist = trained
    (x, y), (tx, ty) = real["train"], real["test"]
    C = real["C"]
    chance, majority = 1 / C, np.bincount(ty).max() / len(ty)
    acc = accuracy(model, tx, ty)
    assert acc > 2 * chance and acc > majority + 0.1, (acc, chance, majority)
    assert hist[-1]["train_loss"] < 0.5 * hist[0]["train_loss"]
    assert accuracy(model, x, y) > 0.8
    # select="last": the returned weights are the last epoch's
    assert hist[-1].get("selected") and accuracy(model, *real["val"]) == pytest.approx(hist[-1]["val_acc"])
    cm = confusion_matrix(model, tx, ty)
    assert cm.shape == (C, C) and cm.sum() == len(ty) and np.trace(cm) / len(ty) == pytest.approx(acc)
    assert recognition_accuracy(model, tx, ty) == acc
    np.testing.assert_array_equal(cm.sum(1), np.bincount(ty, minlength=C))
    assert (predict(model, tx) == ty).mean() == acc


def test_features_separate_real_from_frozen_motion(real, trained):
    # reference and "generated" sets from the same (unseen) test sequences, so that the class mix
    # is the same: FID is dominated by class-mix differences between this small subset's splits
    model, _ = trained
    (tx, ty) = real["test"]
    ref, ref_y, gen, gen_y = tx[::2], ty[::2], tx[1::2], ty[1::2]
    frozen = np.repeat(gen[:, :1], gen.shape[1], axis=1)              # the first pose held still
    good = generative_metrics(model, ref, ref_y, gen, gen_y, seed=0, skip_small=True)
    bad = generative_metrics(model, ref, ref_y, frozen, gen_y, seed=0, skip_small=True)
    assert good["fid"] < 0.5 * bad["fid"]
    assert good["accuracy"] > bad["accuracy"] + 0.1
    assert good["real_accuracy"] == pytest.approx(accuracy(model, ref, ref_y))
    assert good["accuracy"] == pytest.approx(accuracy(model, gen, gen_y))
    assert good["fid"] == pytest.approx(fid(features(model, ref), features(model, gen)))
    assert good["diversity"] > 0 and good["multimodality"] > 0


def test_training_is_deterministic_and_selects_by_val(real, tmp_path):
    (x, y), (vx, vy) = real["train"], real["val"]
    x, y = x[::10], y[::10]
    kw = dict(epochs=3, batch_size=16, lr=2e-3, threads=1)
    a, ha = train_classifier(x, y, vx, vy, real["C"], seed=1, **kw)
    b, hb = train_classifier(x, y, vx, vy, real["C"], seed=1, **kw)
    c, _ = train_classifier(x, y, vx, vy, real["C"], seed=2, **kw)
    sa, sb, sc = a.state_dict(), b.state_dict(), c.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)
    assert [{k: v for k, v in h.items() if k != "seconds"} for h in ha] == \
           [{k: v for k, v in h.items() if k != "seconds"} for h in hb]
    # select="val_acc": the returned weights are those of the best-val epoch
    best = max(ha, key=lambda h: (h["val_acc"], -h["val_loss"]))
    assert [h.get("selected", False) for h in ha] == [h is best for h in ha]
    assert accuracy(a, vx, vy) == pytest.approx(best["val_acc"])
    # save / load round trip
    save_classifier(a, tmp_path / "clf.pt", dataset=DS)
    loaded, meta = load_classifier(tmp_path / "clf.pt")
    assert meta == {"dataset": DS}
    np.testing.assert_array_equal(features(loaded, vx), features(a, vx))


def test_patience_stops_after_the_selected_epoch_with_the_same_weights(real):
    """With ``patience``, training stops ``patience`` epochs after the best one and returns exactly the
    weights (and history prefix) of the run without it."""
    (x, y), (vx, vy) = real["train"], real["val"]
    x, y = x[::40], y[::40]                       # a small train set overfits within a few epochs
    kw = dict(batch_size=8, lr=1e-2, threads=1, seed=3, select="val_loss")
    full, hf = train_classifier(x, y, vx, vy, real["C"], epochs=10, **kw)
    best = next(h["epoch"] for h in hf if h.get("selected"))
    early, he = train_classifier(x, y, vx, vy, real["C"], epochs=10, patience=2, **kw)
    assert best + 3 < 10 and len(he) == best + 3      # the stop is exercised
    assert [h["val_loss"] for h in he] == [h["val_loss"] for h in hf[:len(he)]]
    sf, se = full.state_dict(), early.state_dict()
    assert all(torch.equal(sf[k], se[k]) for k in sf)
    with pytest.raises(ValueError, match="patience"):
        train_classifier(x[:8], y[:8], None, None, real["C"], epochs=1, patience=0)


def test_train_classifier_rejects_bad_inputs(real):
    x, y = real["train"]
    x, y = x[:8], y[:8]
    with pytest.raises(ValueError, match="outside"):
        train_classifier(x, np.full(8, real["C"]), None, None, real["C"], epochs=1)
    with pytest.raises(ValueError, match="non-finite"):
        bad = x.copy()
        bad[0, 0, 0] = np.nan
        train_classifier(bad, y, None, None, real["C"], epochs=1)
    with pytest.raises(ValueError, match="7 entries"):
        train_classifier(x, y[:7], None, None, real["C"], epochs=1)
    with pytest.raises(ValueError, match="both val_x and val_y"):
        train_classifier(x, y, x, None, real["C"], epochs=1)
    with pytest.raises(ValueError, match="takes F"):
        train_classifier(x, y, x[..., :5], y, real["C"], epochs=1)
    with pytest.raises(ValueError, match="lr must be"):
        train_classifier(x, y, None, None, real["C"], epochs=1, lr=0)
    with pytest.raises(ValueError, match="select must be"):
        train_classifier(x, y, None, None, real["C"], epochs=1, select="best")


_TRAIN_IN_SUBPROCESS = """
import sys, numpy as np
from motionsynth.metrics.recognition import features, train_classifier
d = np.load(sys.argv[1])
model, _ = train_classifier(d["x"], d["y"], d["vx"], d["vy"], int(d["C"]), epochs=3, batch_size=16, lr=2e-3,
                            seed=0, threads=1, dtype=sys.argv[2])
np.save(sys.argv[3], features(model, d["vx"]))
"""


def test_float64_classifier_holds_on_another_mkl_kernel_path(real, tmp_path):
    """The generative suite trains its classifier in float64 (``evaluate.generative.dtype``) because a
    float32 one amplifies a CPU's choice of BLAS kernels into other features. Emulate an AVX2-only
    machine with ``MKL_ENABLE_INSTRUCTIONS=AVX2``: float32 features move, float64 ones agree to 1e-9."""
    (x, y), (vx, vy) = real["train"], real["val"]
    data = tmp_path / "d.npz"
    np.savez(data, x=x[::5], y=y[::5], vx=vx, vy=vy, C=real["C"])
    out = {}
    for dtype in ("float32", "float64"):
        for path, extra in (("native", {}), ("avx2", {"MKL_ENABLE_INSTRUCTIONS": "AVX2"})):
            f = tmp_path / f"{dtype}_{path}.npy"
            subprocess.run([sys.executable, "-c", _TRAIN_IN_SUBPROCESS, str(data), dtype, str(f)], check=True,
                           env={**os.environ, **extra})
            out[dtype, path] = np.load(f)
    moved32 = np.abs(out["float32", "native"] - out["float32", "avx2"]).max()
    if moved32 == 0:
        pytest.skip("this CPU's MKL takes the same kernels with MKL_ENABLE_INSTRUCTIONS=AVX2 (no AVX-512)")
    moved64 = np.abs(out["float64", "native"] - out["float64", "avx2"]).max()
    assert moved64 < 1e-9 < moved32, (moved64, moved32)


def test_float64_classifier_saves_and_loads_in_float64(real, tmp_path):
    (x, y), (vx, vy) = real["train"], real["val"]
    model, _ = train_classifier(x[::20], y[::20], None, None, real["C"], epochs=1, threads=1, dtype="float64")
    assert all(p.dtype == torch.float64 for p in model.parameters())
    save_classifier(model, tmp_path / "clf.pt")
    loaded, _ = load_classifier(tmp_path / "clf.pt")
    assert all(p.dtype == torch.float64 for p in loaded.parameters())
    np.testing.assert_array_equal(features(loaded, vx), features(model, vx))
    with pytest.raises(ValueError, match="dtype"):
        train_classifier(x[:8], y[:8], None, None, real["C"], epochs=1, dtype="float16")

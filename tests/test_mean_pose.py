"""The mean-pose reference row: the train split's mean pose (never val or test frames), held after the seed."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import build_eval_root

from motionsynth.data.normalise import Normaliser
from motionsynth.training.checkpoint import load
from motionsynth.training.run import load_trained

DS = "bandai1"


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    r = tmp_path_factory.mktemp("mean_pose_root")
    build_eval_root(r, DS, {"mean_pose": ("mean_pose", "none")}, max_items=16)
    return r


def split_mean(root, split: str) -> np.ndarray:
    """Independently: the mean normalised pose over every frame of the sequences of ``split``."""
    rep, spl = root / "data/processed" / DS / "pos3d", root / "data/splits" / DS / "pos3d"
    meta = pd.read_parquet(rep / "meta.parquet")
    table = pd.read_csv(spl / "random.csv").set_index("sequence_id")["split"]
    pose, norm = np.load(rep / "pose.npy"), Normaliser.load(spl / "random_stats.npz")
    rows = [pose[o:o + f] for o, f, s in zip(meta["offset"], meta["frames"], meta["sequence_id"]) if table[s] == split]
    return norm(np.concatenate(rows).astype(np.float64)).mean(0)


def test_mean_pose_is_the_train_splits_mean(root):
    model, _ = load_trained(root / "models" / DS / "mean_pose")
    mean = model.mean.double().numpy()
    train, test = split_mean(root, "train"), split_mean(root, "test")
    np.testing.assert_allclose(mean, train, atol=1e-5)
    assert np.abs(mean - test).max() > 1e-3                 # another split's mean is another pose
    assert int(load(root / "models" / DS / "mean_pose" / "best.pt")["model"]["frames_seen"]) > 0


def test_mean_pose_keeps_the_seed_then_holds_the_mean(root):
    model, train = load_trained(root / "models" / DS / "mean_pose")
    batch = train.batch(np.arange(min(4, len(train))))
    S = model.seed_frames
    out = model.generate(batch.pose[:, :S], length=batch.pose.shape[1])
    assert torch.equal(out[:, :S], batch.pose[:, :S])
    assert torch.allclose(out[:, S:], model.mean.expand_as(out[:, S:]))
    assert type(model).reference is True

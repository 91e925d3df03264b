"""Splits: protocol logic, determinism, class stratification, and no leakage across splits."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import archive_path, dataset_cfg

from motionsynth.data.ingest import ingest
from motionsynth.data.normalise import Normaliser
from motionsynth.data.prepare import prepare
from motionsynth.data.splits import assign, check_no_leak, protocol_table, split_dataset
from motionsynth.data.types import ConfigError


def meta(n_src=40, views=1, classes=4, subjects=("S1", "S5", "S6", "S7", "S8", "S9", "S11")):
    rows = []
    for i in range(n_src):
        for v in range(views):
            rows.append({"sequence_id": f"s{i}@v{v}", "source_id": f"s{i}", "label": i % classes,
                         "subject": subjects[i % len(subjects)], "view": f"cam{v + 1}"})
    return pd.DataFrame(rows)


def test_subject_protocol_with_unused_subject():
    m = meta(70, views=4)
    s = assign(m, {"by": "subject", "train": [1, 5, 7, 8, 9], "test": [11]}, 0.1, seed=0)
    assert set(s[m.subject == "S6"]) == {"unused"}
    assert set(s[m.subject == "S11"]) == {"test"}
    assert set(s[m.subject.isin(["S1", "S5", "S7", "S8", "S9"])]) == {"train", "val"}
    t = pd.DataFrame({"sequence_id": m.sequence_id, "source_id": m.source_id, "split": s})
    check_no_leak(t)   # all 4 views of a take share the split


def test_keep_restricts_a_protocol_and_says_why():
    m = meta(70, views=4)
    t = protocol_table(m, {"by": "subject", "train": [1, 5, 7, 8, 9], "test": [11], "keep": {"view": ["cam2"]}},
                       0.1, seed=0)
    cam2, s6 = m.view == "cam2", m.subject == "S6"
    assert set(t.split[~cam2 | s6]) == {"unused"} and set(t.split[cam2 & ~s6]) == {"train", "val", "test"}
    assert (t.reason[s6] == "subject S6 is in neither train nor test").all()
    assert (t.reason[~cam2 & ~s6] == "view " + m.view[~cam2 & ~s6] + " is not in keep.view (cam2)").all()
    assert (t.reason[t.split != "unused"] == "").all()
    # the carve-out draws among the kept views: as many val takes as without the filter
    plain = assign(m, {"by": "subject", "train": [1, 5, 7, 8, 9], "test": [11]}, 0.1, seed=0)
    assert m.source_id[t.split == "val"].nunique() == m.source_id[plain == "val"].nunique()


def test_random_split_is_seeded_stratified_and_per_file():
    m = meta(60)
    a = assign(m, {"by": "sequence", "stratify": "label", "test_fraction": 0.25}, 0.1, seed=3)
    b = assign(m, {"by": "sequence", "stratify": "label", "test_fraction": 0.25}, 0.1, seed=3)
    c = assign(m, {"by": "sequence", "stratify": "label", "test_fraction": 0.25}, 0.1, seed=4)
    assert (a == b).all() and not (a == c).all()
    for split in ("train", "val", "test"):
        assert set(m.label[a == split]) == {0, 1, 2, 3}, split   # every class on every side
    assert (a == "test").sum() == 16


def test_rest_and_overlap_errors():
    m = meta(10)
    s = assign(m, {"by": "subject", "train": [1, 5], "test": "rest"}, 0.0, seed=0)
    assert set(s[~m.subject.isin(["S1", "S5"])]) == {"test"}
    with pytest.raises(ValueError, match="both"):
        assign(m, {"by": "subject", "train": [1, 5], "test": [5]}, 0.0, 0)
    with pytest.raises(KeyError, match="camera"):
        assign(m, {"by": "camera", "train": [1], "test": [2]}, 0.0, 0)


def test_check_no_leak_catches_a_leak():
    t = pd.DataFrame({"sequence_id": ["a", "b"], "source_id": ["x", "x"], "split": ["train", "test"]})
    with pytest.raises(AssertionError, match="source takes across splits"):
        check_no_leak(t)


def test_real_ntu_protocols_and_train_only_stats(tmp_path):
    cfg = dataset_cfg("ntu_samples")
    ingest(cfg, archive_path("ntu_samples"), tmp_path / "i", progress=False)
    prepare(tmp_path / "i", tmp_path / "p", cfg["prepare"]["representations"])
    summary = split_dataset(tmp_path / "p", tmp_path / "s", cfg["split"], seed=0)
    cs = pd.read_csv(tmp_path / "s/pos3d/cross_subject.csv").set_index("sequence_id")["split"]
    # performers 1, 8 and 15 are training subjects; 3 is not
    for sid in ("S001C001P001R001A011", "S001C003P008R002A058", "S003C001P015R001A034"):
        assert cs[sid] in ("train", "val")
    assert cs["S002C001P003R001A003"] == "test" and cs["S004C002P003R001A017"] == "test"
    cv = pd.read_csv(tmp_path / "s/pos3d/cross_view.csv").set_index("sequence_id")["split"]
    assert cv["S001C001P001R001A011"] == "test" and cv["S004C002P003R001A017"] in ("train", "val")
    assert sum(summary["pos3d/cross_subject"]["sequences"].values()) == 5
    stats = np.load(tmp_path / "s/pos3d/cross_subject_stats.npz")
    pose = np.load(tmp_path / "p/pos3d/pose.npy")
    m = pd.read_parquet(tmp_path / "p/pos3d/meta.parquet").set_index("sequence_id")
    train_ids = cs[cs == "train"].index
    idx = np.concatenate([np.arange(m.offset[i], m.offset[i] + m.frames[i]) for i in train_ids])
    np.testing.assert_allclose(stats["pose_mean"], pose[idx].mean(0), atol=1e-5)  # train frames only
    assert int(stats["train_frames"]) == len(idx) and "stats_over" not in stats.files   # the keys they always had
    bad = {"protocols": {"peek": {"by": "subject", "train": [1], "test": "rest", "stats_over": ["train", "test"]}}}
    with pytest.raises(ConfigError, match=r"conf/dataset/p.yaml: split.protocols.peek.stats_over must name train"):
        split_dataset(tmp_path / "p", tmp_path / "s2", bad, seed=0)


def test_real_h36m_windows_never_cross_splits(tmp_path):
    cfg = dataset_cfg("h36m")
    ingest(cfg, archive_path("h36m"), tmp_path / "i", max_items=12, progress=False)
    prepare(tmp_path / "i", tmp_path / "p", cfg["prepare"]["representations"])
    split_dataset(tmp_path / "p", tmp_path / "s", cfg["split"], seed=0)
    for proto in ("cross_subject", "csgan", "csgan_4cam", "cross_view"):
        t = pd.read_csv(tmp_path / f"s/bench2d/{proto}.csv")
        w = pd.read_parquet(tmp_path / "p/bench2d/windows_glocal.parquet")
        wsplit = w["sequence_id"].map(t.set_index("sequence_id")["split"])
        assert wsplit.notna().all()
        # every window's frames come from its own sequence, which has exactly one split
        assert (w.groupby("sequence_id").size() > 0).all()
        assert t.groupby("sequence_id")["split"].nunique().max() == 1
    cv = pd.read_csv(tmp_path / "s/bench2d/cross_view.csv")
    assert set(cv[cv.split == "test"].sequence_id.str.split("@").str[1].str.split("+").str[0]) == {"60457274"}
    # csgan: camera 55011271 alone, every other view unused with its reason; csgan_4cam: all four cameras
    cs = pd.read_csv(tmp_path / "s/bench2d/csgan.csv")
    cam = cs.sequence_id.str.contains("@55011271+", regex=False)
    s6 = cs.sequence_id.str.startswith("S6_")
    assert set(cs[~cam | s6].split) == {"unused"} and (cs[s6].reason == "subject S6 is in neither train nor test").all()
    assert cs[~cam & ~s6].reason.str.fullmatch(r"view \d+ is not in keep.view \(55011271\)").all()
    assert set(cs[cam].split) >= {"train", "test"}
    c4 = pd.read_csv(tmp_path / "s/bench2d/csgan_4cam.csv")
    assert set(c4[c4.sequence_id.str.contains("@60457274+", regex=False)].split) >= {"train", "test"}
    assert (c4.reason.isna() == (c4.split != "unused")).all()
    stats = np.load(tmp_path / "s/bench2d/csgan_stats.npz")
    assert float(stats["mean_depth"]) > 1.0 and list(stats["stats_over"]) == ["train", "val"]
    # the c-SkeletonGAN normalisation: depth-scaled, then standardised with train statistics
    norm = Normaliser.load(tmp_path / "s/bench2d/csgan_stats.npz")
    pose, root = np.load(tmp_path / "p/bench2d/pose.npy"), np.load(tmp_path / "p/bench2d/root.npy")
    m = pd.read_parquet(tmp_path / "p/bench2d/meta.parquet")
    t = pd.read_csv(tmp_path / "s/bench2d/csgan.csv")
    train = m[t.split.isin(["train", "val"]).values]               # csgan: every training subject's frames
    idx = np.concatenate([np.arange(o, o + f) for o, f in zip(train.offset, train.frames)])
    z = norm(pose[idx], root[idx])
    np.testing.assert_allclose(z.mean(0), 0, atol=1e-3)
    np.testing.assert_allclose(z.std(0), 1, atol=1e-3)
    np.testing.assert_allclose(norm.inverse(z, root[idx]), pose[idx], atol=1e-3)
    assert not (tmp_path / "s/pos3d/cross_view.csv").exists()   # the view protocol is 2-D only

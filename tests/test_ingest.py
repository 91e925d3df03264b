"""Ingest: safe archive access, full accounting, and every bad-input case in one archive."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import zipfile

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, archive_path, compose_cfg, dataset_cfg, make_zip
from test_bvh import HAND

from motionsynth.data.archive import Archive, unsafe_reason
from motionsynth.data.ingest import ingest
from motionsynth.data.store import Store

MOTION_HEAD = HAND.split("MOTION")[0]


def bvh(frames: int = 5, row: str | None = None, head: str = MOTION_HEAD, declared: int | None = None) -> str:
    row = row or " ".join(["1"] * 15)
    return head + f"MOTION\nFrames: {declared or frames}\nFrame Time: 0.0333333\n" + (row + "\n") * frames


LABEL = json.dumps({"content": 0, "style": 1})
CFG = {
    "name": "toy",
    "reader": {"_target_": "motionsynth.data.bvh.BvhReader", "pattern": "data/*.bvh", "labels": "json",
               "label_pattern": "data/*.json", "content_labels": "cfg/content.txt",
               "style_labels": "cfg/style.txt", "label_prefix": "toy_", "scale": 0.01},
    "skeleton": {"root": "root", "hips": ["a", "b"]},
}


@pytest.mark.parametrize("name,bad", [
    ("../evil.bvh", True), ("a/../../evil", True), ("/etc/passwd", True), ("C:/win.bvh", True),
    ("a\\..\\..\\x", True), ("data/ok.bvh", False), ("data/..hidden.bvh", False),
])
def test_unsafe_member_names(name, bad):
    assert (unsafe_reason(name) is not None) == bad


def test_every_bad_input_is_rejected_with_its_reason_and_counts_add_up(tmp_path):
    corrupt = tmp_path / "crc.zip"
    good = bvh(5)
    members = {
        "cfg/content.txt": "toy_walk\ntoy_run\n", "cfg/style.txt": "toy_normal\ntoy_happy\n",
        "data/a.bvh": good, "data/a.json": LABEL,
        "data/b.bvh": bvh(5)[:-12], "data/b.json": LABEL,                      # truncated
        "data/c.bvh": bvh(5, "1 nan " + "1 " * 13), "data/c.json": LABEL,       # NaN frame
        "data/d.bvh": bvh(5, "1 x " + "1 " * 13), "data/d.json": LABEL,         # non-numeric
        "data/e.bvh": bvh(5, " ".join(["1"] * 14)), "data/e.json": LABEL,      # channel count
        "data/f.bvh": "", "data/f.json": LABEL,                                  # empty
        "data/g.json": LABEL,                                                    # label without motion
        "data/h.bvh": bvh(5, head=MOTION_HEAD.replace("JOINT b", "JOINT zz")), "data/h.json": LABEL,  # unknown joint
        "data/i.bvh": good, "data/i.json": LABEL,                                # corrupt bytes (below)
        "data/j.bvh": good,                                                      # motion without label
        "data/k.bvh": good, "data/k.json": "{\"content\": 7}",                  # bad label json
        "../evil.bvh": good, "/abs/evil.bvh": good,                              # hostile paths
    }
    make_zip(corrupt, members)
    raw = bytearray(corrupt.read_bytes())
    with zipfile.ZipFile(corrupt) as z:
        info = z.getinfo("data/i.bvh")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    raw[start + 5] ^= 0xFF  # flip one byte of data/i.bvh: CRC mismatch
    corrupt.write_bytes(bytes(raw))

    s = ingest(CFG, corrupt, tmp_path / "out", progress=False)
    reasons = {r["member"]: r["reason"] for r in s["rejected_items"]}
    assert s["accepted"] == 1 and s["seen"] == 13 and s["rejected"] == 12
    assert s["accepted"] + s["rejected"] == s["seen"]
    expect = {"data/b.bvh": "truncated", "data/c.bvh": "NaN", "data/d.bvh": "non-numeric",
              "data/e.bvh": "channel count", "data/f.bvh": "empty", "data/g.json": "label without a motion",
              "data/h.bvh": "unknown joints ['zz']", "data/i.bvh": "corrupt", "data/j.bvh": "without its label",
              "data/k.json": "label", "../evil.bvh": "escapes", "/abs/evil.bvh": "absolute"}
    for member, word in expect.items():
        key = member if member in reasons else member.replace(".json", ".bvh")
        assert word in reasons[key], (member, reasons.get(key))
    rej = pd.read_csv(tmp_path / "out" / "rejected.csv")
    assert len(rej) == 12
    store = Store.open(tmp_path / "out")
    assert store.meta["sequence_id"].tolist() == ["a"]
    assert store.meta.loc[0, "label_name"] == "walk" and store.meta.loc[0, "style"] == "happy"
    assert store.sequence(0).positions.shape == (5, 3, 3)  # End Site dropped (end_sites: false)


def test_bandai1_real_archive_accounting(tmp_path):
    s = ingest(dataset_cfg("bandai1"), archive_path("bandai1"), tmp_path / "b1", progress=False)
    assert (s["seen"], s["accepted"], s["rejected"]) == (175, 174, 1)
    assert s["rejected_items"][0]["member"] == "data/dataset-1_dance-long_normal_001.json"
    assert "without a motion file" in s["rejected_items"][0]["reason"]
    st = Store.open(tmp_path / "b1")
    assert st.skeleton.num_joints == 22 and st.skeleton.root == "Hips"
    assert s["fps"] == 30.0 and s["frames"] == int(st.meta["frames"].sum())
    assert set(st.meta["label_name"]) >= {"walk", "run", "punch", "dance-short"}


def test_smoke_limit_is_reported_and_spread_over_classes(tmp_path):
    s = ingest(dataset_cfg("cmu_aclstm"), archive_path("cmu_aclstm"), tmp_path / "c", max_items=6, progress=False)
    assert s["accepted"] == 6 and s["limited_to"] == 6 and s["listed_in_archive"] == 43
    assert s["classes"] == 3
    assert any("conflict" in n and "salsa" in n for n in s["notes"])


def test_unknown_joint_in_config_is_a_clear_error(tmp_path):
    cfg = json.loads(json.dumps(CFG))
    cfg["skeleton"]["hips"] = ["a", "nope"]
    path = make_zip(tmp_path / "t.zip", {"cfg/content.txt": "toy_walk\n", "cfg/style.txt": "toy_x\ntoy_y\n",
                                         "data/a.bvh": bvh(3), "data/a.json": LABEL})
    with pytest.raises(KeyError, match="nope"):
        ingest(cfg, path, tmp_path / "o", progress=False)


def test_archive_lists_hostile_members_without_opening_them(tmp_path):
    path = make_zip(tmp_path / "h.zip", {"ok.txt": "x", "../../x.txt": "y"})
    with Archive(path) as ar:
        assert ar.names == ["ok.txt"] and [r.member for r in ar.unsafe] == ["../../x.txt"]
        with pytest.raises(Exception, match="not a safe member"):
            ar.read("../../x.txt")


def test_not_a_zip_is_a_clear_error(tmp_path):
    p = tmp_path / "bad.zip"
    p.write_bytes(b"not a zip")
    with pytest.raises(Exception, match="bad.zip: cannot open archive"):
        Archive(p)


def test_store_round_trip(tmp_path):
    s = ingest(dataset_cfg("ntu_samples"), archive_path("ntu_samples"), tmp_path / "n", progress=False)
    assert s["accepted"] == 5 and s["multi_body_sequences"] == 1 and s["views"] == 1
    st = Store.open(tmp_path / "n")
    seq = st.sequence(1)
    assert seq.positions.shape[1] == 50 and seq.body_mask.shape[1] == 2
    assert np.isfinite(seq.positions).all()


# ----------------------------------------------------------------------------- zip bombs

def _deflated_zip(path, members):
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


def test_oversized_and_zip_bomb_members_are_rejected_unread_and_counted(tmp_path):
    limits = compose_cfg(tmp_path, "bandai1")["ingest"]          # the configured defaults
    assert limits["max_compression_ratio"] >= 100 and limits["max_member_mb"] >= 512
    bomb = b"0 " * (8 * 2**20)                                   # 16 MB of one token: deflates ~1000:1
    path = _deflated_zip(tmp_path / "bomb.zip", {
        "cfg/content.txt": "toy_walk\ntoy_run\n", "cfg/style.txt": "toy_normal\ntoy_happy\n",
        "data/a.bvh": bvh(5), "data/a.json": LABEL,
        "data/bomb.bvh": bvh(5).encode() + bomb, "data/bomb.json": LABEL})
    s = ingest(CFG, path, tmp_path / "out", progress=False, limits=limits)
    reasons = {r["member"]: r["reason"] for r in s["rejected_items"]}
    assert (s["seen"], s["accepted"], s["rejected"], s["filtered"]) == (2, 1, 1, 0)
    assert "compression ratio" in reasons["data/bomb.bvh"] and "max_compression_ratio" in reasons["data/bomb.bvh"]
    # the size cap (1 MB here): checked first, the setting named
    s = ingest(CFG, path, tmp_path / "out2", progress=False, limits={**limits, "max_member_mb": 1})
    assert (s["accepted"], s["rejected"]) == (1, 1)
    assert s["rejected_items"][0]["reason"].startswith("uncompressed size 16.0 MB exceeds the limit of 1.0 MB "
                                                       "(ingest.max_member_mb)")


def test_member_caps_apply_before_decompressing(tmp_path):
    path = _deflated_zip(tmp_path / "b.zip", {"x.txt": b"0" * (4 * 2**20), "y.txt": b"tiny"})
    with Archive(path, max_member_bytes=2**20, max_ratio=50) as ar:
        with pytest.raises(Exception, match=r"x.txt: uncompressed size 4.0 MB exceeds the limit of 1.0 MB"):
            ar.read("x.txt")
        assert ar.read("y.txt") == b"tiny"
    with Archive(path, max_ratio=50) as ar:
        with pytest.raises(Exception, match=r"x.txt: compression ratio \d+:1 exceeds the limit of 50:1"):
            ar.read("x.txt")


# ----------------------------------------------------------------------------- atomic store

KILLABLE = r'''
import os, sys, time
import numpy as np
sys.path[:0] = [{src!r}, {tests!r}]
from conftest import archive_path, dataset_cfg
from motionsynth.data.ingest import ingest

hook, out, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
def pause(what):
    print("PAUSED", what, flush=True)
    time.sleep(600)
if hook == "mid-write":        # stop for good right after the store's first array is written
    save = np.save
    np.save = lambda path, *a, **k: (save(path, *a, **k), pause(path))
elif hook == "mid-swap":       # ... or between moving the previous store aside and renaming the new one in
    replace = os.replace
    os.replace = lambda src, dst: (replace(src, dst), ".old-" in str(dst) and pause(dst))
ingest(dataset_cfg("bandai1"), archive_path("bandai1"), out, max_items=n, progress=False)
print("DONE", flush=True)
'''


def _ingest_killed_at(tmp_path, hook: str, out, n: int) -> str:
    """Run ingest in a subprocess; with a hook, kill -9 it where the hook pauses; returns where."""
    code = KILLABLE.format(src=str(REPO / "src"), tests=str(REPO / "tests"))
    p = subprocess.Popen([sys.executable, "-c", code, hook, str(out), str(n)], stdout=subprocess.PIPE, text=True)
    line = p.stdout.readline()
    if hook != "none":
        assert line.startswith("PAUSED"), line
        os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=60)
    p.stdout.close()
    assert (p.returncode == -signal.SIGKILL) if hook != "none" else (p.returncode == 0 and line == "DONE\n")
    return line


def _snapshot(d):
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_killed_ingest_leaves_the_previous_store_or_none(tmp_path):
    out = tmp_path / "interim" / "bandai1"
    _ingest_killed_at(tmp_path, "none", out, 4)                   # the previous, complete store
    before = _snapshot(out)
    assert len(Store.open(out)) == 4 and {"meta.parquet", "positions.npy", "classes.json"} <= set(before)

    # killed while writing the new store: the previous one is there, byte for byte
    where = _ingest_killed_at(tmp_path, "mid-write", out, 8)
    assert ".bandai1.tmp-" in where and where.strip().endswith("positions.npy")
    assert _snapshot(out) == before and len(Store.open(out)) == 4
    partial = [p for p in out.parent.iterdir() if p.name.startswith(".bandai1.tmp-")]
    assert len(partial) == 1 and not (partial[0] / "meta.parquet").exists()   # what the kill left: hidden, partial

    # killed between the two renames: no store at all (never a partial one)
    _ingest_killed_at(tmp_path, "mid-swap", out, 8)
    assert not out.exists()
    with pytest.raises(FileNotFoundError, match="dvc repro ingest@bandai1"):
        Store.open(out)

    # the next run cleans up after the killed ones and writes a complete store
    _ingest_killed_at(tmp_path, "none", out, 8)
    assert len(Store.open(out)) == 8
    assert [p.name for p in out.parent.iterdir()] == ["bandai1"]

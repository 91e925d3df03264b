"""A new dataset in a supported format is one new config file: no code changes.

The second test runs one through every stage on the smoke profile, from config alone: a Bandai
subset whose reader has a filter (``reader.pattern``: 129 of the archive's 174 motions are left
out) and whose class ids in the source are not contiguous (contents 6, 7 and 9).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time

import pandas as pd
import yaml
from conftest import REPO, archive_path

from motionsynth.data.store import Store
from motionsynth.params import compose as compose_params
from motionsynth.reporting import kept_joints

NEW = """
name: bandai1_walks
archive: bandai1.zip
description: the walking contents of Bandai-Namco dataset 1 only
licence: CC BY-NC 4.0
reader:
  _target_: motionsynth.data.bvh.BvhReader
  pattern: "data/dataset-1_walk*.bvh"
  labels: json
  label_pattern: "data/dataset-1_walk*.json"
  content_labels: cfg/content_label.txt
  style_labels: cfg/style_label.txt
  label_prefix: dataset-1_
  end_sites: false
  scale: 0.01
skeleton: {root: Hips, hips: [UpperLeg_L, UpperLeg_R], shoulders: [UpperArm_L, UpperArm_R]}
prepare:
  representations:
    pos3d: {space: 3d, fps: 30, drop_joints: [joint_Root], clips: {vae_lstm: {length: 240, stride: 120}}}
split:
  protocols: {random: {by: sequence, stratify: label, test_fraction: 0.25}}
  val_fraction: 0.1
"""


def test_sixth_dataset_needs_only_a_config_file(tmp_path):
    conf = tmp_path / "extra_conf" / "dataset"
    conf.mkdir(parents=True)
    (conf / "bandai1_walks.yaml").write_text(NEW)
    root = tmp_path / "root"
    (root / "data" / "raw").mkdir(parents=True)
    (root / "data" / "raw" / "bandai1.zip").symlink_to(archive_path("bandai1"))
    env = {**os.environ, "MOTIONSYNTH_ROOT": str(root), "PROGRESS": "0"}
    for stage in ("ingest", "prepare", "split"):
        r = subprocess.run([sys.executable, str(REPO / "pipelines" / f"{stage}.py"),
                            "--config-dir", str(tmp_path / "extra_conf"), "dataset=bandai1_walks",
                            "tracking.enabled=false", f"hydra.run.dir={tmp_path}/hydra/{stage}"],
                           cwd=REPO, env=env, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[-3000:]
    summary = json.loads((root / "reports" / "data" / "bandai1_walks" / "ingest.json").read_text())
    assert summary["accepted"] + summary["rejected"] + summary["filtered"] == summary["seen"] > 0
    meta = pd.read_parquet(root / "data" / "interim" / "bandai1_walks" / "meta.parquet")
    assert set(meta["label_name"]) <= {"walk", "walk-back", "walk-left", "walk-right"}
    split = pd.read_csv(root / "data" / "splits" / "bandai1_walks" / "pos3d" / "random.csv")
    assert set(split["split"]) == {"train", "val", "test"}


# ------------------------------------------------------------------ a filtered, non-contiguous dataset

DS = "bandai1_b"
FILTERED = f"""
name: {DS}
archive: bandai1.zip
description: bow, bye and byebye of Bandai-Namco dataset 1 (content ids 6, 7 and 9 in the source)
licence: CC BY-NC 4.0
reader:
  _target_: motionsynth.data.bvh.BvhReader
  pattern: "data/dataset-1_b*.bvh"          # the filter: every other .bvh member is counted as filtered out
  labels: json
  label_pattern: "data/dataset-1_b*.json"
  content_labels: cfg/content_label.txt
  style_labels: cfg/style_label.txt
  label_prefix: dataset-1_
  end_sites: false
  scale: 0.01
skeleton: {{root: Hips, hips: [UpperLeg_L, UpperLeg_R], shoulders: [UpperArm_L, UpperArm_R],
            feet: [Foot_L, Toes_L, Foot_R, Toes_R]}}
prepare:
  representations:
    pos3d: {{space: 3d, fps: 60, drop_joints: [joint_Root], clips: {{vae_lstm: {{length: 240, stride: 120}}}}}}
split:
  protocols: {{random: {{by: sequence, stratify: label, test_fraction: 0.25}}}}
  val_fraction: 0.2
training: {{family: vae_lstm, representation: pos3d, protocol: random, controls: true}}   # num_classes: from the data
evaluate:
  suites: [locomotion, generative]
  locomotion: {{family: vae_lstm}}          # no compare_to: it stands in for no published set
  generative: {{frame_step: 4, epochs: 1}}
"""
PIPELINE = {"datasets": {DS: {"format": "bvh"}}, "evaluate": [DS],
            "train_runs": {f"{DS}-vae_lstm": {"dataset": DS, "model": "vae_lstm", "variant": "none",
                                              "name": "vae_lstm", "src": "vae_lstm", "shared": "base",
                                              "family": "base", "extra": "models/base"}}}


def _stage(root, name, *args, expect=0):
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, str(REPO / "pipelines" / f"{name}.py"), "--config-dir", str(root / "conf"),
                        "profile=smoke", "tracking.enabled=false", f"hydra.run.dir={root}/logs/{name}", *args],
                       cwd=REPO, env={**os.environ, "MOTIONSYNTH_ROOT": str(root), "PROGRESS": "0"},
                       capture_output=True, text=True)
    assert r.returncode == expect, f"{name} {args}: exit {r.returncode}\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"
    print(f"{name} {' '.join(args)}: {time.perf_counter() - t0:.1f} s")
    return r


def test_filtered_non_contiguous_dataset_runs_from_config_alone(tmp_path):
    """ingest -> prepare -> split -> data_report -> train -> evaluate -> report, smoke profile, no Python."""
    root = tmp_path / "root"
    shutil.copytree(REPO / "conf", root / "conf")                 # the project's config ...
    (root / "conf" / "dataset" / f"{DS}.yaml").write_text(FILTERED)  # ... plus one dataset file
    pipeline = root / "conf" / "pipeline" / "default.yaml"      # the stage lists: this dataset alone
    pipeline.write_text("# @package _global_\n" + yaml.safe_dump({**yaml.safe_load(pipeline.read_text()), **PIPELINE}))
    (root / "params.yaml").write_text(compose_params(root, ["profile=smoke"]))   # what `dvc exp run` writes
    (root / "data" / "raw").mkdir(parents=True)
    (root / "data" / "raw" / "bandai1.zip").symlink_to(archive_path("bandai1"))
    (root / "reports").mkdir()
    shutil.copy(REPO / "reports" / "published_results.csv", root / "reports")

    for stage in ("ingest", "prepare", "split"):
        _stage(root, stage, f"dataset={DS}")
    _stage(root, "data_report")

    # counts add up, the filter is reported, the labels are contiguous and the source's ids kept
    s = json.loads((root / "reports" / "data" / DS / "ingest.json").read_text())
    assert (s["seen"], s["accepted"], s["rejected"], s["filtered"]) == (137, 8, 0, 129)
    assert s["filtered_reasons"] == {"not matched by reader.pattern 'data/dataset-1_b*.bvh'": 129}
    assert [(c["label"], c["raw"], c["name"]) for c in s["class_table"]] == [(0, 6, "bow"), (1, 7, "bye"),
                                                                               (2, 9, "byebye")]
    m = json.loads((root / "reports" / "metrics" / "data" / f"{DS}.json").read_text())
    assert m["accepted"] + m["rejected"] + m["filtered"] == m["seen"] == 137
    meta = pd.read_parquet(root / "data" / "processed" / DS / "pos3d" / "meta.parquet")
    assert set(zip(meta["label"], meta["label_raw"], meta["label_name"])) == {(0, 6, "bow"), (1, 7, "bye"),
                                                                              (2, 9, "byebye")}
    data_md = (root / "reports" / "data.md").read_text()
    assert f"| {DS} | 137 | 8 | 0 | 129 |" in data_md and "129: not matched by reader.pattern" in data_md
    # its pose figure draws the skeleton prepare keeps: no bone from the static joint_Root at the origin
    keep, skel = kept_joints(Store.open(root / "data" / "interim" / DS), yaml.safe_load(FILTERED))
    assert len(keep) == len(skel.names) == 21 and "joint_Root" not in skel.names

    # a configured class count that disagrees with the data: one line naming the field and the classes
    r = _stage(root, "train", f"dataset={DS}", "model=vae_lstm", "+dataset.training.num_classes=10", expect=2)
    assert r.stderr.count("\n") == 1 and "training.num_classes is 10" in r.stderr, r.stderr
    assert "3 classes: bow (raw 6), bye (raw 7), byebye (raw 9)" in r.stderr

    _stage(root, "train", f"dataset={DS}", "model=vae_lstm", "run_name=vae_lstm")
    _stage(root, "evaluate", f"dataset={DS}")
    _stage(root, "report")

    rows = pd.read_csv(root / "reports" / "eval" / DS / "results.csv")
    loco = rows[rows["paper"] == "habibie2017_vae_lstm"]
    assert len(loco) and set(loco["compare_to"]) == {f"{DS} (ours)"}      # stands in for no published set
    assert loco["note"].str.contains("no published counterpart").all()
    acc = rows[rows["column"].astype(str).str.contains("accuracy")]
    assert acc["note"].str.contains("3 classes, chance 0.333").any(), acc["note"].tolist()
    # the report gives it tables of its own: its rows never sit beside the published Edinburgh rows
    table1 = (root / "reports" / "tables" / "vae_lstm_table1.md").read_text()
    ours = table1.split(f"**{DS}**", 1)[1].split("\n**", 1)[0]
    assert "(no published counterpart)" in ours.splitlines()[0]
    assert "| paper |" not in ours
    assert "**published only** — *Edinburgh locomotion (test, 20 sequences)*" in table1

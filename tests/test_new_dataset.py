"""A sixth dataset in a supported format is one new config file: no code changes."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pandas as pd
from conftest import REPO, archive_path

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
    assert summary["accepted"] + summary["rejected"] == summary["seen"] > 0
    meta = pd.read_parquet(root / "data" / "interim" / "bandai1_walks" / "meta.parquet")
    assert set(meta["label_name"]) <= {"walk", "walk-back", "walk-left", "walk-right"}
    split = pd.read_csv(root / "data" / "splits" / "bandai1_walks" / "pos3d" / "random.csv")
    assert set(split["split"]) == {"train", "val", "test"}

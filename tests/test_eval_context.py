"""The evaluate framework: suite validation, outputs, and MLflow holding the same numbers as the DVC metrics."""

from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pandas as pd
import pytest
from conftest import build_eval_root, compose_cfg

from motionsynth.data.controls import root_and_controls, to_global
from motionsynth.evaluation import EvalContext, evaluate, log_to_mlflow
from motionsynth.evaluation.context import COLUMNS, metrics_dict

DS = "bandai2_locomotion"


@pytest.fixture(scope="module")
def root(tmp_path_factory, one_thread):
    r = tmp_path_factory.mktemp("evalroot")
    runs = build_eval_root(r, DS, {"erd": ("erd", "none"), "zero_velocity": ("zero_velocity", "none")})
    return r, runs


def test_to_global_inverts_the_pose_split():
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(40, 6, 3))
    pos[:, :, [0, 2]] += np.cumsum(rng.normal(size=(40, 1, 2)), 0)
    pose, root, _ = root_and_controls(pos, 0, (1, 2), (3, 4), 30.0)
    assert np.abs(to_global(pose, root) - pos).max() < 1e-5
    assert to_global(np.stack([pose] * 3), root).shape == (3, 40, 6, 3)   # roots broadcast over samples


def test_unknown_suite_fails_before_any_work(root):
    r, runs = root
    cfg = compose_cfg(r, DS)
    cfg["dataset"]["evaluate"] = {"suites": ["no_such_suite"]}
    with pytest.raises(ValueError, match="unknown suite.*no_such_suite"):
        evaluate(cfg, runs)


def test_outputs_and_mlflow_hold_the_same_numbers(root, tmp_path):
    r, runs = root
    cfg = compose_cfg(r, DS, "tracking.enabled=true", f"paths.reports={tmp_path}/reports",
                      f"paths.samples={tmp_path}/samples")
    cfg["dataset"]["evaluate"] = {"suites": []}
    ctx = EvalContext(cfg, runs)
    assert ctx.available() == ["erd", "zero_velocity"] and ctx.available("erd", None) == ["erd"]
    data = ctx.data("vae_lstm")
    raw = ctx.raw(data, ctx.pick(data, 3))
    assert raw["pose"].shape[1:] == (240, 21, 3) and raw["controls"].shape[-1] == 3
    z = data.batch(ctx.pick(data, 3)).pose
    assert np.allclose(ctx.physical(data, z), raw["pose"], atol=1e-4)    # de-normalise inverts the batch
    ctx.add(paper="p", table="T", compare_to="c", metric="Motion error", column="frame70", method="ERD",
            value=1.5, n=3, run="erd")
    ctx.add_seeds([1.0, 2.0, 3.0], paper="p", table="T", compare_to="c", metric="Motion error", column="frame70",
                  method="VAE-LSTM")
    ctx.curve("err", "ERD", [70, 90], [1.0, 2.0])
    ctx.sample("ground truth", raw["pose"][:1], fps=60)
    from motionsynth.evaluation.context import write

    files = write(ctx)
    table = pd.read_csv(files["results"])
    assert list(table.columns) == COLUMNS and len(table) == 2
    vae = table[table.method == "VAE-LSTM"].iloc[0]
    assert vae["value"] == 2.0 and vae["std"] == 1.0 and vae["seeds"] == 3
    metrics = json.loads(files["metrics"].read_text())
    assert metrics == metrics_dict(ctx.rows) == {"erd": {"motion_error/frame70": 1.5},
                                                 "vae_lstm": {"motion_error/frame70": 2.0}}
    assert pd.read_csv(files["plot:err"]).shape == (2, 3)
    npz = np.load(files["samples"])
    assert npz["m:ground truth"].shape == (1, 240, 21, 3) and json.loads(str(npz["meta"]))["fps"] == 60
    ids = log_to_mlflow(ctx)
    con = sqlite3.connect(r / "mlflow.db")
    for run_id in ids:
        name = con.execute("select name from runs where run_uuid = ?", (run_id,)).fetchone()[0]
        logged = dict(con.execute("select key, value from latest_metrics where run_uuid = ?", (run_id,)).fetchall())
        method = name.split(":", 1)[1]
        assert logged == {f"test/{k}": v for k, v in metrics[method].items()}


def test_non_finite_values_are_kept_out_of_metrics(root):
    r, runs = root
    ctx = EvalContext(compose_cfg(r, DS), runs)
    ctx.add(paper="p", table="T", compare_to="c", metric="m", column="c", method="X", value=math.nan)
    assert metrics_dict(ctx.rows) == {}

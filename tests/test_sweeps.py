"""Hydra multirun sweeps as MLflow parent/child runs (motionsynth.sweeps): the joblib launcher
with two jobs logging at once, submitit (local), the Optuna preset, kill-and-relaunch, and
params.yaml as DVC's Hydra composition of conf/.

Each sweep runs `pipelines/train.py -m` as a user would, on real H3.6M items (smoke sizes)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO, build_eval_root

from motionsynth.params import compose as compose_params

DATASET = "h36m"


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    r = tmp_path_factory.mktemp("sweeps")
    build_eval_root(r, DATASET, {}, max_items=8)
    return r


def sweep(root: Path, *overrides: str, tag: str, timeout: int = 300, wait: bool = True):
    """``python pipelines/train.py -m`` at the smoke sizes into ``root`` (its own mlflow.db)."""
    env = {**os.environ, "MOTIONSYNTH_ROOT": str(root), "PROGRESS": "0", "HYDRA_FULL_ERROR": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    cmd = [sys.executable, "pipelines/train.py", "-m", f"dataset={DATASET}", "profile=smoke", "train.threads=1",
           f"hydra.sweep.dir={root}/multirun/{tag}", *overrides]
    if not wait:
        return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
    r = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    return r.stdout + r.stderr


def db(root: Path) -> sqlite3.Connection:
    return sqlite3.connect(root / "mlflow.db")


def parents(con, key_like: str = "%") -> list[str]:
    return [r[0] for r in con.execute(
        "select r.run_uuid from runs r join tags t on r.run_uuid = t.run_uuid "
        "where t.key = 'kind' and t.value = 'sweep' and r.name like ?", (key_like,))]


def children(con, parent: str) -> dict[str, tuple[str, str]]:
    """child run id -> (name, status)"""
    return {r[0]: (r[1], r[2]) for r in con.execute(
        "select r.run_uuid, r.name, r.status from runs r join tags t on r.run_uuid = t.run_uuid "
        "where t.key = 'mlflow.parentRunId' and t.value = ?", (parent,))}


def artifact_dir(con, run_id: str) -> Path:
    uri = con.execute("select artifact_uri from runs where run_uuid = ?", (run_id,)).fetchone()[0]
    return Path(uri.removeprefix("file://"))


def test_joblib_sweep_two_at_a_time_loses_nothing(root):
    """4 jobs, 2 at a time (joblib), while another process sweeps into the same mlflow.db:
    every run, every per-epoch metric and every artifact arrives; the store stays sound."""
    other = sweep(root, "model=zero_velocity,lstm3lr", "train.lr=5e-4", tag="other", wait=False)
    out = sweep(root, "model=erd,lstm3lr", "train.lr=1e-3,2e-3", "hydra/launcher=joblib",
                "hydra.launcher.n_jobs=2", tag="joblib")
    assert other.wait(timeout=300) == 0, other.stdout.read()[-3000:]
    assert "Joblib.Parallel(n_jobs=2" in out
    con = db(root)
    assert con.execute("pragma integrity_check").fetchone()[0] == "ok"
    (parent,) = parents(con, "sweep:train %model=erd,lstm3lr%")
    kids = children(con, parent)
    assert len(kids) == 4 and {s for _, s in kids.values()} == {"FINISHED"}
    names = sorted(n for n, _ in kids.values())
    assert names == sorted(f"train:{m}@{DATASET} train.lr={lr}" for m in ("erd", "lstm3lr") for lr in ("0.001", "0.002"))
    for run_id in kids:
        hist = con.execute("select count(*) from metrics where run_uuid = ? and key = 'val/loss'", (run_id,)).fetchone()[0]
        assert hist == 2  # the smoke profile's 2 epochs, none lost
        files = {p.name for p in artifact_dir(con, run_id).rglob("*")}
        assert {"config.yaml", "best.pt", "sample.png"} <= files
    # the parent: the sweep's overrides as params, the children's summary table as artifacts, the best value
    params = dict(con.execute("select key, value from params where run_uuid = ?", (parent,)).fetchall())
    assert params["sweep.model"] == "erd,lstm3lr" and params["sweep.train.lr"] == "1e-3,2e-3"
    summary = (artifact_dir(con, parent) / "sweep_summary.csv").read_text().splitlines()
    assert len(summary) == 1 + 4
    best = dict(con.execute("select key, value from latest_metrics where run_uuid = ?", (parent,)).fetchall())
    kid_best = [v for (v,) in con.execute(
        f"select value from latest_metrics where key = 'best/rel_zv' and run_uuid in ({','.join('?' * 4)})",
        list(kids))]
    assert best["best/rel_zv"] == pytest.approx(min(kid_best)) and best["children"] == 4
    # the concurrent sweep: its own parent with its 2 children
    (other_parent,) = parents(con, "sweep:train %model=zero_velocity,lstm3lr%")
    assert len(children(con, other_parent)) == 2
    # sweep jobs keep checkpoints per override set, never in the DVC stages' folders
    assert not (root / "models" / DATASET / "erd").exists()
    assert len(list((root / "models" / "sweeps" / DATASET / "erd").iterdir())) == 2


def test_killed_sweep_relaunch_finishes_and_resumes(root):
    args = ("model=lstm3lr", "run_name=killed", "train.lr=1e-3,3e-3", "train.epochs=8", "train.patience=10")
    proc = sweep(root, *args, tag="kill", wait=False)
    first = root / "models" / "sweeps" / DATASET / "killed"
    deadline = time.time() + 240
    while time.time() < deadline:  # kill -9 once the first job has checkpointed at least one epoch
        if list(first.glob("*/last.pt")) and proc.poll() is None:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    con = db(root)
    (parent,) = parents(con, "sweep:train %model=lstm3lr%train.epochs=8%")
    before = children(con, parent)
    assert 1 <= len(before) <= 2 and "RUNNING" in {s for _, s in before.values()}
    out = sweep(root, *args, tag="relaunch")
    assert "resumed from" in out
    con = db(root)
    assert parents(con, "sweep:train %model=lstm3lr%train.epochs=8%") == [parent]  # the same parent run
    after = children(con, parent)
    assert len(after) == 2 and set(before) <= set(after)  # the killed job continued its own MLflow run
    assert {s for _, s in after.values()} == {"FINISHED"}
    for d in first.iterdir():
        assert json.loads((d / "summary.json").read_text())["epochs_run"] == 8, d
    for run_id in after:  # every epoch's metrics, the interrupted job's included
        steps = con.execute("select count(distinct step) from metrics where run_uuid = ? and key = 'val/loss'",
                            (run_id,)).fetchone()[0]
        assert steps == 8, after[run_id]


def test_submitit_local_launcher(root):
    """The SLURM code path (submitit: pickled jobs, job folders) on this machine."""
    sweep(root, "model=erd", "train.lr=1e-3,2e-3", "hydra/launcher=local", "train.epochs=1", tag="submitit")
    con = db(root)
    (parent,) = parents(con, "sweep:train %model=erd%train.epochs=1 train.lr=1e-3,2e-3%")
    kids = children(con, parent)
    assert len(kids) == 2 and {s for _, s in kids.values()} == {"FINISHED"}
    assert list((root / "multirun" / "submitit" / ".submitit").iterdir())


def test_optuna_preset_in_memory_study(root):
    out = sweep(root, "hparams_search=glogen_h36m", "hydra.sweeper.n_trials=2", "hydra.sweeper.sampler.n_startup_trials=2",
                "train.epochs=1", tag="optuna")
    results = (root / "multirun" / "optuna" / "optimization_results.yaml").read_text()
    assert "best_value" in results and "train.lr" in results
    con = db(root)
    (parent,) = parents(con, "sweep:train %hparams_search=glogen_h36m%")
    kids = children(con, parent)
    assert len(kids) == 2
    best = dict(con.execute("select key, value from latest_metrics where run_uuid = ?", (parent,)).fetchall())
    assert best["best/rel_zv"] == pytest.approx(float(results.split("best_value:")[1].split()[0]))
    assert "Study name: glogen_h36m" in out and "Storage: None" in out


def test_params_yaml_is_the_composition_of_conf():
    """conf/ is the source of truth: the committed params.yaml is exactly what `dvc exp run` composes."""
    assert (REPO / "params.yaml").read_text() == compose_params(REPO), "run: python -m motionsynth.params"
    assert "enabled = true" in (REPO / ".dvc" / "config").read_text().split("[hydra]")[1]

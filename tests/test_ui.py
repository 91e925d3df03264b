"""The MLflow UI (``motionsynth ui``) seen in a real headless browser, and a team tracking server.

* ``test_ui_shows_runs``: a tiny Hydra sweep (``pipelines/train.py -m``, two jobs: an MLflow parent
  run and two children) in a temporary project's SQLite store, the UI
  started with :func:`motionsynth.ui.serve`, the runs checked through the REST API and in the page
  Chromium renders, and a screenshot of the runs table kept in
  ``reports/test_artifacts/mlflow_ui_runs.png``.
* ``test_team_tracking_server``: a training job logs over http to ``mlflow server`` with its own
  SQLite store; its run, per-epoch metric history and artifacts are then read back from the server.

Headless Chromium is installed by ``scripts/install_chromium.sh`` when it is missing; when it cannot
be installed the test fails (deselect these tests with ``-m 'not slow'``).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth import ui

pytestmark = pytest.mark.slow

DS = "bandai2_locomotion"
EXPERIMENT = f"motionsynth/{DS}"          # a plain training run's experiment
SWEEPS = "motionsynth/sweeps"             # a sweep's parent and child runs
SCREENSHOT = REPO / "reports" / "test_artifacts" / "mlflow_ui_runs.png"


# ---------------------------------------------------------------- runs to show


def _prepare_data(root: Path, max_items: int = 16) -> None:
    """Real smoke data of ``DS`` (``max_items`` items of the real archive) under ``root/data``."""
    build_eval_root(root, DS, {}, max_items=max_items)


def _train(root: Path, name: str, *overrides: str) -> dict:
    """One tiny VAE-LSTM training job (smoke sizes, 2 epochs x 4 batches) with MLflow tracking on,
    logging wherever :func:`motionsynth.tracking.tracking_uri` points."""
    from motionsynth.training.run import run

    cfg = compose_cfg(root, DS, "model=vae_lstm", f"run_name={name}", "tracking.enabled=true", *overrides)
    return run(cfg, progress=False)


def _make_runs(root: Path) -> dict[str, dict[str, float]]:
    """A tiny Hydra sweep (2 VAE-LSTM jobs at the smoke sizes) logged to ``root``'s own store
    (``sqlite:///<root>/mlflow.db``), as a user starts it. Returns ``{MLflow run name: {metric:
    expected latest value}}`` for the two child runs (their summaries on disk) and the parent."""
    _prepare_data(root)
    env = {**os.environ, "MOTIONSYNTH_ROOT": str(root), "PROGRESS": "0"}
    env.pop("MLFLOW_TRACKING_URI", None)
    r = subprocess.run([sys.executable, "pipelines/train.py", "-m", f"dataset={DS}", "model=vae_lstm",
                        "train.lr=1e-3,2e-3", "profile=smoke", "train.threads=1",
                        f"hydra.sweep.dir={root}/multirun/ui"], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    expected = {}
    for lr in ("0.001", "0.002"):
        (folder,) = (root / "models" / "sweeps" / DS / "vae_lstm").glob(f"*train.lr={lr}*")
        summary = json.loads((folder / "summary.json").read_text())
        expected[f"train:vae_lstm@{DS} train.lr={lr}"] = {"best/pred_mse": summary["val/pred_mse"],
                                                          "best/loss": summary["val/loss"]}
    expected["sweep:train dataset=bandai2_locomotion model=vae_lstm profile=smoke train.lr=1e-3,2e-3"] = {
        "children": 2.0, "best/loss": min(v["best/loss"] for v in expected.values())}   # VAE-LSTM's monitor: val/loss
    return expected


# ---------------------------------------------------------------- REST and processes


def _get(url: str, **params) -> dict:
    q = urllib.parse.urlencode(params)
    with urllib.request.urlopen(f"{url}?{q}" if q else url, timeout=30) as r:
        return json.loads(r.read())


def _post(url: str, body: dict) -> dict:
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


def _experiments(url: str) -> dict[str, str]:
    """``{name: experiment_id}`` of every experiment on the server."""
    exps = _post(f"{url}/api/2.0/mlflow/experiments/search", {"max_results": 1000}).get("experiments", [])
    return {e["name"]: e["experiment_id"] for e in exps}


def _runs(url: str, experiment_ids: list[str]) -> dict[str, dict]:
    """``{MLflow run name: run}`` (REST ``runs/search``),
    with ``run["metrics"]`` as ``{key: latest value}`` and ``run["tags"]`` as ``{key: value}``."""
    runs = _post(f"{url}/api/2.0/mlflow/runs/search",
                 {"experiment_ids": experiment_ids, "max_results": 1000}).get("runs", [])
    out = {}
    for r in runs:
        r["metrics"] = {m["key"]: m["value"] for m in r["data"].get("metrics", [])}
        r["tags"] = {t["key"]: t["value"] for t in r["data"].get("tags", [])}
        out[r["info"]["run_name"]] = r
    return out


def _processes() -> dict[int, tuple[int, str]]:
    """Every live (non-zombie) process: ``{pid: (session id, command line)}``."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2:].split()
        if fields[0] != "Z":
            out[int(d.name)] = (int(fields[3]), cmd)
    return out


def _server_processes(url: ui.ServerURL) -> dict[int, str]:
    """The processes of ``url``'s server session (the mlflow launcher and its uvicorn worker)."""
    return {pid: cmd for pid, (sid, cmd) in _processes().items() if sid == url.pid}


def _assert_all_gone(started: dict[int, str], port: int, marker: str) -> None:
    """None of ``started`` is alive, and no mlflow / uvicorn / gunicorn process for this ``port`` or
    whose command names ``marker`` (this test's temporary folder) is left anywhere."""
    now = _processes()
    alive = {pid: cmd for pid, cmd in started.items() if pid in now and now[pid][1] == cmd}
    assert not alive, f"server processes left running: {alive}"
    strays = {pid: cmd for pid, (_, cmd) in now.items()
              if any(w in cmd for w in ("mlflow", "uvicorn", "gunicorn", "chromium", "chrome"))
              and (f"--port {port}" in cmd or f":{port}" in cmd or marker in cmd)}
    assert not strays, f"processes started by the test are left: {strays}"


# ---------------------------------------------------------------- headless Chromium


def _chromium() -> str:
    """The ``chromium`` executable, installed by the project's ``scripts/install_chromium.sh`` if missing."""
    exe = shutil.which("chromium")
    if exe:
        return exe
    script = REPO / "scripts" / "install_chromium.sh"
    r = subprocess.run(["bash", str(script)], capture_output=True, text=True, timeout=1200)
    exe = shutil.which("chromium")
    if not exe:
        pytest.fail(f"headless Chromium is needed to check the MLflow UI, and {script.relative_to(REPO)} "
                    f"could not install it (exit {r.returncode}):\n{(r.stdout + r.stderr)[-2000:]}\n"
                    f"Install Debian's `chromium` package, or deselect this test with -m 'not slow'.",
                    pytrace=False)
    return exe


def _chromium_run(args: list[str], profile: Path, timeout: float = 90) -> str:
    """Run headless Chromium once (in its own session, killed as a whole afterwards); returns stdout."""
    cmd = [_chromium(), "--headless", "--disable-gpu", "--disable-dev-shm-usage", "--hide-scrollbars",
           "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-quic", "--no-default-browser-check", "--disable-extensions", "--mute-audio",
           f"--user-data-dir={profile}", "--window-size=1400,900", "--virtual-time-budget=30000", *args]
    if os.geteuid() == 0:
        cmd.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        ui.stop_group(proc)
        out, err = proc.communicate()
        pytest.fail(f"chromium did not finish within {timeout:g} s:\n{err[-2000:]}")
    finally:
        ui.stop_group(proc)  # the renderer / GPU / zygote helpers too
        shutil.rmtree(profile, ignore_errors=True)
    assert proc.returncode == 0, f"chromium failed ({proc.returncode}):\n{err[-2000:]}"
    return out


def _assert_not_blank(png: Path) -> None:
    from PIL import Image

    assert png.exists() and png.stat().st_size > 0, f"no screenshot at {png}"
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape[:2] == (900, 1400), img.shape
    colours = len(np.unique(img.reshape(-1, 3), axis=0))
    non_white = float((img.min(axis=2) < 235).mean())
    assert colours >= 32, f"screenshot has only {colours} colours: blank or an error page"
    assert non_white > 0.01, f"screenshot is {1 - non_white:.1%} white: the page did not render"


# ---------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def root(tmp_path_factory, one_thread) -> Path:
    """A project root for the UI tests (its data is prepared by the tests themselves)."""
    return tmp_path_factory.mktemp("ui_root")


def test_ui_shows_runs(root, tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.setenv("MOTIONSYNTH_ROOT", str(root))
    _chromium()  # installed (or the test failed) before any work
    t0 = time.perf_counter()
    expected = _make_runs(root)
    t_runs = time.perf_counter() - t0

    with ui.serve(root) as url:
        t_up = time.perf_counter() - t0 - t_runs
        assert url.startswith("http://127.0.0.1:")
        port = int(url.rsplit(":", 1)[1])
        started = _server_processes(url)
        assert any("mlflow" in c and "server" in c for c in started.values()), started
        assert any("uvicorn" in c for c in started.values()), started

        # (c) the REST API lists the runs with their metrics
        exps = _experiments(url)
        assert SWEEPS in exps, exps
        runs = _runs(url, list(exps.values()))
        assert set(expected) <= set(runs), sorted(runs)
        parent = next(n for n in expected if n.startswith("sweep:"))
        for name, metrics in expected.items():
            run = runs[name]
            assert run["info"]["status"] == "FINISHED"
            if name != parent:
                assert "val/loss" in run["metrics"] and "val/pred_mse" in run["metrics"]
                assert run["tags"]["mlflow.parentRunId"] == runs[parent]["info"]["run_id"]
            for key, value in metrics.items():
                assert run["metrics"][key] == pytest.approx(value, rel=1e-6), (name, key)

        # (d) the runs page as a browser renders it: its DOM names the runs, and a screenshot
        # (MLflow 3 opens an experiment on its GenAI overview; the "Model training" view is the runs table)
        page = f"{url}/#/experiments/{exps[SWEEPS]}?workflowType=machine_learning"
        dom = _chromium_run(["--dump-dom", page], tmp_path / "chromium-dom")
        # the table lists the sweep's parent run (its children nest under it, collapsed; the REST
        # checks above cover them)
        assert parent in dom, f"{parent!r} is not in the rendered runs page ({len(dom)} characters of DOM)"
        png = tmp_path / "mlflow_ui_runs.png"
        _chromium_run([f"--screenshot={png}", page], tmp_path / "chromium-shot")

    # (g) the server and all its children are gone
    _assert_all_gone(started, port, str(root))

    # (e) a real picture, (f) kept as a test artifact (and left in tmp_path)
    _assert_not_blank(png)
    SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(png, SCREENSHOT)
    print(f"runs {t_runs:.1f} s, server up {t_up:.1f} s, total {time.perf_counter() - t0:.1f} s; "
          f"screenshot {SCREENSHOT}")


def test_team_tracking_server(root, tmp_path, monkeypatch):
    monkeypatch.setenv("MOTIONSYNTH_ROOT", str(root))
    _prepare_data(root)
    db = tmp_path / "team.db"
    with ui.serve(tmp_path, backend_store_uri=f"sqlite:///{db}") as url:
        port = int(url.rsplit(":", 1)[1])
        started = _server_processes(url)
        monkeypatch.setenv("MLFLOW_TRACKING_URI", url)
        summary = _train(root, "team", f"paths.models={tmp_path}/models")
        monkeypatch.delenv("MLFLOW_TRACKING_URI")

        exps = _experiments(url)
        assert EXPERIMENT in exps, exps
        runs = _runs(url, [exps[EXPERIMENT]])
        assert set(runs) == {f"train:team@{DS}"}, sorted(runs)
        run = runs[f"train:team@{DS}"]
        run_id = run["info"]["run_id"]
        assert run["info"]["status"] == "FINISHED"
        assert run["metrics"]["best/pred_mse"] == pytest.approx(summary["val/pred_mse"], rel=1e-6)
        tags = run["tags"]
        assert tags["model"] == "vae_lstm" and tags["dataset"] == DS
        params = {p["key"]: p["value"] for p in run["data"]["params"]}
        assert params["model.name"] == "vae_lstm"

        history = _get(f"{url}/api/2.0/mlflow/metrics/get-history", run_id=run_id,
                       metric_key="val/loss")["metrics"]
        assert len({m["step"] for m in history}) == len(history) == summary["epochs_run"] == 2, history

        files = _get(f"{url}/api/2.0/mlflow/artifacts/list", run_id=run_id).get("files", [])
        names = {f["path"] for f in files}
        assert {"config.yaml", "best.pt", "sample.png"} <= names, names
        # uploaded through the server (mlflow-artifacts:), stored beside its database
        assert run["info"]["artifact_uri"].startswith("mlflow-artifacts:"), run["info"]["artifact_uri"]
        assert any(p.name == "best.pt" for p in (tmp_path / "mlartifacts").rglob("best.pt"))
        if (root / "mlflow.db").exists():  # nothing went to the project's local store instead
            with contextlib.closing(sqlite3.connect(root / "mlflow.db")) as con:
                assert not con.execute("select 1 from runs where name like 'train:team%'").fetchall()
    _assert_all_gone(started, port, str(tmp_path))

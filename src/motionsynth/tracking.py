"""The one place that talks to MLflow.

* Tracking URI: ``$MLFLOW_TRACKING_URI`` if set, else ``sqlite:///<repo>/mlflow.db``
  with an absolute path (Hydra may change the working directory).
* Experiments are named ``motionsynth/<dataset>``; runs ``<stage>:<what>``.
* Only rank 0 of a distributed job logs (``RANK`` unset or ``0``).
"""

from __future__ import annotations

import contextlib
import logging
import json
import os
import re
from pathlib import Path
from typing import Any, Iterator, Mapping

log = logging.getLogger(__name__)
_ACTIVE = {"on": False}  # inside a run: log_metrics / log_artifact write to it


def local_store_uri(root: str | Path) -> str:
    """The project's own store, ``sqlite:///<repo>/mlflow.db`` (absolute). Inside a ``dvc exp run``
    temporary workspace (``<repo>/.dvc/tmp/exps/...``) that is the repository's own ``mlflow.db``,
    so queued experiments land beside every other run."""
    root = Path(root).resolve()
    marker = f"{os.sep}.dvc{os.sep}tmp{os.sep}exps{os.sep}"
    if marker in f"{root}{os.sep}":
        root = Path(f"{root}{os.sep}".split(marker, 1)[0])
    return f"sqlite:///{root / 'mlflow.db'}"


def tracking_uri(root: str | Path) -> str:
    """``$MLFLOW_TRACKING_URI``, else :func:`local_store_uri`."""
    return os.environ.get("MLFLOW_TRACKING_URI") or local_store_uri(root)


def sqlite_artifacts(uri: str) -> Path | None:
    """For a local SQLite store, where its artifacts go: ``mlartifacts/`` beside the database
    (not the working directory); ``None`` for other stores."""
    if not uri.startswith("sqlite:///"):
        return None
    return Path(uri[len("sqlite:///"):]).resolve().parent / "mlartifacts"


@contextlib.contextmanager
def _store_lock(uri: str) -> Iterator[None]:
    """An exclusive file lock beside a local SQLite store (``mlflow.db.lock``) while a process
    opens it: the first open creates the schema, and two processes doing that at once (two
    sweep jobs, a sweep and a ``dvc exp``) fail on "table already exists". Other stores: no-op."""
    if not uri.startswith("sqlite:///"):
        yield
        return
    import fcntl

    db = Path(uri[len("sqlite:///"):])
    db.parent.mkdir(parents=True, exist_ok=True)
    with open(db.with_name(db.name + ".lock"), "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def set_experiment(mlflow, uri: str, experiment: str):
    """Select (creating if needed) ``experiment``. For a local SQLite store, artifacts go to
    ``mlartifacts/`` beside the database rather than to the working directory. Opening the
    store and creating the experiment happen under :func:`_store_lock`."""
    with _store_lock(uri):
        exp = mlflow.get_experiment_by_name(experiment)
        art = sqlite_artifacts(uri)
        if exp is None and art is not None:
            mlflow.create_experiment(experiment, artifact_location=art.as_uri())
        return mlflow.set_experiment(experiment)


def is_rank_zero() -> bool:
    return int(os.environ.get("RANK", "0")) == 0


def metric_key(key: str) -> str:
    """``key`` with the characters MLflow refuses in metric names (anything but letters, digits and
    ``_ - . space : /``) replaced by ``_``: summaries may key counts by free text (an unused reason)."""
    return re.sub(r"[^\w\-. :/]", "_", str(key))


def flatten(d: Mapping[str, Any], prefix: str = "", sep: str = ".") -> dict[str, Any]:
    """Flatten nested mappings into ``a.b.c`` keys; lists become their string form."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{sep}{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            out.update(flatten(v, key, sep))
        else:
            out[key] = v
    return out


class StageRecorder:
    """Log one short stage's run from a helper process started when the stage starts.

    MLflow's import and store initialisation cost ~2.5 s of CPU per process. A
    short data stage starts this recorder first; the helper process pays that
    cost on the second core while the stage works, then waits for the record.
    :meth:`submit` sends params/metrics/artifacts and waits until they are
    written, so a stage never ends with its run unlogged; a logging failure
    fails the stage. Long jobs (training) log in-process with :func:`run`.
    """

    def __init__(self, root: str | Path, experiment: str):
        import subprocess
        import sys

        self.proc = None
        if not is_rank_zero():
            return
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "motionsynth.tracking", tracking_uri(root), experiment],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(
                [str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")])})

    def submit(self, run_name: str, params: Mapping[str, Any], metrics: Mapping[str, Any],
               tags: Mapping[str, str], artifacts: list[str] = ()) -> None:
        if self.proc is None:
            return
        flat_params = {k: _short(v) for k, v in flatten(params).items()}
        flat_metrics = {metric_key(k): float(v) for k, v in flatten(metrics).items()
                        if isinstance(v, (int, float)) and not isinstance(v, bool)}
        payload = json.dumps({"run_name": run_name, "params": flat_params, "metrics": flat_metrics,
                              "tags": dict(tags), "artifacts": [str(a) for a in artifacts if Path(a).exists()]})
        _, err = self.proc.communicate(payload, timeout=600)
        if self.proc.returncode != 0:
            raise RuntimeError(f"MLflow logging of {run_name!r} failed:\n{err[-2000:]}")


def _serve(uri: str, experiment: str) -> None:
    """Helper-process side of :class:`StageRecorder`."""
    import sys

    import mlflow

    logging.getLogger("alembic").setLevel(logging.WARNING)
    mlflow.set_tracking_uri(uri)
    set_experiment(mlflow, uri, experiment)
    data = sys.stdin.read()
    if not data.strip():  # the stage failed before submitting: log nothing
        return
    rec = json.loads(data)
    with mlflow.start_run(run_name=rec["run_name"], tags=rec["tags"]):
        _log_params(mlflow, rec["params"])
        if rec["metrics"]:
            mlflow.log_metrics(rec["metrics"])
        for a in rec["artifacts"]:
            mlflow.log_artifact(a)


@contextlib.contextmanager
def resumable_run(root: str | Path, experiment: str, run_name: str, run_id: str | None = None,
                  params: Mapping[str, Any] | None = None, tags: Mapping[str, str] | None = None,
                  enabled: bool = True, parent_run_id: str | None = None) -> Iterator[Any]:
    """An MLflow run for a long job, continued (same run id) when the job resumes from a checkpoint.
    ``parent_run_id``: a child of that run (a Hydra sweep's parent, :mod:`motionsynth.sweeps`).

    Yields the active run, or ``None`` on non-zero ranks or when ``enabled`` is false;
    :func:`log_metrics` and :func:`log_artifact` are no-ops outside such a run.
    """
    if not (enabled and is_rank_zero()):
        yield None
        return
    import mlflow

    logging.getLogger("alembic").setLevel(logging.WARNING)
    uri = tracking_uri(root)
    mlflow.set_tracking_uri(uri)
    set_experiment(mlflow, uri, experiment)
    resume = None
    if run_id:
        try:
            mlflow.get_run(run_id)
            resume = run_id
        except Exception:  # the run was deleted or lives in another store: start a new one
            resume = None
    tags = dict(tags or {})
    if parent_run_id:
        tags["mlflow.parentRunId"] = parent_run_id
    with mlflow.start_run(run_id=resume, run_name=None if resume else run_name,
                          tags=tags) as active, _activated():
        if not resume:
            _log_params(mlflow, params)
        yield active


def log_runs(root: str | Path, experiment: str, runs: list[Mapping[str, Any]]) -> list[str]:
    """Log several finished runs in one process (one MLflow import and store set-up for all):
    each ``{"run_name", "metrics", "params", "tags", "artifacts"}``. Returns their run ids."""
    if not is_rank_zero() or not runs:
        return []
    import mlflow

    logging.getLogger("alembic").setLevel(logging.WARNING)
    uri = tracking_uri(root)
    mlflow.set_tracking_uri(uri)
    set_experiment(mlflow, uri, experiment)
    ids = []
    for r in runs:
        with mlflow.start_run(run_name=r["run_name"], tags=dict(r.get("tags") or {})) as active:
            _log_params(mlflow, r.get("params"))
            metrics = {metric_key(k): float(v) for k, v in flatten(r.get("metrics") or {}).items()
                       if isinstance(v, (int, float)) and not isinstance(v, bool)}
            for i in range(0, len(metrics), 1000):
                mlflow.log_metrics(dict(list(metrics.items())[i:i + 1000]))
            for a in r.get("artifacts") or []:
                if Path(a).exists():
                    mlflow.log_artifact(str(a))
            ids.append(active.info.run_id)
    return ids


def log_metrics(metrics: Mapping[str, float], step: int | None = None) -> None:
    if not (is_rank_zero() and _ACTIVE["on"]):
        return
    import mlflow

    clean = {metric_key(k): float(v) for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    if clean:
        mlflow.log_metrics(clean, step=step)


def log_artifact(path: str | Path, artifact_path: str | None = None) -> None:
    if not (is_rank_zero() and _ACTIVE["on"]):
        return
    import mlflow

    mlflow.log_artifact(str(path), artifact_path)


@contextlib.contextmanager
def _activated() -> Iterator[None]:
    _ACTIVE["on"] = True
    try:
        yield
    finally:
        _ACTIVE["on"] = False


def _param_items(params: Mapping[str, Any] | None) -> list[tuple[str, str]]:
    """Flattened, shortened params with keys MLflow accepts (alphanumerics, _ - . space : /;
    a config key may hold a regex, e.g. in report.plots)."""
    return [(re.sub(r"[^\w\-. :/]", "_", k), _short(v)) for k, v in flatten(params or {}).items()]


def _log_params(mlflow, params: Mapping[str, Any] | None) -> None:
    """Log params in batches of 100, MLflow's limit per call."""
    items = _param_items(params)
    for i in range(0, len(items), 100):
        mlflow.log_params(dict(items[i:i + 100]))


def log_params_client(client, run_id: str, params: Mapping[str, Any]) -> None:
    """:func:`_log_params` for a run that is not the active one (``MlflowClient``)."""
    from mlflow.entities import Param

    items = [Param(k, v) for k, v in _param_items(params)]
    for i in range(0, len(items), 100):
        client.log_batch(run_id, params=items[i:i + 100])


def _short(v: Any) -> str:
    s = str(v)
    return s if len(s) <= 500 else s[:497] + "..."


if __name__ == "__main__":
    import sys

    _serve(sys.argv[1], sys.argv[2])

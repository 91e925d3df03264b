"""Hydra multirun sweeps as MLflow parent / child runs.

``python pipelines/train.py -m model=glogen,seq2seq train.lr=1e-3,2e-3`` runs four jobs
(with any launcher: basic, ``joblib``, ``submitit_local`` / ``slurm``; or a sweeper:
``hparams_search=...``). Around them:

* :class:`MLflowSweepCallback` (``hydra.callbacks`` in ``conf/config.yaml``) runs in the
  launching process. At the start of a multirun it creates (or, for a relaunch of the
  same command, reopens) the **parent run** in the experiment ``tracking.sweep_experiment``:
  params = the sweep's overrides, tag ``motionsynth.sweep_key`` = a hash of the job name,
  the overrides and the sweeper's search space. Creating the experiment here, once,
  before any job starts, is what keeps parallel jobs from racing to create it. The run id
  goes to ``<sweep dir>/mlflow_parent.json`` for the jobs. At the end it writes the
  **summary table** of the children's best metrics (``sweep_summary.csv`` / ``.md``
  artifacts, and ``best/<metric>`` = the best child's), marks children left ``RUNNING``
  by a killed launch as ``KILLED``, and ends the parent.
* Each job (:func:`job_context`) is a **child run**: tag ``mlflow.parentRunId``, a name
  that says model, dataset and the job's overrides, and a checkpoint folder that is a
  function of those overrides (``<paths.models>/sweeps/<dataset>/<overrides>``), not of
  the launch time. Relaunching a killed sweep therefore finds every job's ``last.pt``:
  finished jobs train no further, interrupted ones resume (same weights as an
  uninterrupted run, same MLflow run id), and jobs that never started run afresh.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

from . import tracking
from .training.job import Job, mlflow_run_name, run_name

log = logging.getLogger(__name__)

PARENT_FILE = "mlflow_parent.json"
SWEEP_KEY_TAG = "motionsynth.sweep_key"
#: overrides that do not change a run's result (where it writes, how it logs, how many threads)
_HIDDEN = ("progress", "paths.", "tracking.", "hydra.", "hydra/", "train.threads", "optimized_metric")
#: ... plus those a child run's name and folder already say
_NOT_KEY = _HIDDEN + ("dataset", "model", "variant", "run_name", "profile", "hparams_search")


def key_overrides(overrides: Sequence[str], drop: Sequence[str] = _NOT_KEY) -> list[str]:
    """The overrides that distinguish runs of one model on one dataset (``train.lr=0.002``),
    without the ones the name already says or that do not change results."""
    out = []
    for o in overrides:
        k = o.split("=", 1)[0].lstrip("+~")
        if not any(k.startswith(n) if n[-1] in "./" else k == n for n in drop):
            out.append(o.lstrip("+"))
    return sorted(out)


def slug(overrides: Sequence[str]) -> str:
    """A folder name for a job's overrides: readable, filesystem-safe, bounded in length."""
    text = ",".join(overrides) or "default"
    safe = re.sub(r"[^\w.=,+-]", "_", text)
    if len(safe) > 80:
        safe = safe[:60] + "-" + hashlib.sha1(text.encode()).hexdigest()[:10]
    return safe


def job_context(cfg: Mapping[str, Any]) -> Job:
    """The :class:`Job` of the running Hydra job: plain runs keep the DVC-stage layout; a job
    of a multirun gets a child run under the sweep's parent and its own checkpoint folder."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized():
        return Job()
    hc = HydraConfig.get()
    task = list(hc.overrides.task)
    keys = key_overrides(task)
    if hc.mode != RunMode.MULTIRUN:
        if any(o.startswith("run_name=") for o in task):  # a DVC stage: its run name says the seed replica
            keys = key_overrides(task, _NOT_KEY + ("seed",))
        return Job(overrides=keys)
    ds, name = cfg["dataset"]["name"], run_name(dict(cfg))
    parent = read_parent(Path(hc.sweep.dir)) or {}
    return Job(out_dir=Path(cfg["paths"]["models"]) / "sweeps" / ds / name / slug(keys),
               experiment=cfg["tracking"]["sweep_experiment"], overrides=keys,
               parent_run_id=parent.get("run_id"), sweep=True, swept=list(parent.get("swept", [])))


def read_parent(sweep_dir: Path) -> dict | None:
    f = Path(sweep_dir) / PARENT_FILE
    return json.loads(f.read_text()) if f.exists() else None


# ----------------------------------------------------------------------------- the launching process
_SWEEP_FUNCS = ("range(", "choice(", "interval(", "glob(", "tag(", "shuffle(", "sort(")


def swept_keys(overrides: Sequence[str], search_space: Mapping[str, Any] | None = None) -> list[str]:
    """The keys a sweep varies: comma lists and sweep functions on the command line, plus a
    sweeper's search space (``hydra.sweeper.params``)."""
    keys = []
    for o in overrides:
        if "=" in o:
            k, v = o.split("=", 1)
            if "," in v or v.startswith(_SWEEP_FUNCS):
                keys.append(k.lstrip("+~"))
    return sorted(set(keys) | set(search_space or {}))


def sweep_key(job_name: str, overrides: Sequence[str], search_space: Any = None) -> str:
    text = json.dumps([job_name, sorted(overrides), search_space], sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


try:  # Hydra's callback base (no-op hooks); the module stays importable without Hydra
    from hydra.experimental.callback import Callback as _HydraCallback
except ImportError:  # pragma: no cover
    _HydraCallback = object


class MLflowSweepCallback(_HydraCallback):
    """Hydra callback: the MLflow parent run of a multirun (see the module docstring)."""

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
        self.parent: dict | None = None

    def _setup(self, config) -> tuple[Any, str] | None:
        from omegaconf import OmegaConf

        if not (self.enabled and config.get("tracking", {}).get("enabled", True) and tracking.is_rank_zero()):
            return None
        import mlflow

        root = str(OmegaConf.select(config, "paths.root"))
        uri = tracking.tracking_uri(root)
        mlflow.set_tracking_uri(uri)
        logging.getLogger("alembic").setLevel(logging.WARNING)
        return mlflow, uri

    def on_multirun_start(self, config, **kwargs) -> None:
        from omegaconf import OmegaConf

        from .threads import PARALLEL_JOBS_ENV

        n_jobs = OmegaConf.select(config, "hydra.launcher.n_jobs")   # joblib: jobs at once -> threads: auto
        if isinstance(n_jobs, int) and n_jobs > 1:
            os.environ[PARALLEL_JOBS_ENV] = str(n_jobs)
        env = self._setup(config)
        if env is None:
            return
        mlflow, uri = env
        from mlflow.tracking import MlflowClient

        experiment = str(OmegaConf.select(config, "tracking.sweep_experiment"))
        exp = tracking.set_experiment(mlflow, uri, experiment)
        task = list(config.hydra.overrides.task)
        space = OmegaConf.to_container(config.hydra.sweeper, resolve=False) if "sweeper" in config.hydra else None
        search = (space or {}).get("params") or {}
        key = sweep_key(config.hydra.job.name, task, search)
        client = MlflowClient(uri)
        found = client.search_runs([exp.experiment_id], f"tags.`{SWEEP_KEY_TAG}` = '{key}'", max_results=1,
                                   order_by=["attributes.start_time DESC"])
        if found:
            run_id = found[0].info.run_id
            client.update_run(run_id, status="RUNNING")
            log.info("sweep: relaunch of MLflow parent run %s (%s)", run_id, experiment)
        else:
            name = " ".join([f"sweep:{config.hydra.job.name}", *key_overrides(task, _HIDDEN), *sorted(search)])
            run = client.create_run(exp.experiment_id, run_name=name[:250],
                                    tags={SWEEP_KEY_TAG: key, "kind": "sweep", "task": config.hydra.job.name,
                                          "sweeper": str(OmegaConf.select(config, "hydra.sweeper._target_")),
                                          "launcher": str(OmegaConf.select(config, "hydra.launcher._target_"))})
            run_id = run.info.run_id
            params = {"sweep.overrides": " ".join(task)[:500]}
            params.update({f"sweep.{o.split('=', 1)[0]}": o.split("=", 1)[1][:500] for o in task if "=" in o})
            tracking.log_params_client(client, run_id, params)
            log.info("sweep: MLflow parent run %s in %s", run_id, experiment)
        self.parent = {"run_id": run_id, "experiment_id": exp.experiment_id, "experiment": experiment,
                       "tracking_uri": uri, "sweep_key": key, "swept": swept_keys(task, search)}
        sweep_dir = Path(str(config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        (sweep_dir / PARENT_FILE).write_text(json.dumps(self.parent, indent=1))

    def on_multirun_end(self, config, **kwargs) -> None:
        if self.parent is None or self._setup(config) is None:
            return
        from omegaconf import OmegaConf

        from .training.trainer import TrainConfig

        monitor = (OmegaConf.select(config, "optimized_metric") or OmegaConf.select(config, "train.monitor")
                   or OmegaConf.select(config, "model.train.monitor") or TrainConfig.monitor)
        finish_parent(self.parent, str(monitor) if monitor else None, Path(str(config.hydra.sweep.dir)))


def children(client, parent: Mapping[str, Any]) -> list:
    return client.search_runs([parent["experiment_id"]], f"tags.`mlflow.parentRunId` = '{parent['run_id']}'",
                              max_results=5000, order_by=["attributes.start_time ASC"])


def summary_rows(runs: Sequence, monitor: str | None) -> list[dict[str, Any]]:
    """One row per child: name, status, overrides and its best metrics (``best/*``)."""
    rows = []
    for r in runs:
        row = {"run": r.info.run_name, "run_id": r.info.run_id, "status": r.info.status,
               "overrides": r.data.tags.get("overrides", "")}
        row.update({k: v for k, v in sorted(r.data.metrics.items()) if k.startswith("best/")})
        rows.append(row)
    key = f"best/{monitor.split('/', 1)[-1]}" if monitor else None
    if key:
        rows.sort(key=lambda r: (r.get(key) is None, r.get(key, 0.0)))
    return rows


def finish_parent(parent: Mapping[str, Any], monitor: str | None, out_dir: Path) -> list[dict[str, Any]]:
    """Close a sweep's parent run: children still ``RUNNING`` (a killed launch) become
    ``KILLED``; the summary table goes up as artifacts; ``best/<metric>`` is the best child's."""
    import pandas as pd
    from mlflow.tracking import MlflowClient

    client = MlflowClient(parent["tracking_uri"])
    runs = children(client, parent)
    left = [r.info.run_id for r in runs if r.info.status == "RUNNING"]
    for run_id in left:
        client.set_terminated(run_id, status="KILLED")
    if left:  # read them back with their new status
        runs = children(client, parent)
    rows = summary_rows(runs, monitor)
    out_dir.mkdir(parents=True, exist_ok=True)
    df = pd.DataFrame(rows)
    csv, md = out_dir / "sweep_summary.csv", out_dir / "sweep_summary.md"
    df.to_csv(csv, index=False)
    md.write_text(_markdown(df) + "\n")
    for f in (csv, md):
        client.log_artifact(parent["run_id"], str(f))
    key = f"best/{monitor.split('/', 1)[-1]}" if monitor else None
    metrics = {"children": float(len(rows)), "children_finished": float(sum(r["status"] == "FINISHED" for r in rows))}
    if key and rows and rows[0].get(key) is not None:
        metrics[key] = float(rows[0][key])
    for k, v in metrics.items():
        client.log_metric(parent["run_id"], k, v)
    client.set_terminated(parent["run_id"], status="FINISHED")
    log.info("sweep: %d child runs summarised in MLflow parent run %s", len(rows), parent["run_id"])
    return rows


def _markdown(df) -> str:
    if df.empty:
        return "(no child runs)"
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(("" if v != v else f"{v:.5g}") if isinstance(v, float) else str(v)
                                       for v in r) + " |")
    return "\n".join(lines)

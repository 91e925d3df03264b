"""What every suite shares: the trained runs of a dataset, its test data, result rows and outputs.

Shapes: poses ``[B, T, J, D]`` (normalised, as models see them, or physical: metres for 3-D,
pixels for 2-D), roots ``[B, T, 3]`` (``x, z, heading`` for 3-D; the centre joint's image
position and depth for 2-D), controls ``[B, T, 3]``.
"""

from __future__ import annotations

import importlib
import json
import logging
import math
import re
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import pandas as pd
import torch
import yaml

from ..data.controls import to_global
from ..threads import resolve as resolve_threads
from ..training.data import WindowData, open_split
from ..training.run import load_trained

log = logging.getLogger(__name__)


@dataclass
class Row:
    """One cell of a results table. The first eight fields are those of ``published_results.csv``
    (``compare_to`` is its ``dataset``: the published setting this row is set beside), so the
    report joins ours and theirs on ``(paper, table, compare_to, metric, column, method)``."""

    paper: str                 # habibie2017_vae_lstm | battan2021_glocalnet | beyond_papers
    table: str                 # "Table 1", ...
    compare_to: str            # the published dataset string this row compares with
    metric: str
    column: str                # frame70, 80ms, MMD_avg, ...
    method: str                # ERD, VAE-LSTM, Zero-velocity, a calibration row's name ...
    condition: str = ""
    value: float = math.nan    # mean over seeds (and sequences)
    std: float = math.nan      # std over seeds (stochastic models, random draws); NaN: one seed
    n: int = 0                 # sequences / samples per seed
    seeds: int = 1
    key: str = ""              # metric name in DVC metrics and MLflow (test/<key>)
    protocol: str = "test split"
    dataset: str = ""          # ours
    run: str = ""              # models/<dataset>/<run>, or "" for references
    kind: str = "model"        # model | reference (calibration / trivial rows)
    note: str = ""


COLUMNS = [f.name for f in fields(Row)]
#: a training-seed replica's run name: ``<base run>-seed<k>``
REPLICA = re.compile(r"(?P<base>.+)-seed(?P<seed>\d+)")
NOT_SUITES = ("__init__", "context", "report", "training")  # modules of this package that are not suites


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", str(text).lower()).strip("_")


class EvalContext:
    """One dataset's evaluation: config, trained runs, cached models and data, collected results.

    ``cfg`` is the resolved Hydra config (``dataset``, ``eval``, ``paths``, ``seed``); ``runs``
    maps run names (folders under ``models/<dataset>/``) to their model names, as
    ``params.yaml: train_runs`` lists them.
    """

    def __init__(self, cfg: dict[str, Any], runs: dict[str, str]):
        self.cfg = cfg
        self.dataset_cfg = cfg["dataset"]
        self.name: str = self.dataset_cfg["name"]
        self.opts: dict[str, Any] = cfg["eval"]
        self.options: dict[str, Any] = self.dataset_cfg.get("evaluate") or {}
        self.paths = {k: Path(v) for k, v in cfg["paths"].items()}
        self.runs = dict(runs)
        self.rows: list[Row] = []
        self.curves: dict[str, list[dict]] = {}
        self.samples: dict[str, np.ndarray] = {}
        self.sample_meta: dict[str, Any] = {}
        self.timings: dict[str, float] = {}
        self._models: dict[str, Any] = {}
        self._data: dict[tuple, WindowData] = {}
        self.device = torch.device("cuda" if (self.opts.get("device") == "auto" and torch.cuda.is_available())
                                   else ("cpu" if self.opts.get("device") == "auto" else self.opts["device"]))

    # ------------------------------------------------------------------ runs and models
    def run_dir(self, run: str) -> Path:
        return self.paths["models"] / self.name / run

    def available(self, model: str | None = None, variant: str | None = "any") -> list[str]:
        """Trained runs (``best.pt`` present), optionally of one model and variant
        (``variant=None``: the plain run; ``"any"``: every variant)."""
        out = []
        for run, m in self.runs.items():
            if model is not None and m != model:
                continue
            if REPLICA.fullmatch(run):           # training-seed replicas: through replicas(), never alone
                continue
            v = run[len(m) + 1:] if run.startswith(m + "-") else None
            if variant != "any" and v != variant:
                continue
            if (self.run_dir(run) / "best.pt").exists():
                out.append(run)
            else:
                log.warning("%s: run %s is not trained (no %s); left out", self.name, run, self.run_dir(run) / "best.pt")
        return out

    def replicas(self, run: str) -> list[str]:
        """The trained training-seed replicas of ``run``: the runs ``<run>-seed<k>`` (the same model and
        config trained with ``seed=k``; ``conf/pipeline/default.yaml: train_runs``), by seed."""
        found = []
        for r in self.runs:
            m = REPLICA.fullmatch(r)
            if m and m["base"] == run and (self.run_dir(r) / "best.pt").exists():
                found.append((int(m["seed"]), r))
        return [r for _, r in sorted(found)]

    @staticmethod
    def seeds_note(runs: list[str]) -> str:
        """How a row over training seeds names them: ``runs`` = the run, then its replicas (every suite)."""
        return f"mean +- std over {len(runs)} training seeds (runs {', '.join(runs)})"

    def model(self, run: str):
        """``(model, train_windows)`` of a trained run, loaded once, in eval mode on the context's device."""
        if run not in self._models:
            model, train = load_trained(self.run_dir(run), {k: self.paths[k] for k in ("processed", "splits", "root",
                                                                                    "models")})
            self._models[run] = (model.to(self.device).eval(), train)
        return self._models[run]

    def kind(self, run: str) -> str:
        """``Row.kind`` of a run: ``"reference"`` for a trivial model that learns nothing (the class
        attribute ``reference``, e.g. zero-velocity), else ``"model"``."""
        return "reference" if getattr(type(self.model(run)[0]), "reference", False) else "model"

    def label(self, model_name: str) -> str:
        """The method's display name (``label`` in ``conf/model/<model>.yaml``, as the papers write it)."""
        for conf_dir in (self.paths["root"] / "conf", Path(__file__).resolve().parents[3] / "conf"):
            conf = conf_dir / "model" / f"{model_name}.yaml"
            if conf.exists():
                return str((yaml.safe_load(conf.read_text()) or {}).get("label", model_name))
        return model_name

    # ------------------------------------------------------------------ data
    def data(self, family: str, split: str = "test", representation: str | None = None,
             protocol: str | None = None) -> WindowData:
        """Windows of ``family`` in ``split`` (the dataset's training representation and protocol
        unless named), normalised with the protocol's train statistics; cached."""
        training = dict(self.dataset_cfg["training"])
        if representation:
            training["representation"] = representation
        if protocol:
            training["protocol"] = protocol
        key = (family, split, training["representation"], training["protocol"])
        if key not in self._data:
            self._data[key] = open_split(self.paths["processed"], self.paths["splits"], self.name, training,
                                         family, split)
        return self._data[key]

    def pick(self, data: WindowData, n: int | None, seed: int = 0) -> np.ndarray:
        """``n`` window indices spread evenly over ``data`` (all when ``n`` is None or larger)."""
        if n is None or n >= len(data):
            return np.arange(len(data))
        return np.unique(np.linspace(0, len(data) - 1, n).round().astype(int))

    def raw(self, data: WindowData, idx: np.ndarray) -> dict[str, np.ndarray]:
        """Physical-unit arrays of windows ``idx``: ``pose`` ``[B, T, J, D]`` (root-relative,
        facing-normalised for 3-D), ``root`` ``[B, T, 3]``, ``controls`` ``[B, T, 3]`` (or absent),
        ``labels`` ``[B]``."""
        from ..data.clips import gather

        w = data.windows.iloc[np.asarray(idx)]
        out = {"pose": gather(data.pose, data.offsets, data.frames, w).astype(np.float64),
               "root": gather(data.root, data.offsets, data.frames, w).astype(np.float64),
               "labels": data.labels[w["seq"].to_numpy()].astype(np.int64)}
        if data.controls is not None:
            out["controls"] = gather(data.controls, data.offsets, data.frames, w, pad_value=0.0).astype(np.float64)
        return out

    def physical(self, data: WindowData, z: torch.Tensor | np.ndarray, root: np.ndarray | None = None) -> np.ndarray:
        """Normalised poses ``[..., T, J, D]`` -> physical units (metres / pixels), float64."""
        z = z.detach().cpu().numpy() if isinstance(z, torch.Tensor) else np.asarray(z)
        return data.norm.inverse(z.astype(np.float64), root)

    @staticmethod
    def global_positions(pose: np.ndarray, root: np.ndarray) -> np.ndarray:
        """Root-relative 3-D poses ``[..., T, J, 3]`` + roots ``[..., T, 3]`` -> world positions."""
        return to_global(pose, root)

    @property
    def seeds(self) -> list[int]:
        return [int(self.cfg.get("seed", 0)) + i for i in range(int(self.opts["seeds"]))]

    def is_stochastic(self, fn, batch, windows: int) -> bool:
        """Whether ``fn(batch, seed)`` (a method's roll-out: a tensor or array) differs between two
        seeds on the first ``windows`` windows of ``batch``: measured, not declared (the cRBM samples
        its hidden units, Vae Seq2Seq its latent; the recurrent baselines are deterministic). Torch
        is seeded with each seed before its roll-out."""
        from ..models.base import Batch

        cut = lambda t: None if t is None else t[:windows]  # noqa: E731
        few = Batch(batch.pose[:windows], cut(batch.controls), cut(batch.labels), batch.every)
        a, b = [], []
        for out, s in zip((a, b), self.seeds[:2] if len(self.seeds) > 1 else (self.seeds[0], self.seeds[0] + 1)):
            self.torch_seed(s)
            z = fn(few, s)
            out.append(z.detach().cpu().numpy() if isinstance(z, torch.Tensor) else np.asarray(z))
        return not np.array_equal(a[0], b[0])

    def torch_seed(self, seed: int) -> None:
        torch.manual_seed(seed)
        np.random.seed(seed % (2 ** 32))

    # ------------------------------------------------------------------ results
    def add(self, **kw: Any) -> Row:
        """Record one result; ``key`` defaults to ``<metric>/<column>`` slugs."""
        kw.setdefault("dataset", self.name)
        row = Row(**kw)
        if not row.key:
            row.key = f"{slug(row.metric)}/{slug(row.column)}"
        if not math.isfinite(row.value):
            log.warning("%s %s %s %s: value %s", self.name, row.table, row.method, row.column, row.value)
        self.rows.append(row)
        return row

    def add_seeds(self, values: Iterable[float], **kw: Any) -> Row:
        """Record the mean and (with more than one) the std over per-seed values."""
        v = np.asarray(list(values), dtype=np.float64)
        return self.add(value=float(np.mean(v)), std=float(np.std(v, ddof=1)) if len(v) > 1 else math.nan,
                        seeds=len(v), **kw)

    def curve(self, name: str, method: str, horizons: Iterable[Any], values: Iterable[float]) -> None:
        """A ``dvc plots`` curve: ``reports/plots/<ds>/<name>.csv`` rows ``method, horizon, value``."""
        self.curves.setdefault(name, []).extend(
            {"method": method, "horizon": h, "value": float(v)} for h, v in zip(horizons, values))

    def sample(self, method: str, positions: np.ndarray, **meta: Any) -> None:
        """Positions ``[N, T, J, D]`` (physical, global where the data has a trajectory) of the fixed
        animation sequences; ``method="ground truth"`` for the reference. ``meta`` keys (one suite per
        dataset samples): ``fps``, ``parents``, ``joints`` (names), ``space`` ("3d"/"2d"), ``title``,
        ``seed_frames`` (an int, or a dict per method), optionally ``trajectory``, ``units``,
        ``sequences`` and ``start_frames``."""
        self.samples[method] = np.asarray(positions, dtype=np.float32)
        self.sample_meta.update(meta)


# ============================================================================ the stage

def evaluate(cfg: dict[str, Any], runs: dict[str, str]) -> EvalContext:
    """Run the dataset's suites and write every output (module docstring)."""
    torch.set_num_threads(resolve_threads(cfg["eval"]["threads"]))
    ctx = EvalContext(cfg, runs)
    suites = list(ctx.options.get("suites") or [])
    known = sorted(p.stem for p in Path(__file__).parent.glob("*.py") if p.stem not in NOT_SUITES)
    unknown = [s for s in suites if s not in known]
    if unknown:  # before any work
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.suites names unknown suite(s) {unknown}; "
                         f"known: {known} (modules of motionsynth.evaluation)")
    for name in suites:
        mod = importlib.import_module(f"{__package__}.{name}")
        t0 = time.perf_counter()
        log.info("%s: suite %s", ctx.name, name)
        mod.run(ctx)
        ctx.timings[name] = round(time.perf_counter() - t0, 2)
        log.info("%s: suite %s done in %.1f s", ctx.name, name, ctx.timings[name])
    write(ctx)
    return ctx


def metrics_dict(rows: list[Row]) -> dict[str, dict[str, float]]:
    """``{method: {key: value}}`` (the DVC metrics file and the MLflow runs hold the same numbers)."""
    out: dict[str, dict[str, float]] = {}
    for r in rows:
        if math.isfinite(r.value):
            out.setdefault(slug(r.method), {})[r.key] = round(float(r.value), 6)
    return out


def write(ctx: EvalContext) -> dict[str, Path]:
    reports = ctx.paths["reports"]
    eval_dir = reports / "eval" / ctx.name
    eval_dir.mkdir(parents=True, exist_ok=True)
    files = {"results": eval_dir / "results.csv", "metrics": reports / "metrics" / f"{ctx.name}.json"}
    pd.DataFrame([asdict(r) for r in ctx.rows], columns=COLUMNS).to_csv(files["results"], index=False)
    files["metrics"].parent.mkdir(parents=True, exist_ok=True)
    files["metrics"].write_text(json.dumps(metrics_dict(ctx.rows), indent=1, sort_keys=True) + "\n")
    plots = reports / "plots" / ctx.name
    plots.mkdir(parents=True, exist_ok=True)
    for name, rows in ctx.curves.items():
        files[f"plot:{name}"] = plots / f"{name}.csv"
        pd.DataFrame(rows, columns=["method", "horizon", "value"]).to_csv(files[f"plot:{name}"], index=False)
    samples = ctx.paths["samples"] / f"{ctx.name}.npz"
    samples.parent.mkdir(parents=True, exist_ok=True)
    meta = {"dataset": ctx.name, **ctx.sample_meta}
    np.savez_compressed(samples, **{f"m:{k}": v for k, v in ctx.samples.items()},
                        meta=np.array(json.dumps(meta, default=str)))
    files["samples"] = samples
    (eval_dir / "timings.json").write_text(json.dumps(ctx.timings, indent=1) + "\n")
    return files


def log_to_mlflow(ctx: EvalContext) -> list[str]:
    """One MLflow run ``evaluate:<method>`` per method in ``motionsynth/<ds>``, with the metrics of
    ``reports/metrics/<ds>.json`` as ``test/<key>``; the results table rides on every run as an artifact."""
    from .. import tracking

    by_method = metrics_dict(ctx.rows)
    runs_of = {slug(r.method): r.run for r in ctx.rows}
    table = ctx.paths["reports"] / "eval" / ctx.name / "results.csv"
    records = [{"run_name": f"evaluate:{m}",
                "metrics": {f"test/{k}": v for k, v in vals.items()},
                "params": {"dataset": ctx.name, "method": m, "run": runs_of.get(m, ""), "eval": ctx.opts},
                "tags": {"stage": "evaluate", "dataset": ctx.name, "method": m, "run": runs_of.get(m, ""),
                         "profile": str(ctx.cfg.get("profile_name"))},
                "artifacts": [table]}
               for m, vals in sorted(by_method.items())]
    experiment = f"{ctx.cfg['tracking']['experiment_prefix']}/{ctx.name}"
    return tracking.log_runs(ctx.paths["root"], experiment, records)

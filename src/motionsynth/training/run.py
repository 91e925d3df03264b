"""One training run from a resolved config: data, model, trainer, MLflow, artifacts.

Everything that can be wrong in the config (unknown model, non-positive learning
rate, a window the model cannot take) fails here, before any epoch runs.
"""

from __future__ import annotations

import json
import logging
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from .. import tracking
from ..models.base import MotionModel
from . import distributed
from .checkpoint import fingerprint
from .criteria import converged
from .data import open_split
from .job import Job, mlflow_run_name, run_name
from .trainer import TrainConfig, Trainer, seed_everything

log = logging.getLogger(__name__)


#: config sections about other stages or the stage graph, not this training run (not logged as its params)
PIPELINE_KEYS = ("eval", "report", "datasets", "evaluate", "train_runs")


def model_class(target: str) -> type[MotionModel]:
    from hydra.utils import get_class

    cls = get_class(target)
    if not (isinstance(cls, type) and issubclass(cls, MotionModel)):
        raise TypeError(f"{target} is not a MotionModel")
    return cls


def train_config(cfg: dict[str, Any]) -> TrainConfig:
    """Trainer settings, later entries winning: the model's paper defaults (``model.train``), the
    model's budget for the active profile (``model.schedule.<profile_name>``: optimiser steps,
    validation interval, warm-up and learning-rate schedule that make this model converge under
    that profile), the dataset's entry in it (``schedule.<profile_name>.datasets.<dataset>``), that
    entry's protocol variant entry (``...datasets.<dataset>.variants.<variant_name>``: one of the
    dataset's two protocols may need another budget), a profile's budget for every model
    (``profile_schedule``: the smoke profile's few steps), then
    every non-null ``train`` value (the profile's and the command line's overrides). A budget given
    as ``train.epochs`` (data passes, a validation after each) replaces any ``steps`` and ``eval_every``
    not given under ``train`` too."""
    schedule = dict((cfg["model"].get("schedule") or {}).get(cfg.get("profile_name"), {}) or {})
    per_dataset = schedule.pop("datasets", None) or {}
    ds_name = (cfg.get("dataset") or {}).get("name")
    ds_entry = dict(per_dataset.get(ds_name) or {})
    per_variant = ds_entry.pop("variants", None) or {}
    explicit = {k: v for k, v in cfg["train"].items() if v is not None}
    merged = {**cfg["model"].get("train", {}), **schedule, **ds_entry,
              **(per_variant.get(cfg.get("variant_name")) or {}),
              **(cfg.get("profile_schedule") or {}), **explicit}
    if "epochs" in explicit:            # N data passes, validated after each: the schedule's steps do not apply
        merged.update({k: None for k in ("steps", "eval_every") if k not in explicit})
    known = TrainConfig.__dataclass_fields__
    unknown = sorted(set(merged) - set(known))
    if unknown:
        raise ValueError(f"unknown train options {unknown}; known: {sorted(known)}")
    merged["seed"] = int(cfg.get("seed", 0))
    return TrainConfig(**merged).validate()


def hparams(cfg: dict[str, Any]) -> dict[str, Any]:
    """The model's constructor arguments, later entries winning: ``model.sizes.<model_size>``, the
    dataset's protocol-level ``training.model_overrides`` (H3.6M Table 3: 10 input + 50 predicted
    poses) for the model's ``overrides_as`` (a config variant of another model, e.g. GloGen's loss
    ablation, takes that model's protocol) and then for its own name, and a protocol variant's
    ``model_args`` (conf/variant/, e.g. VAE-LSTM Table 2's given controls)."""
    m, ds = cfg["model"], cfg["dataset"]
    overrides = (ds["training"].get("model_overrides") or {})
    names = [n for n in (m.get("overrides_as"), m["name"]) if n]
    return {**(m.get("sizes") or {}).get(cfg.get("model_size", "default"), {}),
            **{k: v for n in names for k, v in (overrides.get(n) or {}).items()},
            **(cfg.get("model_args") or {})}


def build(cfg: dict[str, Any]):
    """Data, model and trainer config from a resolved config dict (no training yet)."""
    ds, m = cfg["dataset"], cfg["model"]
    size = cfg.get("model_size", "default")
    if size not in m.get("sizes", {}):
        raise ValueError(f"model {m.get('name')!r} has no sizes.{size}; has {sorted(m.get('sizes', {}))}")
    cls = model_class(m["_target_"])
    args = hparams(cfg)
    try:                                  # a config the model cannot use fails here, before any data is read
        cls.check_hparams(args)
    except (ValueError, TypeError) as e:
        raise ValueError(f"model {m.get('name')!r} (conf/model/{m.get('name')}.yaml, sizes.{size}): {e}") from None
    tcfg = train_config(cfg)
    family = getattr(cls, "family", None) or ds["training"]["family"]
    paths = cfg["paths"]
    train = open_split(paths["processed"], paths["splits"], ds["name"], ds["training"], family, "train")
    val = open_split(paths["processed"], paths["splits"], ds["name"], ds["training"], family, "val")
    seed_everything(tcfg.seed)
    model = cls(train.spec, **args)
    return model, train, val, tcfg


def load_trained(run_dir: str | Path, paths: dict[str, Any] | None = None, checkpoint: str = "best.pt"):
    """A trained run's model (eval mode, ``checkpoint``'s weights) and its training windows, rebuilt
    from the run's own resolved ``config.yaml``. ``paths`` replaces entries of the stored
    ``paths`` (they may be another machine's)."""
    from .checkpoint import load

    run_dir = Path(run_dir)
    missing = [f for f in ("config.yaml", checkpoint) if not (run_dir / f).exists()]
    if missing:
        raise FileNotFoundError(f"{run_dir}: no {' or '.join(missing)} (not trained yet?)")
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    cfg["paths"] = {**cfg.get("paths", {}), **{k: str(v) for k, v in (paths or {}).items()}}
    model, train, _val, _ = build(cfg)
    model.load_state_dict(load(run_dir / checkpoint)["model"])
    return model.eval(), train


def git_commit(root: str | Path) -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def dataset_hash(root: str | Path, dataset: str, attempts: int = 10, wait_s: float = 0.1) -> str:
    """The DVC md5 of the dataset's prepared data and splits, from dvc.lock.

    Under ``make run`` another stage's DVC bookkeeping may be rewriting dvc.lock as this reads it (DVC
    truncates the file, then writes it): an empty, unparsable or cut-off read, one without the dataset's
    ``prepare`` and ``split`` entries, is read again after ``wait_s`` seconds, up to ``attempts`` times,
    and then gives ``"unknown"`` (it is an MLflow tag, never a reason to fail a training stage)."""
    lock = Path(root) / "dvc.lock"
    if not lock.exists():
        return "unknown"
    wanted = (f"prepare@{dataset}", f"split@{dataset}")
    # dvc.lock grows with every stage: libyaml's loader reads it in ~0.1 s where the pure-Python one took ~2 s
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    for attempt in range(attempts):
        if attempt:
            time.sleep(wait_s)
        try:
            data = yaml.load(lock.read_text(), Loader=loader)
        except (OSError, yaml.YAMLError):
            continue
        stages = data.get("stages") if isinstance(data, dict) else None
        if not isinstance(stages, dict) or not all(s in stages for s in wanted):
            continue
        parts = [out.get("md5", "?") for s in wanted for out in stages[s].get("outs", [])
                 if str(out.get("path", "")).startswith("data/")]
        return "+".join(parts) or "unknown"
    return "unknown"


def run(cfg: dict[str, Any], progress: bool = True, job=None) -> dict[str, Any]:
    """Train one (model, dataset) pair; returns the summary written to the metrics file.

    ``job`` (:class:`motionsynth.training.job.Job`): where a sweep's job writes and its MLflow
    parent; ``None``: the DVC stage layout, ``<paths.models>/<dataset>/<run_name>``."""
    job = job or Job()
    model, train, val, tcfg = build(cfg)
    ds, m, name = cfg["dataset"]["name"], cfg["model"]["name"], run_name(cfg)
    out = Path(job.out_dir) if job.out_dir else Path(cfg["paths"]["models"]) / ds / name
    out.mkdir(parents=True, exist_ok=True)
    main = distributed.is_main()  # under torchrun only rank 0 writes files (the trainer syncs the ranks)
    if main:
        (out / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    fp = fingerprint({k: cfg.get(k) for k in ("dataset", "model", "train", "seed", "model_size", "model_args")})
    trainer = Trainer(model, train, val, tcfg, out, fp, progress=progress)
    trainer.try_resume()
    tags = {"model": m, "dataset": ds, "stage": "train", "run": name, "variant": str(cfg.get("variant_name")),
            "git_commit": git_commit(cfg["paths"]["root"]), "dataset_hash": dataset_hash(cfg["paths"]["root"], ds),
            "profile": str(cfg.get("profile_name")), "overrides": " ".join(job.overrides), "checkpoints": str(out)}
    with tracking.resumable_run(cfg["paths"]["root"], job.experiment or f"{cfg['tracking']['experiment_prefix']}/{ds}",
                                run_name=mlflow_run_name(name, ds, job.name_overrides), run_id=trainer.run_id,
                                params={k: v for k, v in cfg.items() if k not in PIPELINE_KEYS}, tags=tags,
                                enabled=bool(cfg["tracking"].get("enabled", True)),
                                parent_run_id=job.parent_run_id) as active:
        trainer.run_id = active.info.run_id if active is not None else None

        def on_epoch(epoch: int, metrics: dict) -> None:
            tracking.log_metrics({k: v for k, v in metrics.items() if k != "epoch"}, step=epoch)

        trainer.on_epoch = on_epoch
        result = trainer.fit()
        trainable = trainer.optim is not None   # False: a reference (zero-velocity, the mean pose) learns nothing
        best = _best_row(result["history"], tcfg.monitor) if trainable else {
            k: v for k, v in _best_row(result["history"], tcfg.monitor).items() if k not in ("epoch", "step")}
        summary = {"model": m, "run": name, "variant": cfg.get("variant_name"), "dataset": ds,
                   "epochs_run": result["epochs_run"], "steps": int(result["history"][-1].get("step", 0)),
                   "budget_steps": result["total_steps"], "steps_per_pass": result["steps_per_pass"],
                   "seconds": result["seconds"], "best_epoch": best.get("epoch"), "best_step": best.get("step"),
                   "monitor": tcfg.monitor, "reference": not trainable,
                   "converged": trainer_converged(result["history"], tcfg, trainable=trainable),
                   **{k: v for k, v in best.items() if k not in ("epoch", "step")},
                   "parameters": sum(p.numel() for p in model.parameters()),
                   "train_windows": len(train), "val_windows": len(val)}
        if "val/zero_velocity_mse" in best:
            summary["beats_zero_velocity"] = bool(best["val/pred_mse"] < best["val/zero_velocity_mse"])
        if main:
            (out / "summary.json").write_text(json.dumps(summary, indent=1))
            write_curve(out / CURVE, result["history"], tcfg.monitor, name)
            png = sample_figure(model, val, out / "sample.png", seed=tcfg.seed)
            tracking.log_metrics({f"best/{k.split('/', 1)[-1]}": v for k, v in best.items() if k != "epoch"})
            for art in (out / "config.yaml", out / "best.pt", png):
                tracking.log_artifact(art)
    return summary


#: the learning curve of a run, next to its checkpoints (the train stage copies it to reports/plots/train/)
CURVE = "curve.csv"


def write_curve(path: Path, history: list[dict], monitor: str, run: str) -> Path:
    """One row per validation round: ``run, step, round, data_epoch, lr, criterion`` (the selection
    criterion ``monitor``), ``train_loss``, ``val_loss`` and every other ``val/*`` metric
    (``val/pred_mse`` -> ``val_pred_mse``): what ``dvc plots`` and the report draw."""
    import pandas as pd

    rows = []
    for h in history:
        row = {"run": run, "step": h.get("step", 0), "round": h.get("epoch", 0), "data_epoch": h.get("data_epoch", 0.0),
               "lr": h.get("lr", float("nan")), "criterion": h.get(monitor, float("nan")),
               "train_loss": h.get("train/loss", float("nan"))}
        row.update({k.replace("/", "_"): v for k, v in h.items() if k.startswith("val/")})
        rows.append(row)
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def trainer_converged(history: list[dict], tcfg: TrainConfig, trainable: bool = True) -> bool | None:
    """``converged`` of a run (:func:`~.criteria.converged` on its selection criterion); ``None`` for a
    reference with nothing to learn (zero-velocity, the mean pose: no optimiser step, so neither
    converged nor not: its summary says ``reference: true`` and has no selected step)."""
    if not trainable:
        return None
    return converged(history, tcfg.monitor, tcfg.converged_tol, tcfg.converged_tail)


def _best_row(history: list[dict], monitor: str) -> dict:
    rows = [h for h in history if monitor in h and h.get("selectable", 1)] or [h for h in history if monitor in h]
    return min(rows, key=lambda h: h[monitor]) if rows else (history[-1] if history else {})


def sample_figure(model: MotionModel, val, path: Path, seed: int) -> Path:
    """A generated validation window against the ground truth: a few pose coordinates over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .checkpoint import load

    best = load(path.parent / "best.pt")
    model.load_state_dict(best["model"])
    model.eval()
    torch.manual_seed(seed)
    batch = val.batch(np.array([0]))
    device = next(iter(model.parameters()), torch.zeros(0)).device
    batch = batch.to(device)
    with torch.no_grad():
        p = model.predict(batch)[0]
    from .trainer import target_of

    g = target_of(model, batch)[0]
    pred = p.reshape(p.shape[0], -1).cpu().numpy()
    gt = g.reshape(g.shape[0], -1).cpu().numpy()
    S = int(getattr(model, "seed_frames", 0))
    dims = np.argsort(-gt.std(0))[:4]  # the four most-moving coordinates
    fig, axes = plt.subplots(len(dims), 1, figsize=(7, 1.6 * len(dims)), sharex=True)
    for ax, d in zip(np.atleast_1d(axes), dims):
        ax.plot(gt[:, d], "k-", lw=1.2, label="ground truth")
        ax.plot(pred[:, d], "C3-", lw=1.2, label="generated")
        if S:
            ax.axvline(S - 0.5, color="gray", ls=":", lw=1)
        ax.set_ylabel(f"dim {d}", fontsize=8)
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="upper right")
    np.atleast_1d(axes)[0].set_title(f"{type(model).__name__}: validation window 0 (normalised units)", fontsize=9)
    np.atleast_1d(axes)[-1].set_xlabel("frame")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path

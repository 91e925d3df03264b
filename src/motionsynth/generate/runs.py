"""Look-ups of trained runs and their prepared data: checkpoints, configs, class names, the
training split's controls."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .config import TARGETS, GenerateError


# ============================================================================ data look-ups

@dataclass
class RunInfo:
    """A trained run: its folder, resolved training config and checkpoint."""

    name: str
    dir: Path
    cfg: dict
    ckpt: Path


def _train_stage(params_file: Path, dataset: str, run: str, model: str) -> str:
    try:
        import yaml

        runs = yaml.safe_load(params_file.read_text()).get("train_runs") or {}
        for key, r in runs.items():
            if r.get("dataset") == dataset and r.get("name") == run:
                return f"`dvc repro train@{key}`"
    except (OSError, ValueError, AttributeError):
        pass
    return (f"`python pipelines/train.py dataset={dataset} model={model} run_name={run}` (no train stage in "
            f"params.yaml names it)")


def _find_run(cfg: dict, dataset: str, run: str, kind: str) -> RunInfo:
    import yaml

    d = Path(cfg["models_dir"]) / dataset / run
    ckpt, conf = d / "best.pt", d / "config.yaml"
    if not ckpt.exists() or not conf.exists():
        stage = _train_stage(Path(cfg["params_file"]), dataset, run, kind)
        state = "is still training or stopped early" if (d / "last.pt").exists() else "has not been trained"
        raise GenerateError(f"no trained {kind} model at {ckpt} (it {state}); {stage} produces it. "
                            f"Models are looked up in models_dir={cfg['models_dir']}")
    rcfg = yaml.safe_load(conf.read_text())
    target = (rcfg.get("model") or {}).get("_target_")
    if target != TARGETS[kind]:
        raise GenerateError(f"{d} holds a {str(target).rsplit('.', 1)[-1]} model, not a {TARGETS[kind].rsplit('.', 1)[-1]}")
    return RunInfo(run, d, rcfg, ckpt)


def _run_cfg_with_paths(info: RunInfo, cfg: dict) -> dict:
    """The run's training config pointed at this command's data folders (the stored paths may
    be another machine's)."""
    rc = json.loads(json.dumps(info.cfg))
    rc["paths"] = {**(rc.get("paths") or {}), "processed": cfg["processed_dir"], "splits": cfg["splits_dir"],
                   "root": cfg["root"], "models": cfg["models_dir"]}
    return rc


def _hparams(rc: dict) -> dict:
    """The model's constructor arguments as :func:`motionsynth.training.run.build` merges them."""
    from ..training.run import hparams

    return hparams(rc)


@dataclass
class DataInfo:
    rep_dir: Path
    split_dir: Path
    protocol: str
    fps: float
    meta: Any            # pandas DataFrame: the representation's sequences
    split: Any           # pandas Series sequence_id -> split
    skeleton: Any        # motionsynth.data.types.Skeleton


def _data(cfg: dict, info: RunInfo) -> DataInfo:
    import pandas as pd

    from ..data.types import Skeleton

    ds = info.cfg["dataset"]
    rep, proto = ds["training"]["representation"], ds["training"]["protocol"]
    rep_dir = Path(cfg["processed_dir"]) / ds["name"] / rep
    split_dir = Path(cfg["splits_dir"]) / ds["name"] / rep
    need = [rep_dir / "representation.json", rep_dir / "meta.parquet", rep_dir / "skeleton.json",
            split_dir / f"{proto}.csv", split_dir / f"{proto}_stats.npz"]
    missing = [p for p in need if not p.exists()]
    if missing:
        raise GenerateError(f"the prepared data of {ds['name']} is missing ({missing[0]}); `dvc repro split@{ds['name']}` "
                            f"produces it (generation needs its skeleton, class names and normalisation statistics)")
    repr_ = json.loads((rep_dir / "representation.json").read_text())
    if repr_.get("space") != "3d":
        raise GenerateError(f"{info.dir} was trained on the {repr_.get('space')} representation {rep!r}; "
                            f"generate writes 3-D motion only")
    meta = pd.read_parquet(rep_dir / "meta.parquet")
    split = pd.read_csv(split_dir / f"{proto}.csv").set_index("sequence_id")["split"]
    return DataInfo(rep_dir, split_dir, proto, float(repr_["fps"]), meta, split, Skeleton.load(rep_dir / "skeleton.json"))


def _train_controls(data: DataInfo, label: int | None = None) -> np.ndarray:
    """Control signals ``[N, 3]`` of the training split's frames (of one class)."""
    c = np.load(data.rep_dir / "controls.npy", mmap_mode="r")
    m = data.meta
    keep = m["sequence_id"].map(data.split).to_numpy() == "train"
    if label is not None:
        keep &= m["label"].to_numpy() == label
    rows = [np.arange(o, o + f) for o, f in zip(m["offset"].to_numpy()[keep], m["frames"].to_numpy()[keep])]
    if not rows:
        return np.zeros((0, 3))
    return np.asarray(c[np.concatenate(rows)], dtype=np.float64)


def class_names(data: DataInfo) -> dict[str, int]:
    """Class name -> label of the classes with training sequences, in label order."""
    m = data.meta
    if "label_name" not in m.columns or "label" not in m.columns:
        return {}
    train = m[m["sequence_id"].map(data.split).to_numpy() == "train"]
    pairs = train[["label", "label_name"]].drop_duplicates().sort_values("label")
    return {str(n): int(lab) for lab, n in zip(pairs["label"], pairs["label_name"]) if str(n) and int(lab) >= 0}



def _load(info: RunInfo, cfg: dict):
    from ..training.run import load_trained

    return load_trained(info.dir, _run_cfg_with_paths(info, cfg)["paths"])

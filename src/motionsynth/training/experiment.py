"""The DVC experiment slot: ``dvc exp run -S model=<name> [-S train.epochs=5 ...]``.

With ``hydra.enabled`` DVC composes params.yaml from conf/ plus the ``-S`` overrides
(:mod:`motionsynth.params`). The ``experiment`` stage then trains that composed model
(params.yaml's ``model``, ``model_size``, ``train``, ``seed``, ``model_args``) on each dataset
``train_runs`` pairs the model with (variant ``none``), or on ``exp_datasets``, into
``<paths.models>/experiment/<dataset>/<model>/``, and writes one metrics file that
``dvc exp show`` / ``dvc metrics diff`` compare. ``model: null`` (plain ``dvc repro``):
nothing to train, an empty record.

The runs land in the repository's MLflow store (also from a queued experiment's temporary
workspace: :func:`motionsynth.tracking.tracking_uri`), named
``train:<model>@<dataset> exp=<DVC experiment name>``.
"""

from __future__ import annotations

import copy
import logging
import os
from pathlib import Path
from typing import Any, Mapping

from omegaconf import OmegaConf

from .job import Job
from .run import run

log = logging.getLogger(__name__)

#: the summary fields the experiment's metrics file keeps per dataset
KEEP = ("epochs_run", "best_epoch", "beats_zero_velocity")


def datasets_for(params: Mapping[str, Any]) -> list[str]:
    model = params.get("model") or {}
    if not model:
        return []
    if params.get("exp_datasets"):
        return list(params["exp_datasets"])
    found = sorted({r["dataset"] for r in (params.get("train_runs") or {}).values()
                    if r["model"] == model["name"] and r.get("variant", "none") == "none"})
    if not found:
        raise ValueError(f"model {model['name']!r} is paired with no dataset in train_runs (conf/pipeline/); "
                         "set exp_datasets=[...]")
    return found


def run_configs(params: Mapping[str, Any], conf_dir: str | Path) -> list[dict[str, Any]]:
    """One resolved training config per dataset: params.yaml with ``dataset`` replaced by that
    dataset's own config (conf/dataset/<ds>.yaml)."""
    out = []
    for ds in datasets_for(params):
        f = Path(conf_dir) / "dataset" / f"{ds}.yaml"
        if not f.exists():
            raise FileNotFoundError(f"exp_datasets: no dataset config {f}")
        cfg = copy.deepcopy(dict(params))
        cfg["dataset"] = OmegaConf.to_container(OmegaConf.load(f), resolve=True)
        cfg["run_name"] = params["model"]["name"]
        out.append(cfg)
    return out


def run_experiment(params: Mapping[str, Any], conf_dir: str | Path, progress: bool = True) -> dict[str, Any]:
    """Train the experiment's model on its datasets; returns the metrics record."""
    exp_name = os.environ.get("DVC_EXP_NAME", "")
    record: dict[str, Any] = {"model": (params.get("model") or {}).get("name")}
    (Path(params["paths"]["models"]) / "experiment").mkdir(parents=True, exist_ok=True)  # the stage's out, even empty
    for cfg in run_configs(params, conf_dir):
        ds, m = cfg["dataset"]["name"], cfg["model"]["name"]
        job = Job(out_dir=Path(cfg["paths"]["models"]) / "experiment" / ds / m,
                  overrides=[f"exp={exp_name}"] if exp_name else [])
        log.info("experiment: %s on %s", m, ds)
        s = run(cfg, progress=progress, job=job)
        record[ds] = {**{k: v for k, v in s.items() if k.startswith("val/")}, **{k: s.get(k) for k in KEEP}}
    if record["model"] is None:
        log.info("experiment: no model chosen (dvc exp run -S model=<name>): nothing to train")
    return record

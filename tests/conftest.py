"""Shared fixtures: real archives located through their committed .dvc pointers."""

from __future__ import annotations

import io
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
STORE = REPO.parent / "shared" / "dvc-store" / "files" / "md5"
sys.path.insert(0, str(REPO / "src"))


def archive_path(name: str) -> Path:
    """The real archive ``name`` (e.g. ``bandai1``): data/raw/ if pulled, else the team's DVC store."""
    local = REPO / "data" / "raw" / f"{name}.zip"
    if local.exists():
        return local
    md5 = yaml.safe_load((REPO / "data" / "raw" / f"{name}.zip.dvc").read_text())["outs"][0]["md5"]
    path = STORE / md5[:2] / md5[2:]
    if not path.exists():
        raise FileNotFoundError(f"archive {name} is neither in data/raw nor in {STORE} (run `dvc pull`)")
    return path


def dataset_cfg(name: str) -> dict:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "dataset" / f"{name}.yaml"), resolve=True)


def make_zip(path: Path, members: dict[str, bytes | str]) -> Path:
    """Write a zip archive with the given members (names are written verbatim, hostile ones included)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(zipfile.ZipInfo(name), data.encode() if isinstance(data, str) else data)
    path.write_bytes(buf.getvalue())
    return path


@pytest.fixture
def repo() -> Path:
    return REPO


@pytest.fixture(scope="module")
def one_thread():
    """Small models: one thread is several times faster than two, and immune to a busy second core."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def overfit(model, batch, steps: int = 200, lr: float = 3e-3) -> tuple[float, float]:
    """Train ``model`` on one batch with Adam; return (first loss, last loss)."""
    import torch

    opt = torch.optim.Adam(model.parameters(), lr=lr)
    first = last = None
    for _ in range(steps):
        loss, _ = model.loss(batch)
        first = loss.item() if first is None else first
        last = loss.item()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return first, last


def synthetic(spec, B: int = 3, T: int = 30, seed: int = 0):
    """A ``Batch`` of random tensors of the right shapes for ``spec`` (shape, gradient and determinism
    checks only: the learning tests use real data)."""
    import torch

    from motionsynth.models.base import Batch

    g = torch.Generator().manual_seed(seed)
    return Batch(torch.randn(B, T, spec.joints, spec.dims, generator=g),
                 torch.randn(B, T, 3, generator=g) if spec.controls else None,
                 torch.randint(0, spec.num_classes, (B,), generator=g) if spec.num_classes else None)


def train_steps(model, batch, opt, steps: int) -> list[tuple[float, dict]]:
    """``steps`` optimiser steps of ``model.loss`` on one batch (train mode): each step's loss and logs."""
    model.train()
    out = []
    for _ in range(steps):
        opt.zero_grad()
        loss, logs = model.loss(batch)
        loss.backward()
        opt.step()
        out.append((loss.item(), logs))
    return out


def compose_cfg(root: Path, dataset: str, *overrides: str) -> dict:
    """The pipeline's resolved Hydra config for ``dataset`` under project root ``root`` (smoke profile,
    MLflow off unless overridden)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.root={root}", f"dataset={dataset}", "profile=smoke",
                                           "tracking.enabled=false", *overrides])
    return OmegaConf.to_container(cfg, resolve=True)


def build_eval_root(root: Path, dataset: str, runs: dict[str, tuple[str, str]], max_items: int = 16,
                    epochs: int = 1, batches: int = 2) -> dict[str, str]:
    """A project root for evaluation tests: ``max_items`` real items of ``dataset`` ingested, prepared
    and split into ``root/data``, and each run ``name -> (model, variant)`` trained for ``epochs`` rounds x
    ``batches`` at the smoke sizes into ``root/models/<dataset>/<name>``. Returns ``{name: model}``
    (what ``params.yaml: train_runs`` gives the evaluate stage)."""
    from motionsynth.data.ingest import ingest
    from motionsynth.data.prepare import prepare
    from motionsynth.data.splits import split_dataset
    from motionsynth.training.run import run

    cfg = dataset_cfg(dataset)
    if not (root / "data/splits" / dataset).exists():
        ingest(cfg, archive_path(dataset), root / "data/interim" / dataset, max_items=max_items, progress=False)
        prepare(root / "data/interim" / dataset, root / "data/processed" / dataset, cfg["prepare"]["representations"])
        split_dataset(root / "data/processed" / dataset, root / "data/splits" / dataset, cfg["split"], seed=0)
    for name, (model, variant) in runs.items():
        if not (root / "models" / dataset / name / "best.pt").exists():
            run(compose_cfg(root, dataset, f"model={model}", f"variant={variant}", f"run_name={name}",
                            f"train.steps={epochs * batches}", f"train.eval_every={batches}"), progress=False)
    return {name: model for name, (model, _) in runs.items()}

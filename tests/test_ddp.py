"""Multi-process (DDP) training through torchrun, on the CPU (gloo), on real prepared windows.

Two ranks with per-rank batch 4 must follow the trajectory of one process with batch 8 on the
same windows and seed: a deterministic model (LSTM-3LR at the smoke size: teacher forcing, no
noise, no dropout, no sampling), compared step by step and by the final weights. The job is
crashed on rank 0 after epoch 1 and relaunched, so the trajectory also goes through a resume
under DDP. 19 training windows (18 real items of bandai2_locomotion) make every epoch end on
a short batch on rank 0 and an idle rank 1, the two cases of the per-rank loss weighting.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth.training import distributed
from motionsynth.training.checkpoint import load
from motionsynth.training.run import build
from motionsynth.training.trainer import Trainer

DS = "bandai2_locomotion"
EPOCHS, CRASH_AFTER = 4, 1
RTOL = 1e-4


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """A project root with 18 real items of bandai2_locomotion ingested, prepared and split."""
    r = tmp_path_factory.mktemp("ddp_root")
    build_eval_root(r, DS, {}, max_items=18)
    return r


def config(root: Path, batch_size: int) -> dict:
    return compose_cfg(root, DS, "model=lstm3lr", f"train.batch_size={batch_size}", f"train.epochs={EPOCHS}",
                       "+model_args.train_window=null",      # no random crops: the same windows in both runs "train.patience=100", "train.threads=1",
                       "train.device=cpu")


@pytest.fixture(scope="module")
def single(root, tmp_path_factory, one_thread) -> dict:
    """One process, batch 8: per-step losses, history and final weights."""
    out = tmp_path_factory.mktemp("single")
    model, train, val, tcfg = build(config(root, 8))
    n = len(train)
    assert n % 8 in (1, 2, 3), f"{n} windows: the last global step must be short on rank 0 and empty on rank 1"
    steps: list[list] = []
    trainer = Trainer(model, train, val, tcfg, out, "ddp-test", progress=False,
                      on_step=lambda e, s, loss: steps.append([e, s, loss]))
    assert not trainer.distributed and trainer.world == 1 and trainer.ddp is None
    result = trainer.fit()
    return {"steps": steps, "history": result["history"], "weights": load(out / "last.pt")["model"],
            "windows": n}


def torchrun(spec: dict, path: Path, cwd: Path) -> tuple[subprocess.CompletedProcess, float]:
    """Launch ``tests/_ddp_worker.py`` on 2 CPU ranks (gloo), one thread each."""
    path.write_text(json.dumps(spec))
    env = {k: v for k, v in os.environ.items()
           if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")}
    env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PROGRESS="0")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "--monitor-interval=0.1", str(REPO / "tests" / "_ddp_worker.py"), str(path)]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=180)
    return r, time.perf_counter() - t0


@pytest.fixture(scope="module")
def ddp(root, tmp_path_factory) -> dict:
    """Two ranks, batch 4 each: crashed on rank 0 after epoch 1 (each rank writing to its own
    folder), then relaunched on rank 0's folder, where it resumes and finishes."""
    tmp = tmp_path_factory.mktemp("ddp")
    cwd = tmp / "cwd"
    cwd.mkdir()
    spec = {"cfg": config(root, 4), "steps": str(tmp / "steps.jsonl"), "result": str(tmp / "result.json")}
    crashed, t_crash = torchrun({**spec, "out": str(tmp / "out" / "rank{rank}"), "crash_after_epoch": CRASH_AFTER},
                                tmp / "spec_crash.json", cwd)
    after_crash = sorted(p.relative_to(tmp / "out").as_posix() for p in (tmp / "out").rglob("*"))
    last_after_crash = load(tmp / "out" / "rank0" / "last.pt")
    resumed, t_resume = torchrun({**spec, "out": str(tmp / "out" / "rank0")}, tmp / "spec_resume.json", cwd)
    assert resumed.returncode == 0, resumed.stdout[-3000:] + resumed.stderr[-5000:]
    print(f"\ntorchrun: crashed run {t_crash:.1f} s, resumed run {t_resume:.1f} s")
    return {"tmp": tmp, "cwd": cwd, "crashed": crashed, "resumed": resumed, "after_crash": after_crash,
            "last_after_crash": last_after_crash,
            "steps": [json.loads(line) for line in (tmp / "steps.jsonl").read_text().splitlines()],
            "result": json.loads((tmp / "result.json").read_text()),
            "weights": load(tmp / "out" / "rank0" / "last.pt")["model"]}


def rel_diff(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12)))


def test_two_ranks_follow_one_process_with_the_global_batch(single, ddp):
    assert ddp["result"]["distributed"] and ddp["result"]["world"] == 2
    steps_per_epoch = -(-single["windows"] // 8)
    # [round, global step]: train.epochs=N gives N rounds of one data pass each
    assert [s[:2] for s in single["steps"]] == [[e, e * steps_per_epoch + i] for e in range(EPOCHS)
                                                 for i in range(steps_per_epoch)]
    # rank 0 died in the epoch hook, which runs before last.pt is written: the resumed run redoes
    # that epoch, with the same losses (deterministic); after that every step once
    by_step: dict = {}
    for s in ddp["steps"]:
        if tuple(s[:2]) in by_step:
            assert s[2] == pytest.approx(by_step[tuple(s[:2])][2], rel=1e-6)
        by_step[tuple(s[:2])] = s
    steps = [by_step[k] for k in sorted(by_step)]
    assert len(ddp["steps"]) - len(steps) == steps_per_epoch  # exactly one epoch redone
    assert [s[:2] for s in steps] == [s[:2] for s in single["steps"]]
    assert {s[3] for s in ddp["steps"]} == {0}  # the logging hook runs on rank 0 only
    loss_1, loss_2 = [s[2] for s in single["steps"]], [s[2] for s in steps]
    d_loss = rel_diff(loss_2, loss_1)
    w1, w2 = single["weights"], ddp["weights"]
    assert w1.keys() == w2.keys()
    d_w = max(float((w2[k] - w1[k]).abs().max()) for k in w1)
    print(f"\nper-step loss: max relative difference {d_loss:.2e} over {len(loss_1)} steps; "
          f"weights: max absolute difference {d_w:.2e}")
    np.testing.assert_allclose(loss_2, loss_1, rtol=RTOL)
    for k in w1:
        torch.testing.assert_close(w2[k], w1[k], rtol=RTOL, atol=1e-5, msg=lambda m, k=k: f"{k}: {m}")
    assert loss_1[-1] < loss_1[0]  # it learnt something: the comparison is not between two idle runs
    # the epoch metrics: train/* all-reduced over ranks, validation identical on both ranks
    h1, h2 = single["history"], ddp["result"]["history"]
    assert [h.keys() for h in h2] == [h.keys() for h in h1]
    for a, b in zip(h1, h2):
        np.testing.assert_allclose([b[k] for k in a], [a[k] for k in a], rtol=RTOL)


def test_only_rank_zero_writes_and_the_crash_resumes_on_every_rank(ddp):
    crashed = ddp["crashed"]
    # rank 0 died (its exit code 3) in epoch 1's hook, before that epoch's last.pt, and took the job down
    assert crashed.returncode != 0 and re.search(r"exitcode\s*:\s*3\b", crashed.stderr), crashed.stderr[-3000:]
    # rank 1 had its own output folder during the crashed run: it wrote nothing there
    assert ddp["after_crash"] == ["rank0", "rank0/best.pt", "rank0/last.pt"]
    assert ddp["last_after_crash"]["epoch"] == CRASH_AFTER - 1  # the epoch hook runs before last.pt is written
    assert sorted(p.name for p in (ddp["tmp"] / "out").iterdir()) == ["rank0"]
    assert sorted(p.name for p in (ddp["tmp"] / "out" / "rank0").iterdir()) == ["best.pt", "last.pt"]
    assert list(ddp["cwd"].iterdir()) == []  # no stray files from either rank
    # both ranks resumed from rank 0's last.pt (a rank starting afresh would deadlock the all-reduce
    # or train epoch 0 again; the steps file shows epoch 1 redone, then epochs 2-3 once each)
    assert ddp["result"]["resumed"]
    history = ddp["result"]["history"]
    assert [h["epoch"] for h in history] == list(range(EPOCHS))
    assert history[:CRASH_AFTER] == ddp["last_after_crash"]["history"]
    assert load(ddp["tmp"] / "out" / "rank0" / "last.pt")["done"]


def test_single_process_is_untouched(monkeypatch):
    for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK"):
        monkeypatch.delenv(k, raising=False)
    assert not distributed.launched() and not distributed.init("cpu")
    assert (distributed.rank(), distributed.world(), distributed.local_rank(), distributed.is_main()) == (0, 1, 0, True)
    distributed.barrier()
    distributed.cleanup()
    monkeypatch.setenv("WORLD_SIZE", "1")  # torchrun --nproc_per_node=1: one process, no group
    monkeypatch.setenv("RANK", "0")
    monkeypatch.setenv("LOCAL_RANK", "0")
    assert not distributed.launched() and not distributed.init("cpu") and not distributed.initialized()
    monkeypatch.setenv("WORLD_SIZE", "2")
    assert distributed.launched() and distributed.backend_for("cpu") == "gloo"
    assert distributed.backend_for("cuda") == "nccl" and distributed.device_for("cuda") == torch.device("cuda", 0)


@pytest.mark.parametrize("rank,added", [(None, False), ("0", False), ("1", True)])
def test_rank_zero_hydra_argv(monkeypatch, rank, added):
    sys.path.insert(0, str(REPO / "pipelines"))
    from _common import rank_zero_hydra_argv

    if rank is None:
        monkeypatch.delenv("RANK", raising=False)
    else:
        monkeypatch.setenv("RANK", rank)
    argv = ["train.py", "dataset=bandai1", "model=erd"]
    monkeypatch.setattr(sys, "argv", list(argv))
    rank_zero_hydra_argv()
    rank_zero_hydra_argv()  # idempotent
    extra = ["hydra.output_subdir=null", "hydra/job_logging=stdout", "hydra.run.dir=."]
    assert sys.argv == argv + (extra if added else [])

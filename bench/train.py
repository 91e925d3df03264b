"""Training throughput per model (samples/s at the default sizes, 2 threads), with the GFLOP/s
achieved against a plain fp32 matmul on the same threads; plus acLSTM at the paper size.

Usage: python bench/train.py [--models vae_lstm,glogen,...] [--steps 5]
       python bench/train.py --paper     # s/step of every (model, dataset) at the paper size + profile=paper's wall time
Prints one JSON line per figure. Real data: a few items of each dataset, prepared in a temp dir.
"""

from __future__ import annotations

import argparse
import tempfile

import torch
from _flops import matmul_gflops, step_flops
from _util import ROOT, emit, median_time
from omegaconf import OmegaConf

from motionsynth.training.data import real_batch
from motionsynth.training.run import model_class, train_config
from motionsynth.training.trainer import make_optimizer, player_optimizers

DATASET_FOR = {"vae_lstm": "bandai2_locomotion", "glocal": "h36m"}
#: sequences/s of the acLSTM authors' code at the paper size on this machine (issue 3)
REFERENCE_ACLSTM = 6.2


class Step:
    """One optimiser step: ``model.loss`` and one optimiser, or an adversarial model's whole step (every
    player's update, as the trainer runs it; ``optim`` is then the dict of the players' optimisers)."""

    def __init__(self, model, batch, optim):
        self.model, self.batch, self.optim = model, batch, optim

    def update(self, player, loss):
        opt = self.optim[player]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    def __call__(self):
        if getattr(self.model, "adversarial", False):
            self.model.adversarial_step(self.batch, self.update)
            return
        loss, _ = self.model.loss(self.batch)
        self.optim.zero_grad(set_to_none=True)
        loss.backward()
        self.optim.step()


def dataset_cfg(name: str) -> dict:
    return OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "dataset" / f"{name}.yaml"), resolve=True)


def bench_model(name: str, size: str, tmp: str, steps: int, threads: int, peaks: dict, window: int | None = None,
                dataset: str | None = None, batch_size: int | None = None, label: str | None = None) -> float | None:
    mcfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "model" / f"{name}.yaml"), resolve=True)
    cls = model_class(mcfg["_target_"])
    family = getattr(cls, "family", None)
    if family is None:  # a model that takes any window family: the dataset's own (as training does)
        family = dataset_cfg(dataset)["training"]["family"] if dataset else "vae_lstm"
    dataset = dataset or DATASET_FOR[family]
    bs = batch_size or int(mcfg.get("train", {}).get("batch_size", 32))
    batch, spec = real_batch(dataset, family, bs, f"{tmp}/{dataset}-{window}", max_items=40, length=window)
    if batch.size < bs:  # repeat real windows up to the batch size
        reps = -(-bs // batch.size)
        batch.pose = batch.pose.repeat(reps, 1, 1, 1)[:bs]
        batch.controls = batch.controls.repeat(reps, 1, 1)[:bs] if batch.controls is not None else None
        batch.labels = batch.labels.repeat(reps)[:bs] if batch.labels is not None else None
    torch.manual_seed(0)
    over = (dataset_cfg(dataset)["training"].get("model_overrides") or {}).get(name, {})   # as training builds it
    model = cls(spec, **{**mcfg["sizes"][size], **over})
    tcfg = train_config({"model": mcfg, "train": {}, "seed": 0})
    optim = player_optimizers(model, tcfg) if getattr(model, "adversarial", False) else make_optimizer(model, tcfg)
    if optim is None:
        return None
    if hasattr(model, "pretrain_steps"):      # SkeletonGAN's family: time the sequence stage (its costly one)
        model.set_progress(model.pretrain_steps, model.pretrain_steps + 1)
    model.train()
    step = Step(model, batch, optim)
    dt = median_time(step, repeats=steps, warmup=2)
    flops = step_flops(step)
    gf = flops / dt / 1e9
    emit(f"train_{label or name}", batch.size / dt, "samples/s", None, dataset=dataset, size=size,
         batch=batch.size, frames=int(batch.pose.shape[1]), step_s=round(dt, 4), gflop_per_step=round(flops / 1e9, 3),
         gflops=round(gf, 2), **{f"fraction_of_{k}": round(gf / v, 3) for k, v in peaks.items()}, threads=threads)
    return batch.size / dt


def paper_estimate(tmp: str, steps: int, threads: int, peaks: dict) -> None:
    """Seconds per optimiser step of every model at the paper size, on each dataset the pipeline trains
    it on (its window family there), and the wall time of ``profile=paper`` they imply: every
    ``train_runs`` pair's ``schedule.paper`` budget (steps, or epochs x steps per pass) x its step time."""
    import math

    import yaml

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    per_step: dict[tuple[str, str], float] = {}
    total, lines = 0.0, []
    for key, r in params["train_runs"].items():
        m, ds = r["model"], r["dataset"]
        mcfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "model" / f"{m}.yaml"), resolve=True)
        sched = dict((mcfg.get("schedule") or {}).get("paper") or {})
        sched.update((sched.pop("datasets", None) or {}).get(ds, {}))
        budget = sched.get("steps", (mcfg.get("train") or {}).get("steps"))
        if budget == 0 or m in ("zero_velocity", "mean_pose"):
            continue
        if (m, ds) not in per_step:
            rate = bench_model(m, "paper", tmp, steps, threads, peaks, dataset=ds, label=f"{m}_paper@{ds}")
            bs = int(sched.get("batch_size", (mcfg.get("train") or {}).get("batch_size", 32)))
            per_step[(m, ds)] = bs / rate if rate else 0.0
        if budget is None:                    # epochs x steps per pass over the dataset's train windows
            n = _train_windows(ds, mcfg)
            bs = int(sched.get("batch_size", (mcfg.get("train") or {}).get("batch_size", 32)))
            budget = int(sched.get("epochs", 20)) * math.ceil(n / bs)
        sec = budget * per_step[(m, ds)]
        total += sec
        lines.append({"stage": key, "steps": int(budget), "step_s": round(per_step[(m, ds)], 4), "hours": round(sec / 3600, 2)})
    emit("paper_profile_estimate", total / 3600, "hours", None, threads=threads, stages=lines,
         note="sum over train_runs of schedule.paper steps x measured seconds per step at the paper size on this "
              "machine; validation and start-up not included")


def _train_windows(ds: str, mcfg: dict) -> int:
    from motionsynth.training.data import open_split

    dcfg = dataset_cfg(ds)
    family = model_class(mcfg["_target_"]).family or dcfg["training"]["family"]
    return len(open_split(ROOT / "data/processed", ROOT / "data/splits", ds, dcfg["training"], family, "train"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", default=",".join(sorted(p.stem for p in (ROOT / "conf/model").glob("*.yaml"))))
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-paper-aclstm", action="store_true")
    ap.add_argument("--paper", action="store_true", help="seconds per step of every model at the paper size, and "
                    "the estimated wall time of profile=paper (needs the prepared data of `make run`)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    peaks = {"matmul_mkl": matmul_gflops(args.threads), "matmul_onednn": matmul_gflops(args.threads, onednn=True)}
    for k, v in peaks.items():
        emit(f"{k}_fp32_4096", v, "GFLOP/s", None, threads=args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        if args.paper:
            paper_estimate(tmp, args.steps, args.threads, peaks)
            return
        for name in args.models.split(","):
            bench_model(name, "default", tmp, args.steps, args.threads, peaks)
        if not args.skip_paper_aclstm:
            # acLSTM at the paper size: 3x1024 LSTM, batch 32 x 100 frames, 57 joints (CMU)
            rate = bench_model("aclstm", "paper", tmp, max(3, args.steps // 2), args.threads, peaks, window=100,
                               dataset="cmu_aclstm", batch_size=32, label="aclstm_paper")
            emit("train_aclstm_paper_vs_reference", rate / REFERENCE_ACLSTM, "x", 1.5,
                 note=f"the reference implementation trains at {REFERENCE_ACLSTM} sequences/s on this machine")


if __name__ == "__main__":
    main()

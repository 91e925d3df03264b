"""The one trainer every model uses.

* Deterministic: seeds Python, numpy and torch, and the batch order is a
  function of ``(seed, epoch)`` only (:meth:`WindowData.iterate`). A rerun on
  the CPU gives bitwise-equal weights and metrics.
* Crash-safe: ``last.pt`` (model, optimiser, epoch, history, RNG state, best
  score, MLflow run id) is written atomically every ``checkpoint_every`` epochs.
  Rerunning after a ``kill -9`` resumes from it and ends with the same weights
  as an uninterrupted run. ``best.pt`` holds the best weights by ``monitor``.
* Early stopping on the monitored validation metric, with ``patience`` epochs.
* Common validation metrics for every model, so that runs compare:
  ``val/loss`` (the model's own objective), ``val/pred_mse`` (MSE of
  ``model.predict`` on the frames after its seed, in normalised units) and
  ``val/zero_velocity_mse`` (the same frames predicted by repeating the last
  seed frame).
* Multi-process data parallel (DDP) under ``torchrun`` (:mod:`.distributed`; a single
  process runs exactly the code it ran before), e.g.
  ``torchrun --standalone --nproc_per_node=2 pipelines/train.py dataset=... model=...``:

  - the model is wrapped in ``torch.nn.parallel.DistributedDataParallel`` (through
    :class:`_LossForward`, whose ``forward`` is ``model.loss``, so DDP's reducer is
    prepared by the call that builds the graph); DDP broadcasts rank 0's initial weights
    and averages the gradients over ranks in every backward. ``find_unused_parameters``
    is off (it costs a graph traversal per step, and every model's loss uses all its
    parameters); a model whose loss leaves parameters out on some steps sets the class
    attribute ``ddp_find_unused_parameters = True`` (without it DDP stops with an error
    naming the parameters, it does not hang).
  - ``train.batch_size`` is the batch of ONE process: the global batch of an optimiser step
    is ``world x batch_size``. Rank ``r`` takes every ``world``-th batch of the
    ``(seed, epoch)`` permutation (:meth:`WindowData.iterate` with ``rank``/``world``,
    ``torch.utils.data.DistributedSampler`` semantics; the epoch is passed, as
    ``DistributedSampler.set_epoch`` would be, so the shuffle differs per epoch). Global
    step ``k`` therefore covers exactly the windows one process with batch
    ``world x batch_size`` sees at its step ``k``, and ``max_batches_per_epoch`` counts
    these global steps. Each rank's loss is weighted by ``world x (its windows) / (the
    step's windows)`` before the backward, so DDP's gradient average is the gradient of
    the mean over the step's windows also when the last batches are short; a rank whose
    shard has run out on the last step runs its previous batch with weight 0, so every rank
    joins every gradient all-reduce (instead of ``DistributedSampler``'s padding with
    repeated windows). Exact for a loss that is a mean over the batch's windows (a
    per-window term averaged over the batch); otherwise the usual DDP approximation.
  - ``train/*`` metrics are means over the windows of all ranks (all-reduce of sums and
    counts). Validation: every rank evaluates the same full validation set with the same
    (all-reduced, hence identical) weights, so the metrics, the best epoch, patience and
    early stopping agree on every rank without any communication.
  - the torch RNG is reseeded at the start of every epoch from ``(seed, epoch, rank)``: ranks
    draw different noise (dropout, sampling) for their different windows, and a resumed run
    draws what an uninterrupted one would.
  - only rank 0 writes ``best.pt`` / ``last.pt``, calls ``on_epoch`` / ``on_step`` (the
    logging hooks) and shows progress; a barrier after each epoch's writes keeps the other
    ranks from running ahead (into the next epoch, a resume or the end of the run) before
    the checkpoint is on disk. :meth:`Trainer.try_resume` reads ``last.pt`` on every rank
    (the output folder must be one all ranks see: always so on one node).
"""

from __future__ import annotations

import logging
import math
import random
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from ..models.base import Batch, MotionModel
from . import checkpoint as ckpt
from . import distributed
from .data import WindowData

log = logging.getLogger(__name__)


@dataclass
class TrainConfig:
    epochs: int = 20
    batch_size: int = 32          # per process: under torchrun the global batch is world x batch_size
    optimizer: str = "adam"
    lr: float = 1e-3
    weight_decay: float = 0.0
    momentum: float = 0.9         # SGD only
    grad_clip: float | None = 1.0
    patience: int = 5
    min_delta: float = 0.0
    monitor: str = "val/pred_mse"
    checkpoint_every: int = 1
    max_batches_per_epoch: int | None = None  # optimiser steps (global batches) per epoch
    val_windows: int | None = None    # validate on N evenly spaced windows (None: all): the same ones for every model
    eval_batch_size: int = 64
    seed: int = 0
    threads: int = 2
    device: str = "auto"

    def validate(self) -> "TrainConfig":
        """Reject garbage before any work starts."""
        problems = []
        if not isinstance(self.epochs, int) or self.epochs < 0:
            problems.append(f"train.epochs must be a non-negative integer, got {self.epochs!r}")
        if not isinstance(self.batch_size, int) or self.batch_size <= 0:
            problems.append(f"train.batch_size must be a positive integer, got {self.batch_size!r}")
        if not (isinstance(self.lr, (int, float)) and self.lr > 0 and math.isfinite(self.lr)):
            problems.append(f"train.lr must be a positive number, got {self.lr!r}")
        if self.optimizer not in ("adam", "adamw", "sgd"):
            problems.append(f"train.optimizer must be adam, adamw or sgd, got {self.optimizer!r}")
        if not (isinstance(self.momentum, (int, float)) and 0 <= self.momentum < 1):
            problems.append(f"train.momentum must lie in [0, 1), got {self.momentum!r}")
        if self.weight_decay < 0:
            problems.append(f"train.weight_decay must be >= 0, got {self.weight_decay!r}")
        for name in ("val_windows",):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, int) or v < 1):
                problems.append(f"train.{name} must be a positive integer or null, got {v!r}")
        if not isinstance(self.eval_batch_size, int) or self.eval_batch_size < 1:
            problems.append(f"train.eval_batch_size must be a positive integer, got {self.eval_batch_size!r}")
        if self.checkpoint_every < 1 or self.patience < 1:
            problems.append("train.checkpoint_every and train.patience must be >= 1")
        if self.device not in ("auto", "cpu", "cuda") and not str(self.device).startswith("cuda:"):
            problems.append(f"train.device must be auto, cpu or cuda[:N], got {self.device!r}")
        if self.threads < 1:
            problems.append(f"train.threads must be >= 1, got {self.threads!r}")
        if problems:
            raise ValueError("invalid training config: " + "; ".join(problems))
        return self


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def resolve_device(name: str, threads: int) -> torch.device:
    torch.set_num_threads(threads)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def make_optimizer(model: torch.nn.Module, cfg: TrainConfig) -> torch.optim.Optimizer | None:
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        return None
    if cfg.optimizer == "adamw":
        return torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(params, lr=cfg.lr, weight_decay=cfg.weight_decay, momentum=cfg.momentum)
    return torch.optim.Adam(params, lr=cfg.lr, weight_decay=cfg.weight_decay)


def target_of(model: MotionModel, batch: Batch) -> torch.Tensor:
    """What ``model.predict(batch)`` is compared with (sparse poses for GloGen)."""
    return model.target(batch) if hasattr(model, "target") else batch.pose


class _LossForward(torch.nn.Module):
    """``forward(batch) = model.loss(batch)``: what ``DistributedDataParallel`` wraps (models
    train through :meth:`MotionModel.loss`, not ``forward``), so that DDP prepares its reducer
    in the same call that builds the graph. Holds no parameters of its own: checkpoints keep
    saving ``model.state_dict()`` with its usual keys."""

    def __init__(self, model: MotionModel):
        super().__init__()
        self.model = model

    def forward(self, batch: Batch) -> tuple[torch.Tensor, dict[str, float]]:
        return self.model.loss(batch)


class Trainer:
    """Fits ``model`` on ``train_data``, validating on ``val_data`` after every epoch.

    ``on_epoch(epoch, metrics)`` is called after every epoch and ``on_step(epoch, step,
    loss)`` after every optimiser step (``loss``: the step's mean over all its windows;
    under DDP one extra scalar all-reduce per step while it is set). Both are logging hooks:
    under DDP they run on rank 0 only. See the module docstring for DDP.
    """

    def __init__(self, model: MotionModel, train_data: WindowData, val_data: WindowData, cfg: TrainConfig,
                 out_dir: str | Path, fingerprint: str, on_epoch: Callable[[int, dict], None] | None = None,
                 progress: bool = True, on_step: Callable[[int, int, float], None] | None = None):
        self.model, self.train_data, self.val_data = model, train_data, val_data
        self.cfg, self.out = cfg.validate(), Path(out_dir)
        self.fingerprint, self.on_epoch, self.on_step = fingerprint, on_epoch, on_step
        self.device = resolve_device(cfg.device, cfg.threads)
        self.distributed = distributed.init(self.device)  # False (and nothing done) outside torchrun
        if self.distributed:
            self.device = distributed.device_for(self.device)
        self.rank, self.world = distributed.rank(), distributed.world()
        self.is_main = self.rank == 0
        self.progress = progress and self.is_main
        self.model.to(self.device)
        self.optim = make_optimizer(model, cfg)
        self.ddp: torch.nn.parallel.DistributedDataParallel | None = None
        if self.distributed and self.optim is not None:  # nothing to synchronise without trainable parameters
            self.ddp = torch.nn.parallel.DistributedDataParallel(
                _LossForward(model), device_ids=[self.device.index] if self.device.type == "cuda" else None,
                find_unused_parameters=bool(getattr(model, "ddp_find_unused_parameters", False)))
        self.start_epoch, self.best, self.bad_epochs = 0, math.inf, 0
        self.history: list[dict[str, float]] = []
        self.run_id: str | None = None
        self.done = False  # finished (all epochs, or stopped early): a rerun trains no further

    # ------------------------------------------------------------------ state
    def state(self, epoch: int) -> dict[str, Any]:
        return {"model": self.model.state_dict(), "optim": self.optim.state_dict() if self.optim else {},
                "epoch": epoch, "best": self.best, "bad_epochs": self.bad_epochs, "history": self.history,
                "rng": torch.get_rng_state(), "fingerprint": self.fingerprint, "run_id": self.run_id or "",
                "done": bool(self.done)}

    def try_resume(self) -> bool:
        """Resume from ``last.pt`` when it exists and was written under the same config."""
        last = self.out / "last.pt"
        if not last.exists():
            return False
        st = ckpt.load(last, self.device)
        if st.get("fingerprint") != self.fingerprint:
            log.warning("%s was written under another config; starting afresh", last)
            return False
        self.model.load_state_dict(st["model"])
        if self.optim and st["optim"]:
            self.optim.load_state_dict(st["optim"])
        self.start_epoch, self.best, self.bad_epochs = int(st["epoch"]) + 1, float(st["best"]), int(st["bad_epochs"])
        self.history = list(st["history"])
        torch.set_rng_state(st["rng"])
        self.run_id = st.get("run_id") or None
        self.done = bool(st.get("done", False))
        log.info("resumed from %s at epoch %d", last, self.start_epoch)
        return True

    def _save(self, epoch: int, name: str) -> None:
        """Write checkpoint ``name`` atomically: on rank 0 only (every rank holds the same state)."""
        if self.is_main:
            ckpt.save_atomic(self.state(epoch), self.out / name)

    # ------------------------------------------------------------------ loops
    def _set_epoch(self, epoch: int) -> None:
        if hasattr(self.model, "set_epoch"):
            self.model.set_epoch(epoch)

    def train_epoch(self, epoch: int) -> dict[str, float]:
        """One epoch: ``ceil(windows / (world x batch_size))`` optimiser steps (at most
        ``max_batches_per_epoch``); returns the ``train/*`` means over all ranks' windows."""
        if self.distributed:
            return self._train_epoch_ddp(epoch)
        self.model.train()
        self._set_epoch(epoch)
        total, n, terms = 0.0, 0, {}
        n_batches = math.ceil(len(self.train_data) / self.cfg.batch_size)
        if self.cfg.max_batches_per_epoch:
            n_batches = min(n_batches, self.cfg.max_batches_per_epoch)
        it = self.train_data.iterate(self.cfg.batch_size, shuffle=True, seed=self.cfg.seed, epoch=epoch)
        bar = tqdm(total=n_batches, desc=f"epoch {epoch}", disable=not self.progress, leave=False)
        for i, batch in enumerate(it):
            if i >= n_batches:
                break
            batch = batch.to(self.device)
            loss, logs = self.model.loss(batch)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"non-finite training loss at epoch {epoch}, batch {i}: {logs}")
            if self.optim is not None:
                self.optim.zero_grad(set_to_none=True)
                loss.backward()
                if self.cfg.grad_clip:
                    torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.grad_clip)
                self.optim.step()
            total += float(loss.detach()) * batch.size
            n += batch.size
            for k, v in logs.items():
                terms[k] = terms.get(k, 0.0) + float(v) * batch.size
            if self.on_step:
                self.on_step(epoch, i, float(loss.detach()))
            bar.update(1)
            bar.set_postfix(loss=f"{float(loss.detach()):.4f}")
        bar.close()
        out = {"train/loss": total / max(n, 1)}
        out.update({f"train/{k}": v / max(n, 1) for k, v in terms.items()})
        return out

    def _rank_seed(self, epoch: int) -> int:
        """The torch seed of this rank's training draws in ``epoch`` (DDP)."""
        return int(np.random.SeedSequence([self.cfg.seed, epoch, self.rank]).generate_state(1)[0])

    def _train_epoch_ddp(self, epoch: int) -> dict[str, float]:
        """:meth:`train_epoch` on rank ``self.rank`` of ``self.world`` (see the module docstring).

        Batch ``j`` of the epoch's permutation (``batch_size`` windows, the last one shorter)
        is rank ``j % world``'s batch of global step ``j // world``; the table of windows per
        (step, rank) follows from the window count alone, so weighting needs no communication.
        """
        import torch.distributed as dist

        self.model.train()
        self._set_epoch(epoch)
        torch.manual_seed(self._rank_seed(epoch))
        bs, world, n_windows = self.cfg.batch_size, self.world, len(self.train_data)
        n_steps = math.ceil(n_windows / (bs * world))
        if self.cfg.max_batches_per_epoch:
            n_steps = min(n_steps, self.cfg.max_batches_per_epoch)
        first = (np.arange(n_steps)[:, None] * world + np.arange(world)[None, :]) * bs   # [steps, world]
        sizes = np.clip(n_windows - first, 0, bs)                                          # [steps, world] windows
        it = self.train_data.iterate(bs, shuffle=True, seed=self.cfg.seed, epoch=epoch, rank=self.rank, world=world)
        total, n, terms = 0.0, 0, {}
        previous: Batch | None = None
        bar = tqdm(total=n_steps, desc=f"epoch {epoch}", disable=not self.progress, leave=False)
        for i in range(n_steps):
            mine, step_windows = int(sizes[i, self.rank]), int(sizes[i].sum())
            batch = next(it) if mine > 0 else None
            if batch is None:  # this rank's shard has run out on the last step: join the all-reduce with weight 0
                batch = previous if previous is not None else self.train_data.batch(np.arange(min(bs, n_windows)))
            batch = batch.to(self.device)
            previous = batch
            loss, logs = self.ddp(batch) if self.ddp is not None else self.model.loss(batch)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"non-finite training loss at epoch {epoch}, batch {i} "
                                         f"(rank {self.rank}): {logs}")
            if self.optim is not None:
                self.optim.zero_grad(set_to_none=True)
                # DDP averages over ranks: this weight turns the average into the step's window mean
                (loss * (mine * world / step_windows)).backward()
                if self.cfg.grad_clip:
                    torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.grad_clip)
                self.optim.step()
            value = float(loss.detach())
            if mine > 0:
                total += value * mine
                n += mine
                for k, v in logs.items():
                    terms[k] = terms.get(k, 0.0) + float(v) * mine
            if self.on_step:
                step = torch.tensor([value * mine], dtype=torch.float64, device=self.device)
                dist.all_reduce(step)
                if self.is_main:
                    self.on_step(epoch, i, float(step) / step_windows)
            bar.update(1)
            bar.set_postfix(loss=f"{value:.4f}")
        bar.close()
        # means over all ranks' windows; the union of the log keys, in one order on every rank
        keys: list[list[str]] = [[] for _ in range(world)]
        dist.all_gather_object(keys, sorted(terms))
        names = sorted(set().union(*keys))
        sums = torch.tensor([total, n, *(terms.get(k, 0.0) for k in names)], dtype=torch.float64, device=self.device)
        dist.all_reduce(sums)
        sums = sums.tolist()
        count = max(sums[1], 1)
        out = {"train/loss": sums[0] / count}
        out.update({f"train/{k}": v / count for k, v in zip(names, sums[2:])})
        return out

    @torch.no_grad()
    def evaluate(self, data: WindowData, prefix: str = "val") -> dict[str, float]:
        """The model's loss, its prediction MSE after its seed frames, and zero-velocity's on the same frames."""
        self.model.eval()
        S = int(getattr(self.model, "seed_frames", 0))
        sums = {"loss": 0.0, "pred_mse": 0.0, "zero_velocity_mse": 0.0}
        n = 0
        g = torch.get_rng_state()
        torch.manual_seed(self.cfg.seed + 1)  # sampling models: the same draws at every evaluation
        if self.cfg.val_windows and self.cfg.val_windows < len(data):
            # evenly spaced windows: the same ones for every model of a dataset, spread over its sequences
            idx = np.linspace(0, len(data) - 1, self.cfg.val_windows).round().astype(np.int64)
            batches = (data.batch(idx[i:i + self.cfg.eval_batch_size])
                       for i in range(0, len(idx), self.cfg.eval_batch_size))
        else:
            batches = data.iterate(self.cfg.eval_batch_size, shuffle=False, seed=0)
        for batch in batches:
            batch = batch.to(self.device)
            loss, _ = self.model.loss(batch)
            pred, tgt = self.model.predict(batch), target_of(self.model, batch)
            sums["loss"] += float(loss.detach()) * batch.size
            sums["pred_mse"] += float(((pred[:, S:] - tgt[:, S:]) ** 2).mean()) * batch.size
            if S > 0:
                zv = tgt[:, S - 1:S].expand_as(tgt[:, S:])
                sums["zero_velocity_mse"] += float(((zv - tgt[:, S:]) ** 2).mean()) * batch.size
            n += batch.size
        torch.set_rng_state(g)
        out = {f"{prefix}/{k}": v / max(n, 1) for k, v in sums.items() if not (k == "zero_velocity_mse" and S == 0)}
        return out

    def fit(self) -> dict[str, Any]:
        t0 = time.perf_counter()
        if len(self.train_data) == 0 or len(self.val_data) == 0:
            raise ValueError(f"empty data: {len(self.train_data)} train and {len(self.val_data)} val windows")
        epochs = self.cfg.epochs if self.optim is not None and not self.done else 0
        if epochs == 0 and not self.history:  # nothing to learn (zero-velocity): evaluate once
            metrics = {"epoch": 0, **self.evaluate(self.val_data)}
            self.history.append(metrics)
            self.best = metrics.get(self.cfg.monitor, math.inf)
            self.done = True
            self._save(0, "best.pt")
            self._save(0, "last.pt")
            distributed.barrier()
            if self.on_epoch and self.is_main:
                self.on_epoch(0, metrics)
        for epoch in range(self.start_epoch, epochs):
            metrics = {"epoch": epoch, **self.train_epoch(epoch), **self.evaluate(self.val_data)}
            self.history.append(metrics)
            score = metrics.get(self.cfg.monitor, math.inf)
            improved = score < self.best - self.cfg.min_delta
            if improved:
                self.best, self.bad_epochs = score, 0
                self._save(epoch, "best.pt")
            else:
                self.bad_epochs += 1
            stop = self.bad_epochs >= self.cfg.patience
            self.done = stop or epoch == epochs - 1
            # log before last.pt: a kill between the two redoes (and re-logs) this epoch on resume,
            # rather than resuming after an epoch whose metrics never reached MLflow
            if self.on_epoch and self.is_main:
                self.on_epoch(epoch, metrics)
            if (epoch + 1) % self.cfg.checkpoint_every == 0 or self.done:
                self._save(epoch, "last.pt")
            distributed.barrier()  # DDP: rank 0's checkpoints are on disk before any rank goes on
            if self.is_main:
                log.info("epoch %d: %s", epoch, ", ".join(f"{k}={v:.5f}" for k, v in metrics.items() if k != "epoch"))
            if stop:  # the same decision on every rank: identical validation (module docstring)
                if self.is_main:
                    log.info("early stop at epoch %d (%s has not improved for %d epochs)", epoch,
                             self.cfg.monitor, self.cfg.patience)
                break
        return {"history": self.history, "best": self.best, "epochs_run": len(self.history),
                "seconds": time.perf_counter() - t0, "config": asdict(self.cfg)}

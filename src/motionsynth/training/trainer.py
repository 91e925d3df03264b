"""The one trainer every model uses.

* Budgets in optimiser steps: ``train.steps`` (else ``train.epochs`` passes over the data), with a
  linear warm-up (``warmup_steps``) and a constant or cosine learning rate (``lr_schedule``,
  ``min_lr_ratio``); :func:`lr_factor`. The model's config gives its budget per profile (and per
  dataset), ``conf/model/<name>.yaml: schedule``.
* Validation every ``eval_every`` steps (a *round*; the history's ``epoch`` counts rounds, ``step``
  the optimiser steps, ``data_epoch`` the passes over the data). Early stopping after ``patience``
  rounds without improvement of ``monitor``; ``best.pt`` holds the weights of the best round.
* A model whose ``selectable`` is false after a round (SkeletonGAN in its pose stage, whose sequence
  generator is not trained yet) has that round logged with ``selectable: 0``: it is neither a
  candidate for ``best.pt`` nor counted by patience or ``converged``.
* Selection: ``monitor`` is a criterion a constant (mean) pose cannot win, by default ``val/rel_zv``
  (:mod:`.criteria`: per-horizon MSE relative to zero-velocity, weighted ``1/h``); models without
  seed frames or with their own objective set theirs (LocGen: the error of its in-betweens; VAE-LSTM:
  its negative ELBO). ``val/pred_mse`` (the long roll-out error) and ``val/zero_velocity_mse`` are
  logged beside it. ``converged`` (:func:`.criteria.converged`) is computed by the caller from the
  history.
* Deterministic: seeds Python, numpy and torch; the batches of step ``g`` are a function of
  ``(seed, g)`` only (:meth:`Trainer.train_round`) and torch is reseeded from ``(seed, round,
  rank)`` at every round. A rerun on the CPU gives bitwise-equal weights and metrics.
* Crash-safe: ``last.pt`` (model, optimiser, round, history, RNG state, best score, MLflow run id)
  is written atomically every ``checkpoint_every`` rounds. Rerunning after a ``kill -9`` resumes
  from it and ends with the same weights as an uninterrupted run.
* A model that has ``fit_statistics(train)`` gets it on the train split before the first step of a
  fresh run (the mean pose, the cRBM's whitened conditioning) and, when it trains, after every round,
  before validation and the checkpoints, so the statistics in ``best.pt`` are those of its own weights
  (VAE-LSTM's aggregate-posterior prior). It uses no RNG. Models with nothing to learn (zero-velocity,
  the mean pose: ``reference = True``) are then evaluated once.
* Weight average (``average_decay``, off by default; ours, no paper of the project uses one): the
  trainer keeps an exponential moving average of the trainable weights, updated after every optimiser
  step (:meth:`Trainer._update_average`), and validates, selects and writes to ``best.pt`` the average,
  not the last step's weights (Polyak averaging; what the GANs' generator average does for their
  generator, :mod:`motionsynth.models.adversarial`). Training itself runs on the trained weights, so the
  optimiser's path is that of a run without it; ``last.pt`` holds both, and a resumed run goes on
  bit for bit.
* Progress hooks: the model's ``set_epoch(round)`` and ``set_progress(step, total_steps)`` (noise
  curricula, scheduled sampling, KL warm-up) are called before every step.
* Adversarial models (``model.adversarial``: the GAN family, :mod:`motionsynth.models.adversarial`) train
  with one optimiser per player (``model.players()``: generator, discriminator(s)); the model runs its
  own algorithm in ``model.adversarial_step(batch, update)`` (which losses, how many discriminator
  updates per generator update) and calls ``update(player, loss)``, which checks the loss, back-
  propagates it, clips and steps that player's optimiser at the step's learning rate (``lr``, or
  ``player_lr[player]`` where given, times the schedule's factor; ``betas`` for Adam). After each step the
  model folds its generator into its weight average, if it keeps one (``update_average``). Selection is the model's own
  ``validate(data, ...)`` (an MMD on the validation split: GANs have no validation loss).
  Divergence stops the run (:class:`TrainingDiverged`): a non-finite loss of any player, or a
  discriminator logit beyond ``max_logit`` (``logit_absmax`` in the step's logs). Nothing of the
  diverged round is written: ``last.pt`` and ``best.pt`` keep the last good round, and no metrics
  file is written. Everything else (budgets, schedules, atomic checkpoints, resume, determinism,
  ``weights_only`` loads, per-round MLflow metrics) is the same code as for every model; DDP is
  refused for them (one clear error).
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
    is ``world x batch_size``. Rank ``r`` takes every ``world``-th batch of the data pass's
    ``(seed, pass)`` permutation (``torch.utils.data.DistributedSampler`` semantics with
    ``set_epoch(pass)``). Global step ``k`` therefore covers exactly the windows one process
    with batch ``world x batch_size`` sees at its step ``k``, and ``steps`` / ``eval_every``
    count these global steps. Each rank's loss is weighted by ``world x (its windows) / (the
    step's windows)`` before the backward, so DDP's gradient average is the gradient of
    the mean over the step's windows also when the last batches are short; a rank whose
    shard has run out on the last step runs its previous batch with weight 0, so every rank
    joins every gradient all-reduce (instead of ``DistributedSampler``'s padding with
    repeated windows). Exact for a loss that is a mean over the batch's windows (a
    per-window term averaged over the batch); otherwise the usual DDP approximation.
  - ``train/*`` metrics are means over the windows of all ranks (all-reduce of sums and
    counts). Validation: every rank evaluates the same full validation set with the same
    (all-reduced, hence identical) weights, so the metrics, the best round, patience and
    early stopping agree on every rank without any communication.
  - the torch RNG is reseeded at the start of every round from ``(seed, round, rank)``: ranks
    draw different noise (dropout, sampling) for their different windows, and a resumed run
    draws what an uninterrupted one would.
  - only rank 0 writes ``best.pt`` / ``last.pt``, calls ``on_epoch`` / ``on_step`` (the
    logging hooks) and shows progress; a barrier after each round's writes keeps the other
    ranks from running ahead (into the next round, a resume or the end of the run) before
    the checkpoint is on disk. :meth:`Trainer.try_resume` reads ``last.pt`` on every rank
    (the output folder must be one all ranks see: always so on one node).
"""

from __future__ import annotations

import contextlib
import logging
import math
import random
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch
from tqdm.auto import tqdm

from ..models.base import Batch, MotionModel, average_beta
from ..threads import check as threads_check
from ..threads import resolve as resolve_threads
from . import checkpoint as ckpt
from . import distributed
from .criteria import horizon_weighted_ratio
from .data import WindowData

log = logging.getLogger(__name__)


@dataclass
class TrainConfig:
    steps: int | None = None      # optimiser-step budget (global steps); None: epochs x steps per data pass
    epochs: int = 20              # data passes: the budget when `steps` is None
    eval_every: int | None = None  # optimiser steps between validations (a round); None: one data pass
    batch_size: int = 32          # per process: under torchrun the global batch is world x batch_size
    optimizer: str = "adam"
    lr: float = 1e-3
    lr_schedule: str = "constant"  # constant | cosine (after the warm-up)
    warmup_steps: int = 0         # linear warm-up from lr / warmup_steps to lr
    min_lr_ratio: float = 0.0     # cosine: the final lr as a fraction of lr
    weight_decay: float = 0.0
    momentum: float = 0.9         # SGD only
    grad_clip: float | None = 1.0
    betas: list[float] | None = None  # Adam / AdamW (beta1, beta2); None: torch's (0.9, 0.999)
    player_lr: dict[str, float] | None = None   # adversarial models: learning rate per player (others: lr)
    max_logit: float = 1.0e4      # adversarial models: a discriminator logit beyond this magnitude is divergence
    average_decay: float = 0.0    # > 0: validate, select and keep an exponential moving average of the weights
    patience: int = 5             # validation rounds without improvement before stopping
    min_delta: float = 0.0
    monitor: str = "val/rel_zv"   # selection criterion (motionsynth.training.criteria)
    converged_tol: float = 0.01   # `converged`: improved by < this (relative) ...
    converged_tail: float = 0.2   # ... over this last fraction of the steps
    checkpoint_every: int = 1     # rounds between atomic last.pt writes
    val_windows: int | None = None    # validate on N evenly spaced windows (None: all): the same ones for every model
    eval_batch_size: int = 64
    seed: int = 0
    threads: int | str = "auto"   # CPU threads: "auto" = the cores this process may use / parallel jobs (threads.py)
    device: str = "auto"

    def validate(self) -> "TrainConfig":
        """Reject garbage before any work starts."""
        problems = []

        def count(name: str, v, minimum: int, optional: bool = False) -> None:
            if optional and v is None:
                return
            if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
                problems.append(f"train.{name} must be an integer >= {minimum}{' or null' if optional else ''}, "
                                f"got {v!r}")

        count("steps", self.steps, 0, optional=True)
        count("epochs", self.epochs, 0)
        count("eval_every", self.eval_every, 1, optional=True)
        count("warmup_steps", self.warmup_steps, 0)
        if not isinstance(self.batch_size, int) or self.batch_size <= 0:
            problems.append(f"train.batch_size must be a positive integer, got {self.batch_size!r}")
        if not (isinstance(self.lr, (int, float)) and self.lr > 0 and math.isfinite(self.lr)):
            problems.append(f"train.lr must be a positive number, got {self.lr!r}")
        if self.optimizer not in ("adam", "adamw", "sgd"):
            problems.append(f"train.optimizer must be adam, adamw or sgd, got {self.optimizer!r}")
        if self.lr_schedule not in LR_SCHEDULES:
            problems.append(f"train.lr_schedule must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}")
        if not (isinstance(self.min_lr_ratio, (int, float)) and 0 <= self.min_lr_ratio <= 1):
            problems.append(f"train.min_lr_ratio must lie in [0, 1], got {self.min_lr_ratio!r}")
        if not (isinstance(self.momentum, (int, float)) and 0 <= self.momentum < 1):
            problems.append(f"train.momentum must lie in [0, 1), got {self.momentum!r}")
        if self.weight_decay < 0:
            problems.append(f"train.weight_decay must be >= 0, got {self.weight_decay!r}")
        if self.betas is not None and not (
                isinstance(self.betas, (list, tuple)) and len(self.betas) == 2
                and all(isinstance(b, (int, float)) and not isinstance(b, bool) and 0 <= b < 1 for b in self.betas)):
            problems.append(f"train.betas must be two numbers in [0, 1) or null, got {self.betas!r}")
        if self.player_lr is not None and not (isinstance(self.player_lr, dict) and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 and math.isfinite(v)
                for v in self.player_lr.values())):
            problems.append(f"train.player_lr must map player names to positive numbers, or be null; "
                            f"got {self.player_lr!r}")
        if isinstance(self.average_decay, bool) or not (isinstance(self.average_decay, (int, float))
                                                        and 0 <= self.average_decay < 1):
            problems.append(f"train.average_decay must be a number in [0, 1), got {self.average_decay!r}")
        if not (isinstance(self.max_logit, (int, float)) and self.max_logit > 0):
            problems.append(f"train.max_logit must be a positive number, got {self.max_logit!r}")
        if not (isinstance(self.converged_tol, (int, float)) and self.converged_tol > 0):
            problems.append(f"train.converged_tol must be > 0, got {self.converged_tol!r}")
        if not (isinstance(self.converged_tail, (int, float)) and 0 < self.converged_tail < 1):
            problems.append(f"train.converged_tail must lie in (0, 1), got {self.converged_tail!r}")
        if not (isinstance(self.monitor, str) and self.monitor.startswith("val/")):
            problems.append(f"train.monitor must name a validation metric (val/...), got {self.monitor!r}")
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
        bad_threads = threads_check(self.threads, "train.threads")
        if bad_threads:
            problems.append(bad_threads)
        if problems:
            raise ValueError("invalid training config: " + "; ".join(problems))
        return self


LR_SCHEDULES = ("constant", "cosine")


def lr_factor(step: int, total: int, cfg: TrainConfig) -> float:
    """The learning rate of optimiser step ``step`` (0-based) as a fraction of ``cfg.lr``: a linear
    warm-up over ``warmup_steps`` (``(step + 1) / warmup_steps``), then constant, or a cosine from 1
    down to ``min_lr_ratio`` at step ``total``."""
    w = cfg.warmup_steps
    if step < w:
        return (step + 1) / w
    if cfg.lr_schedule == "constant" or total <= w:
        return 1.0
    frac = min(max((step - w) / max(total - w, 1), 0.0), 1.0)
    return cfg.min_lr_ratio + (1.0 - cfg.min_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * frac))


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def resolve_device(name: str, threads: int | str) -> torch.device:
    torch.set_num_threads(resolve_threads(threads))
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def make_optimizer(model: torch.nn.Module, cfg: TrainConfig) -> torch.optim.Optimizer | None:
    """The optimiser of ``cfg``; ``None`` for a model with nothing to learn (no trainable parameter, or a
    ``reference`` model such as zero-velocity or the mean pose: the trainer then evaluates it once)."""
    params = [p for p in model.parameters() if p.requires_grad]
    if not params or getattr(model, "reference", False):
        return None
    return optimizer_for(params, cfg, cfg.lr)


def optimizer_for(params: list[torch.nn.Parameter], cfg: TrainConfig, lr: float) -> torch.optim.Optimizer:
    """``cfg.optimizer`` over ``params`` at learning rate ``lr`` (Adam / AdamW with ``cfg.betas`` when set)."""
    betas = {"betas": tuple(cfg.betas)} if cfg.betas is not None else {}
    if cfg.optimizer == "adamw":
        return torch.optim.AdamW(params, lr=lr, weight_decay=cfg.weight_decay, **betas)
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(params, lr=lr, weight_decay=cfg.weight_decay, momentum=cfg.momentum)
    return torch.optim.Adam(params, lr=lr, weight_decay=cfg.weight_decay, **betas)


class TrainingDiverged(FloatingPointError):
    """Training stopped on divergence (a non-finite loss, an exploding discriminator logit). The
    checkpoints on disk are those of the last good round; nothing of the diverged round was written."""


def kept(round_: int) -> str:
    """What a run that diverged in ``round_`` leaves on disk (the end of :class:`TrainingDiverged`'s message)."""
    return ("training stopped before its first checkpoint" if round_ == 0 else
            f"training stopped; the checkpoints of round {round_ - 1} (the last good one) are kept")


def player_optimizers(model: MotionModel, cfg: TrainConfig) -> dict[str, torch.optim.Optimizer]:
    """One optimiser per player of an adversarial model (``model.players()``: name -> parameters; each at
    :func:`player_lr`). Each trainable parameter belongs to exactly one player, or the model is refused."""
    players = model.players()
    if "generator" not in players:
        raise ValueError(f"{type(model).__name__}.players() has no 'generator'; it has {sorted(players)}")
    unknown = sorted(set(cfg.player_lr or {}) - set(players))
    if unknown:
        raise ValueError(f"train.player_lr names {unknown}, not players of {type(model).__name__} ({sorted(players)})")
    seen: dict[int, str] = {}
    for name, ps in players.items():
        for p in ps:
            if id(p) in seen:
                raise ValueError(f"{type(model).__name__}: a parameter belongs to both {seen[id(p)]} and {name}")
            seen[id(p)] = name
    left = [n for n, p in model.named_parameters() if p.requires_grad and id(p) not in seen]
    if left:
        raise ValueError(f"{type(model).__name__}: parameters of no player: {left[:5]}")
    return {name: optimizer_for(list(ps), cfg, player_lr(cfg, name)) for name, ps in players.items()}


def player_lr(cfg: TrainConfig, player: str) -> float:
    """The base learning rate of an adversarial model's ``player``: ``player_lr[player]``, else ``lr``."""
    return float((cfg.player_lr or {}).get(player, cfg.lr))


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
        self.adversarial = bool(getattr(model, "adversarial", False))
        if self.adversarial:
            if self.distributed:
                raise ValueError(f"{type(model).__name__} is adversarial: training it under torchrun (DDP) is not "
                                 "supported; run it as one process")
            self.optims = player_optimizers(model, cfg)
            self.optim = self.optims["generator"]
        else:
            self.optim = make_optimizer(model, cfg)
            self.optims = {"model": self.optim} if self.optim is not None else {}
        # the weight average (train.average_decay): a copy of the trainable parameters, no gradients
        self.average: list[torch.Tensor] | None = None
        self.average_updates = 0
        if cfg.average_decay and self.optim is not None:
            if self.adversarial:
                raise ValueError(f"train.average_decay: {type(model).__name__} is adversarial; a GAN keeps the "
                                 "average of its generator alone (the model's average_decay)")
            self.average = [p.detach().clone() for p in self._trainable()]
        self.ddp: torch.nn.parallel.DistributedDataParallel | None = None
        if self.distributed and self.optim is not None:  # nothing to synchronise without trainable parameters
            self.ddp = torch.nn.parallel.DistributedDataParallel(
                _LossForward(model), device_ids=[self.device.index] if self.device.type == "cuda" else None,
                find_unused_parameters=bool(getattr(model, "ddp_find_unused_parameters", False)))
        self.start_epoch, self.best, self.bad_epochs = 0, math.inf, 0
        self.history: list[dict[str, float]] = []
        self.run_id: str | None = None
        self.done = False  # finished (all epochs, or stopped early): a rerun trains no further
        # training seconds of earlier processes of this run (a resumed run reports its whole time)
        self.seconds_before, self._t0 = 0.0, time.perf_counter()

    # ------------------------------------------------------------------ state
    def state(self, epoch: int) -> dict[str, Any]:
        optim = ({k: o.state_dict() for k, o in self.optims.items()} if self.adversarial
                 else self.optim.state_dict() if self.optim else {})
        return {"model": self.model.state_dict(), "optim": optim,
                "epoch": epoch, "best": self.best, "bad_epochs": self.bad_epochs, "history": self.history,
                "rng": torch.get_rng_state(), "fingerprint": self.fingerprint, "run_id": self.run_id or "",
                "done": bool(self.done), "seconds": self.seconds(),
                **({"average": self.average, "average_updates": self.average_updates} if self.average else {})}

    def seconds(self) -> float:
        """Training seconds of this run so far, over every process that resumed it."""
        return self.seconds_before + time.perf_counter() - self._t0

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
        if self.adversarial:
            for k, o in self.optims.items():
                o.load_state_dict(st["optim"][k])
        elif self.optim and st["optim"]:
            self.optim.load_state_dict(st["optim"])
        self.start_epoch, self.best, self.bad_epochs = int(st["epoch"]) + 1, float(st["best"]), int(st["bad_epochs"])
        self.history = list(st["history"])
        if self.average is not None:
            self.average = [a.to(self.device) for a in st["average"]]
            self.average_updates = int(st["average_updates"])
        torch.set_rng_state(st["rng"].cpu())   # loaded onto self.device: on a GPU the saved CPU state moved there
        self.run_id = st.get("run_id") or None
        self.done = bool(st.get("done", False))
        self.seconds_before, self._t0 = float(st.get("seconds", 0.0)), time.perf_counter()
        log.info("resumed from %s at round %d", last, self.start_epoch)
        return True

    # ------------------------------------------------------------------ the weight average
    def _trainable(self) -> list[torch.nn.Parameter]:
        return [p for p in self.model.parameters() if p.requires_grad]

    @torch.no_grad()
    def _update_average(self) -> None:
        """Fold the weights of the step just taken into the average: ``a <- beta a + (1 - beta) w`` with
        ``beta = min(average_decay, (1 + n) / (10 + n))`` after ``n`` earlier updates (so the early average
        is not held at the initial weights; the rule of the GANs' generator average)."""
        beta = average_beta(self.cfg.average_decay, self.average_updates)
        torch._foreach_lerp_(self.average, [p.detach() for p in self._trainable()], 1.0 - beta)
        self.average_updates += 1

    @contextlib.contextmanager
    def _averaged(self) -> Iterator[None]:
        """Inside: the model holds the averaged weights (validation, ``fit_statistics``, ``best.pt``);
        after: the trained weights again, bit for bit. Without an average, nothing changes."""
        if self.average is None:
            yield
            return
        params = self._trainable()
        with torch.no_grad():
            trained = [p.detach().clone() for p in params]
            torch._foreach_copy_(params, self.average)
        try:
            yield
        finally:
            with torch.no_grad():
                torch._foreach_copy_(params, trained)

    def _save(self, epoch: int, name: str) -> None:
        """Write checkpoint ``name`` atomically: on rank 0 only (every rank holds the same state)."""
        if self.is_main:
            ckpt.save_atomic(self.state(epoch), self.out / name)

    # ------------------------------------------------------------------ the step plan
    @property
    def steps_per_pass(self) -> int:
        """Optimiser (global) steps in one pass over the training windows."""
        return max(math.ceil(len(self.train_data) / (self.cfg.batch_size * self.world)), 1)

    @property
    def total_steps(self) -> int:
        """The budget: ``train.steps``, else ``train.epochs`` data passes (0 without trainable parameters)."""
        if self.optim is None:
            return 0
        return int(self.cfg.steps) if self.cfg.steps is not None else int(self.cfg.epochs) * self.steps_per_pass

    @property
    def round_steps(self) -> int:
        """Optimiser steps between two validations: ``train.eval_every``, else one data pass."""
        return int(self.cfg.eval_every or self.steps_per_pass)

    @property
    def rounds(self) -> int:
        return math.ceil(self.total_steps / self.round_steps) if self.total_steps else 0

    def _pass_batches(self, data_epoch: int) -> list[np.ndarray]:
        """The window indices of every batch of data pass ``data_epoch`` (:meth:`WindowData.batch_indices`:
        a function of ``(seed, data_epoch)`` only), cached for the current pass."""
        if getattr(self, "_cached_pass", (None,))[0] != data_epoch:
            self._cached_pass = (data_epoch, self.train_data.batch_indices(self.cfg.batch_size, True, self.cfg.seed,
                                                                           data_epoch))
        return self._cached_pass[1]

    def _set_progress(self, round_: int, step: int) -> None:
        if hasattr(self.model, "set_epoch"):
            self.model.set_epoch(round_)
        if hasattr(self.model, "set_progress"):
            self.model.set_progress(step, self.total_steps)

    # ------------------------------------------------------------------ training
    def _rank_seed(self, round_: int) -> int:
        """The torch seed of this rank's training draws in round ``round_``."""
        return int(np.random.SeedSequence([self.cfg.seed, round_, self.rank]).generate_state(1)[0])

    def train_round(self, round_: int) -> dict[str, float]:
        """Optimiser steps ``round_ * round_steps ..`` (at most ``round_steps``, never past the budget);
        returns the ``train/*`` means over all ranks' windows.

        Global step ``g`` is step ``i = g % steps_per_pass`` of data pass ``e = g // steps_per_pass``:
        with ``world`` ranks, rank ``r`` takes batch ``i * world + r`` of that pass's permutation
        (``torch.utils.data.DistributedSampler`` semantics), so the batches of a step are a function
        of ``(seed, g)`` alone and a resumed run sees exactly what an uninterrupted one would. Each
        rank's loss is weighted by ``world x (its windows) / (the step's windows)`` so that DDP's
        gradient average is the mean over the step's windows when the last batch of a pass is short;
        a rank without a batch on such a step runs its previous batch with weight 0 (every rank joins
        every all-reduce). The learning rate of step ``g`` is ``lr * lr_factor(g)`` (warm-up, decay).
        """
        self.model.train()
        torch.manual_seed(self._rank_seed(round_))
        bs, world, n = self.cfg.batch_size, self.world, len(self.train_data)
        first = round_ * self.round_steps
        last = min(first + self.round_steps, self.total_steps)
        total, count, terms = 0.0, 0, {}
        previous = None
        bar = tqdm(total=last - first, desc=f"round {round_}", disable=not self.progress, leave=False)
        for g in range(first, last):
            self._set_progress(round_, g)
            e, i = divmod(g, self.steps_per_pass)
            batches = self._pass_batches(e)
            sizes = [len(batches[j]) if j < len(batches) else 0 for j in range(i * world, (i + 1) * world)]
            mine, step_windows = sizes[self.rank], sum(sizes)
            if mine > 0:
                batch = self.train_data.batch(batches[i * world + self.rank])
            else:  # this rank's share of the pass has run out on its last step: weight 0
                batch = previous if previous is not None else self.train_data.batch(np.arange(min(bs, n)))
            batch = batch.to(self.device)
            previous = batch
            if self.adversarial:
                logs = self._adversarial_step(batch, round_, g)
                value = float(logs["g_loss"])
                total += value * mine
                count += mine
                for k, v in logs.items():
                    terms[k] = terms.get(k, 0.0) + float(v) * mine
                if self.on_step and self.is_main:
                    self.on_step(round_, g, value)
                bar.update(1)
                bar.set_postfix(d=f"{float(logs['d_loss']):.3f}", g=f"{value:.3f}")
                continue
            for group in self.optim.param_groups:
                group["lr"] = self.cfg.lr * lr_factor(g, self.total_steps, self.cfg)
            loss, logs = self.ddp(batch) if self.ddp is not None else self.model.loss(batch)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"non-finite training loss at step {g} (round {round_}"
                                         f"{f', rank {self.rank}' if self.distributed else ''}): {logs}")
            self.optim.zero_grad(set_to_none=True)
            # DDP averages over ranks: this weight turns the average into the step's window mean
            (loss * (mine * world / step_windows) if self.distributed else loss).backward()
            if self.cfg.grad_clip:
                torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.grad_clip)
            self.optim.step()
            if self.average is not None:
                self._update_average()
            value = float(loss.detach())
            if mine > 0:
                total += value * mine
                count += mine
                for k, v in logs.items():
                    terms[k] = terms.get(k, 0.0) + float(v) * mine
            if self.on_step:
                if self.distributed:
                    import torch.distributed as dist

                    t = torch.tensor([value * mine], dtype=torch.float64, device=self.device)
                    dist.all_reduce(t)
                    value = float(t) / step_windows
                if self.is_main:
                    self.on_step(round_, g, value)
            bar.update(1)
            bar.set_postfix(loss=f"{float(loss.detach()):.4f}")
        bar.close()
        return self._reduce_means(total, count, terms)

    def _adversarial_step(self, batch: Batch, round_: int, g: int) -> dict[str, float]:
        """Global step ``g`` of an adversarial model: the model's ``adversarial_step`` with an ``update``
        that checks, back-propagates and applies one player's loss (module docstring). Returns the
        step's logs (``d_loss`` and ``g_loss`` at least); raises :class:`TrainingDiverged`."""
        factor = lr_factor(g, self.total_steps, self.cfg)
        for name, opt in self.optims.items():
            for group in opt.param_groups:
                group["lr"] = player_lr(self.cfg, name) * factor

        def update(player: str, loss: torch.Tensor) -> None:
            if player not in self.optims:
                raise KeyError(f"{type(self.model).__name__}.adversarial_step updated an unknown player {player!r}; "
                               f"players: {sorted(self.optims)}")
            if not torch.isfinite(loss):
                raise TrainingDiverged(f"{type(self.model).__name__} diverged at step {g} (round {round_}): the "
                                       f"{player} loss is {float(loss.detach())}; {kept(round_)}")
            opt = self.optims[player]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if self.cfg.grad_clip:
                torch.nn.utils.clip_grad_norm_([p for grp in opt.param_groups for p in grp["params"]],
                                               self.cfg.grad_clip)
            opt.step()

        logs = {k: float(v) for k, v in self.model.adversarial_step(batch, update).items()}
        self.model.update_average()
        missing = {"d_loss", "g_loss"} - set(logs)
        if missing:
            raise KeyError(f"{type(self.model).__name__}.adversarial_step must log {sorted(missing)}")
        peak = logs.get("logit_absmax", 0.0)
        if not math.isfinite(peak) or peak > self.cfg.max_logit:
            raise TrainingDiverged(f"{type(self.model).__name__} diverged at step {g} (round {round_}): a "
                                   f"discriminator logit reached {peak:.3g} (train.max_logit {self.cfg.max_logit:g}); "
                                   f"{kept(round_)}")
        return logs

    def _reduce_means(self, total: float, count: int, terms: dict[str, float]) -> dict[str, float]:
        """``train/*`` means over the windows of all ranks (all-reduce of sums and counts under DDP)."""
        if self.distributed:
            import torch.distributed as dist

            keys: list[list[str]] = [[] for _ in range(self.world)]
            dist.all_gather_object(keys, sorted(terms))        # the union of the log keys, in one order
            names = sorted(set().union(*keys))
            sums = torch.tensor([total, count, *(terms.get(k, 0.0) for k in names)], dtype=torch.float64,
                                device=self.device)
            dist.all_reduce(sums)
            total, count, *rest = sums.tolist()
            terms = dict(zip(names, rest))
        c = max(count, 1)
        return {"train/loss": total / c, **{f"train/{k}": v / c for k, v in terms.items()}}

    # ------------------------------------------------------------------ validation
    @torch.no_grad()
    def evaluate(self, data: WindowData, prefix: str = "val") -> dict[str, float]:
        """The model's loss and its prediction error against zero-velocity's, per horizon.

        ``pred_mse``: MSE of ``model.predict`` over the scored frames (``model.scored_frames(T)``,
        default every frame after the ``seed_frames`` seed); ``zero_velocity_mse``: the same frames
        predicted by repeating the last seed frame; ``rel_zv``: the selection criterion
        :func:`~.criteria.horizon_weighted_ratio` of the two per-horizon curves (models with a seed).
        """
        self.model.eval()
        S = int(getattr(self.model, "seed_frames", 0))
        loss_sum, n = 0.0, 0
        err_t = zv_t = mask = None
        g = torch.get_rng_state()
        torch.manual_seed(self.cfg.seed + 1)  # sampling models: the same draws at every evaluation
        if hasattr(self.model, "validate"):   # a model with its own validation (GANs: an MMD on the split)
            try:
                out = self.model.validate(data, batch_size=self.cfg.eval_batch_size, device=self.device)
            finally:
                torch.set_rng_state(g)
            bad = sorted(k for k, v in out.items() if not math.isfinite(float(v)))
            if bad:  # never a NaN metric in the history: a generator that outputs NaN has diverged
                raise TrainingDiverged(f"{type(self.model).__name__} diverged: validation {bad} not finite; training "
                                       "stopped, the checkpoints of the last good round are kept")
            return {f"{prefix}/{k}": float(v) for k, v in out.items()}
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
            e = ((pred - tgt) ** 2).flatten(2).mean(-1).double().sum(0)             # [T]: summed over windows
            err_t = e if err_t is None else err_t + e
            if S > 0:
                z = ((tgt[:, S - 1:S] - tgt) ** 2).flatten(2).mean(-1).double().sum(0)
                zv_t = z if zv_t is None else zv_t + z
            if mask is None:
                T = tgt.shape[1]
                mask = (self.model.scored_frames(T) if hasattr(self.model, "scored_frames")
                        else torch.arange(T) >= S).to(e.device)
            loss_sum += float(loss.detach()) * batch.size
            n += batch.size
        torch.set_rng_state(g)
        n = max(n, 1)
        out = {f"{prefix}/loss": loss_sum / n, f"{prefix}/pred_mse": float(err_t[mask].mean()) / n}
        if S > 0:
            out[f"{prefix}/zero_velocity_mse"] = float(zv_t[S:].mean()) / n
            out[f"{prefix}/rel_zv"] = horizon_weighted_ratio((err_t[S:] / n).tolist(), (zv_t[S:] / n).tolist())
        return out

    # ------------------------------------------------------------------ the loop
    def fit(self) -> dict[str, Any]:
        if len(self.train_data) == 0 or len(self.val_data) == 0:
            raise ValueError(f"empty data: {len(self.train_data)} train and {len(self.val_data)} val windows")
        if not self.history:  # a fresh run: its clock starts here (a resumed one goes on from its checkpoint)
            self.seconds_before, self._t0 = 0.0, time.perf_counter()
            if hasattr(self.model, "fit_statistics"):  # the train split's statistics (the mean pose, the
                self.model.fit_statistics(self.train_data)  # cRBM's whitening) before the first step; no RNG
            if self.average is not None:          # the average starts at the weights of the first step
                self.average = [p.detach().clone() for p in self._trainable()]
                self.average_updates = 0
        rounds = self.rounds if not self.done else 0
        if rounds == 0 and not self.history:  # nothing to learn (zero-velocity, the mean pose): evaluate once
            metrics = {"epoch": 0, "step": 0, **self.evaluate(self.val_data)}
            self.history.append(metrics)
            self.best = metrics.get(self.cfg.monitor, math.inf)
            self.done = True
            self._save(0, "best.pt")
            self._save(0, "last.pt")
            distributed.barrier()
            if self.on_epoch and self.is_main:
                self.on_epoch(0, metrics)
        for r in range(self.start_epoch, rounds):
            metrics = {"epoch": r, **self.train_round(r)}
            step = min((r + 1) * self.round_steps, self.total_steps)
            metrics.update(step=step, data_epoch=round(step / self.steps_per_pass, 4),
                           lr=self.cfg.lr * lr_factor(step - 1, self.total_steps, self.cfg))
            with self._averaged():  # validated, selected and kept in best.pt: the average, if kept
                if hasattr(self.model, "fit_statistics"):  # no RNG, eval mode inside: training's bits untouched
                    self.model.fit_statistics(self.train_data)
                metrics.update(self.evaluate(self.val_data))
                if self.cfg.monitor not in metrics:
                    raise ValueError(f"train.monitor {self.cfg.monitor!r} is not a validation metric of "
                                     f"{type(self.model).__name__}; it reports "
                                     f"{sorted(k for k in metrics if '/' in k)}")
                selectable = bool(getattr(self.model, "selectable", True))
                if not selectable:          # a round the model says cannot be chosen (SkeletonGAN's pose stage)
                    metrics["selectable"] = 0.0
                self.history.append(metrics)
                score = metrics[self.cfg.monitor]
                if selectable and score < self.best - self.cfg.min_delta:
                    self.best, self.bad_epochs = score, 0
                    self._save(r, "best.pt")
                elif selectable:
                    self.bad_epochs += 1
            stop = self.bad_epochs >= self.cfg.patience
            self.done = stop or r == rounds - 1
            # log before last.pt: a kill between the two redoes (and re-logs) this round on resume,
            # rather than resuming after a round whose metrics never reached MLflow
            if self.on_epoch and self.is_main:
                self.on_epoch(r, metrics)
            if (r + 1) % self.cfg.checkpoint_every == 0 or self.done:
                self._save(r, "last.pt")
            distributed.barrier()  # DDP: rank 0's checkpoints are on disk before any rank goes on
            if self.is_main:
                log.info("round %d (step %d): %s", r, step,
                         ", ".join(f"{k}={v:.5f}" for k, v in metrics.items() if "/" in k))
            if stop:  # the same decision on every rank: identical validation (module docstring)
                if self.is_main:
                    log.info("early stop at round %d, step %d (%s has not improved for %d rounds)", r, step,
                             self.cfg.monitor, self.cfg.patience)
                break
        return {"history": self.history, "best": self.best, "epochs_run": len(self.history),
                "seconds": self.seconds(), "config": asdict(self.cfg),
                "steps_per_pass": self.steps_per_pass, "total_steps": self.total_steps}

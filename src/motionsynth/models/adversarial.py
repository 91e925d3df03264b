"""What every action GAN of GlocalNet's Table 3 shares: players, real clips, sampling, and selection.

The GAN family (SA-GCN, c-SkeletonGAN, SkeletonGAN; SkeletonVAE shares the sampling and the
selection) generates a whole clip of ``clip`` poses from noise and a class label; none of them
takes seed poses. Each model is one file (``sagcn.py``, ...) that subclasses
:class:`AdversarialModel` and implements

* ``sample(labels [N], length) -> [N, length, J, D]``: the generator, from fresh noise;
* ``adversarial_step(batch, update) -> logs``: one training step of its paper's algorithm. It
  computes each player's loss and calls ``update(player, loss)`` (the shared trainer's: it
  checks the loss for divergence, back-propagates it and steps that player's optimiser), and
  returns float logs with at least ``d_loss`` and ``g_loss``, plus ``logit_absmax`` (the largest
  discriminator logit magnitude of the step: the trainer stops a run whose logits explode).

Shared here (``motionsynth.training.trainer`` documents the trainer's side). :class:`ClipGenerator`
holds what SkeletonVAE shares too (clips, generation, selection); :class:`AdversarialModel` adds:

* **Players**: by default ``generator`` (the module ``self.generator``) and ``discriminator`` (every
  module in ``self.discriminators``); models with more (SkeletonGAN's pretrained pose decoder and
  its critic) override :meth:`AdversarialModel.players`. Each parameter belongs to exactly one (the
  trainer checks).
* **Real clips** (:meth:`real_clips`): the training windows of the ``glocal`` family hold
  ``seed_poses + clip`` = 60 poses on ``h36m``; a real clip is ``clip`` consecutive poses of a
  window at a uniformly drawn offset (torch RNG: deterministic under the trainer's per-round seed),
  as the reference's loader cuts its 50-pose clips at random starts (ours: within our windows).
* **Generation** (:meth:`generate`): the seed poses, if any, are copied to the output and the
  generator's clip follows them; the generated clip does not depend on the seed (these models
  take none). ``length - S`` poses are generated (any length the generator supports).
* **Selection** (:meth:`validate`; the trainer calls it instead of its roll-out errors): a GAN has
  no validation loss. Every validation round draws one generated clip per validation window
  (fixed noise: the trainer reseeds torch before every validation) and scores them against the
  windows' real clips (poses ``seed_poses .. seed_poses + clip``, the poses the MMD suite scores)
  with :func:`motionsynth.metrics.mmd.mmd`, per class over at most ``val_per_class`` windows a class
  (evenly spaced, the same every round). Logged: ``mmd_avg``, ``mmd_seq`` and the velocity
  ``mmd_vel_seq``; the selection criterion ``mmd_motion`` = ``mmd_seq + mmd_vel_seq``. Ours: the
  references select on the MMD of their *training* clips (SA-GCN: MMD_seq, every 200 iterations);
  we select on the validation split, and add the velocity term because a generator that holds one
  real pose still scores well on MMD_seq (the MMD suite's calibration: a still real pose 0.071 on
  the training subjects' clips) but about 1 on velocity MMD: a still pose cannot win this criterion.
"""

from __future__ import annotations

import copy
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .base import Batch, DataSpec, MotionModel, average_beta, check_int as _count

#: ``update(player, loss)``: the trainer's step of one player (check, backward, clip, optimiser step)
Update = Callable[[str, Tensor], None]


def bce_logits(logits: Tensor, target: float) -> Tensor:
    """Binary cross-entropy of raw logits against a constant target (1 real, 0 fake, 0.9 smoothed):
    ``BCELoss(sigmoid(logits), target)`` computed stably."""
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, float(target)))


class ClipGenerator(MotionModel):
    """A class-conditional generator of whole clips from noise (module docstring): real clips,
    :meth:`generate` / :meth:`predict`, and selection by :meth:`validate`. Subclasses implement
    :meth:`sample` and either :meth:`loss` (SkeletonVAE: the usual trainer path) or, through
    :class:`AdversarialModel`, :meth:`adversarial_step`."""

    family = "glocal"
    uses_labels = True

    def __init__(self, spec: DataSpec, seed_poses: int = 10, clip: int = 50, val_per_class: int = 100):
        super().__init__(spec)
        self.seed_frames = _count("seed_poses", seed_poses, 0)
        self.clip = _count("clip", clip, 2)
        self.val_per_class = _count("val_per_class", val_per_class, 2)
        if _count("spec.every", spec.every, 1) != 1:
            raise ValueError(f"{type(self).__name__} generates dense poses; the data's windows are sparse "
                             f"(every {spec.every})")
        if spec.window < self.clip:
            raise ValueError(f"{type(self).__name__} trains on clips of {self.clip} poses; the data's windows have "
                             f"{spec.window}")
        if spec.num_classes < 1:
            raise ValueError(f"{type(self).__name__} is class-conditional and needs labelled data")
        self.num_classes = int(spec.num_classes)
        self._val_cache: tuple[int, Tensor, Tensor] | None = None

    # ------------------------------------------------------------------ data
    def real_clips(self, batch: Batch) -> Tensor:
        """``clip`` consecutive poses of each window at a uniform random offset: ``[B, clip, J, D]``."""
        B, T = batch.pose.shape[:2]
        off = torch.randint(0, T - self.clip + 1, (B,), device=batch.pose.device)
        idx = off[:, None] + torch.arange(self.clip, device=batch.pose.device)        # [B, clip]
        return batch.pose[torch.arange(B, device=batch.pose.device)[:, None], idx]

    def labels_of(self, batch: Batch) -> Tensor:
        if batch.labels is None:
            raise ValueError(f"{type(self).__name__} is class-conditional: the batch has no labels")
        return batch.labels.long().reshape(-1)

    def one_hot(self, labels: Tensor) -> Tensor:
        return F.one_hot(labels.long(), self.num_classes).float()

    # ------------------------------------------------------------------ to implement
    def sample(self, labels: Tensor, length: int) -> Tensor:
        """``length`` generated poses per label ``[N] -> [N, length, J, D]`` (fresh noise)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ generation
    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 60, num_samples: int = 1) -> Tensor:
        S = 0 if seed is None else int(seed.shape[1])
        if labels is None:
            raise ValueError(f"{type(self).__name__} is class-conditional: generate needs labels")
        labels = labels.long()
        if labels.dim() == 2:                     # a class per frame: these generators take one per clip
            labels = labels[:, S] if labels.shape[1] > S else labels[:, -1]
        if length - S < 1:
            raise ValueError(f"length {length} leaves no pose to generate after {S} seed poses")
        labels = labels.repeat_interleave(num_samples)
        fake = self.sample(labels, length - S)
        if S == 0:
            return fake
        return torch.cat([seed.repeat_interleave(num_samples, 0).to(fake.dtype), fake], dim=1)

    def predict(self, batch: Batch) -> Tensor:
        """The window's seed poses followed by one generated clip: ``[B, seed_poses + clip, J, D]``."""
        S = self.seed_frames
        return self.generate(batch.pose[:, :S], labels=self.labels_of(batch), length=S + self.clip)

    def target(self, batch: Batch) -> Tensor:
        return batch.pose[:, :self.seed_frames + self.clip]

    # ------------------------------------------------------------------ selection
    def _validation_set(self, data, batch_size: int) -> tuple[Tensor, Tensor]:
        """The validation windows' real clips ``[N, clip, J, D]`` and labels: at most ``val_per_class``
        windows a class, evenly spaced over the class's windows (cached per data set)."""
        if self._val_cache is not None and self._val_cache[0] == id(data):
            return self._val_cache[1], self._val_cache[2]
        lab = np.asarray(data.labels)[data.windows["seq"].to_numpy()]
        pick = []
        for c in np.unique(lab):
            idx = np.flatnonzero(lab == c)
            n = min(len(idx), self.val_per_class)
            pick.append(idx[np.linspace(0, len(idx) - 1, n).round().astype(np.int64)])
        pick = np.concatenate(pick)
        clips, labels = [], []
        S = self.seed_frames
        for i in range(0, len(pick), batch_size):
            b = data.batch(pick[i:i + batch_size])
            if b.pose.shape[1] < S + self.clip:
                raise ValueError(f"validation windows of {b.pose.shape[1]} poses; selection scores poses "
                                 f"{S}..{S + self.clip}")
            clips.append(b.pose[:, S:S + self.clip])
            labels.append(self.labels_of(b))
        out = torch.cat(clips), torch.cat(labels)
        self._val_cache = (id(data), *out)
        return out

    @torch.no_grad()
    def validate(self, data, batch_size: int = 64, device: torch.device | str = "cpu") -> dict[str, float]:
        """Selection metrics on the validation split (module docstring): ``mmd_avg``, ``mmd_seq``,
        ``mmd_vel_seq`` and the criterion ``mmd_motion``."""
        from ..metrics.mmd import mmd

        real, labels = self._validation_set(data, batch_size)
        fake = torch.cat([self.sample(labels[i:i + batch_size].to(device), self.clip).cpu()
                          for i in range(0, len(labels), batch_size)])
        r, f, lab = real.numpy().astype(np.float64), fake.numpy().astype(np.float64), labels.numpy()
        if not np.isfinite(f).all():      # the trainer stops the run on a non-finite validation metric
            return dict.fromkeys(("mmd_avg", "mmd_seq", "mmd_vel_seq", "mmd_motion"), float("nan"))
        out = {"mmd_avg": mmd(r, f, lab, lab, mode="avg").value, "mmd_seq": mmd(r, f, lab, lab, mode="seq").value,
               "mmd_vel_seq": mmd(r, f, lab, lab, mode="seq", velocity=True).value}
        out["mmd_motion"] = out["mmd_seq"] + out["mmd_vel_seq"]
        return out


class AdversarialModel(ClipGenerator):
    """Base of the GAN family (module docstring). Subclasses set ``self.generator`` and
    ``self.discriminators`` (an ``nn.ModuleDict``), or override :meth:`players`, and implement
    :meth:`sample` (from :meth:`sampler`) and :meth:`adversarial_step`.

    **Generator average** (:meth:`keep_average`, ours; no reference of the family has it): the trained
    generator keeps playing the game, but validation and generation (eval mode) sample from an
    exponential moving average of its weights (Yazici et al., ICLR 2019, "The unusual effectiveness
    of averaging in GAN training"), a copy without gradients that is a part of every checkpoint."""

    adversarial = True
    average_decay = 0.0      # ``keep_average``: 0 samples from the trained generator itself

    def keep_average(self, decay: float) -> None:
        """Sample from an exponential moving average of the generator's weights (class docstring);
        a subclass calls this once ``self.generator`` is built. ``decay`` 0 keeps none."""
        if isinstance(decay, bool) or not isinstance(decay, (int, float)) or not 0.0 <= decay < 1.0:
            raise ValueError(f"average_decay must be a number in [0, 1), got {decay!r}")
        self.average_decay = float(decay)
        if self.average_decay > 0:
            self.generator_average = copy.deepcopy(self.generator).requires_grad_(False)
            self.register_buffer("average_updates", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def update_average(self) -> None:
        """Fold the generator's current weights into the average (the trainer calls this after every
        step): ``a <- beta a + (1 - beta) w`` with ``beta = min(decay, (1 + n) / (10 + n))`` after ``n``
        earlier updates (the early average is not held at the initial weights); buffers are copied."""
        if not self.average_decay:
            return
        beta = average_beta(self.average_decay, int(self.average_updates))
        for a, w in zip(self.generator_average.parameters(), self.generator.parameters()):
            a.lerp_(w, 1.0 - beta)
        for a, w in zip(self.generator_average.buffers(), self.generator.buffers()):
            a.copy_(w)
        self.average_updates += 1

    def sampler(self) -> nn.Module:
        """The generator that samples: the trained one while training, the average (if kept) in eval mode."""
        return self.generator_average if self.average_decay and not self.training else self.generator

    def players(self) -> dict[str, list[nn.Parameter]]:
        """Player name -> its parameters; ``generator`` is required (the trainer's learning rate ``lr``;
        other players ``train.player_lr[name]`` where given)."""
        return {"generator": list(self.generator.parameters()),
                "discriminator": [p for d in self.discriminators.values() for p in d.parameters()]}

    def adversarial_step(self, batch: Batch, update: Update) -> dict[str, float]:
        raise NotImplementedError

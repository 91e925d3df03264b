"""Mean pose: the train split's mean pose after the seed, the floor below which a model has collapsed.

``x^_t = mu`` for every ``t >= S`` (the seed frames ``0 .. S-1`` are the ground truth), with
``mu`` ``[J, D]`` the mean over every frame of every **train-split** sequence of the training
representation, in the normalised space the models work in (:meth:`MeanPose.fit_statistics`,
called by the trainer on the training windows' sequences before its single evaluation; stored
as the buffer ``mean``, so ``best.pt`` carries it). Where the normalisation's own mean comes from
the same train frames, ``mu`` is about 0 in normalised units; where a protocol takes its statistics
over other frames (``csgan``: the reference's, over train + val at 50 Hz) it is not. Either way it is
measured, not assumed.

Why it exists: a recurrent model that has collapsed to the mean pose scores about this row's
error at every horizon, and at long horizons it even beats zero-velocity (any real motion drifts
further from the truth than the mean does). So every learnt model's first-horizon error must
clear it by far, and the report puts it in every horizon table.

Everything else is zero-velocity's (it subclasses :class:`~.zero_velocity.ZeroVelocity`):
the seed protocol (``seed_frames`` ``None``: 60 frames on locomotion windows, ``window // 6``
on short ones), nothing to learn (0 epochs: the trainer evaluates once), ``reference = True``
(tables list it with the calibration rows), and the trajectory: where an evaluation integrates
a root, the mean pose's root **stands still** at the last seed frame, as zero-velocity's does.

Shapes: ``seed`` ``[B, S, J, D]`` -> ``[B, length, J, D]``; ``mean`` ``[J, D]``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .base import Batch, DataSpec
from .zero_velocity import ZeroVelocity


class MeanPose(ZeroVelocity):
    def __init__(self, spec: DataSpec, seed_frames: int | None = None, family: str | None = None):
        super().__init__(spec, seed_frames, family)
        self.register_buffer("mean", torch.zeros(spec.joints, spec.dims))
        self.register_buffer("frames_seen", torch.zeros((), dtype=torch.long))

    @torch.no_grad()
    def fit_statistics(self, train) -> None:
        """``mean`` = the mean normalised pose over every frame of the sequences that ``train``
        (a :class:`~motionsynth.training.data.WindowData` of the train split) has windows in."""
        seqs = np.unique(train.windows["seq"].to_numpy())
        total, n = np.zeros(self.mean.shape, np.float64), 0
        for s in seqs:
            a, f = int(train.offsets[s]), int(train.frames[s])
            z = train.norm(np.asarray(train.pose[a:a + f], np.float64), np.asarray(train.root[a:a + f], np.float64))
            total += z.sum(0)
            n += f
        if n == 0:
            raise ValueError("MeanPose: the train split has no frames")
        self.mean.copy_(torch.from_numpy(total / n).to(self.mean.dtype))
        self.frames_seen.fill_(n)

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        pose = batch.pose
        S = min(self.seed_frames, pose.shape[1] - 1)
        if S < 1:
            raise ValueError(f"MeanPose needs windows of >= 2 frames, got {pose.shape[1]}")
        mse = ((pose[:, S:] - self.mean) ** 2).mean()
        return mse + 0.0 * self.dummy, {"pose_mse": float(mse)}

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        out = super().generate(seed, controls, labels, length, 1)
        S = 0 if seed is None else min(int(seed.shape[1]), length)
        out[:, S:] = self.mean.to(out.dtype)
        return out.repeat_interleave(num_samples, 0) if num_samples > 1 else out

"""Zero-velocity baseline: repeat the last seed pose (the baseline of Martinez et al., CVPR 2017).

``x^_t = x_{S-1}`` for every ``t >= S``, with ``S = seed_frames`` ground-truth frames. It
has nothing to learn; :meth:`ZeroVelocity.loss` returns the MSE of the repeated pose on
the frames after the seed (the trainer's ``val/pred_mse`` of this model) plus ``0 *`` a
dummy zero parameter, so that the generic trainer can build an optimiser and call
``backward`` (zero gradients: Adam leaves the parameter at zero). Its config trains for
0 epochs: the trainer then evaluates once.

Choices: ``seed_frames`` ``None`` = 60 on locomotion-length windows, ``window // 6`` on
short ones (the recurrent baselines' protocol); without a seed, :meth:`generate` repeats
the mean pose (zeros in normalised units). ``family`` ``None`` (class attribute too):
the trainer uses the dataset's ``training.family``.

Shapes: ``seed`` ``[B, S, J, D]`` -> ``[B, length, J, D]``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .base import Batch, DataSpec, MotionModel
from .recurrent import check_family, check_int, default_seed_frames


class ZeroVelocity(MotionModel):
    family = None  # type: ignore[assignment]
    #: a trivial reference, not a learnt model: evaluation tables list it with the calibration rows
    reference = True
    uses_controls = False
    uses_labels = False

    def __init__(self, spec: DataSpec, seed_frames: int | None = None, family: str | None = None):
        super().__init__(spec)
        self.seed_frames = default_seed_frames(spec, seed_frames)
        self.family = check_family(family)
        self.dummy = nn.Parameter(torch.zeros(()))

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        pose = batch.pose
        S = min(self.seed_frames, pose.shape[1] - 1)
        if S < 1:
            raise ValueError(f"ZeroVelocity needs windows of >= 2 frames, got {pose.shape[1]}")
        mse = ((pose[:, S:] - pose[:, S - 1:S]) ** 2).mean()
        return mse + 0.0 * self.dummy, {"pose_mse": float(mse)}

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        check_int("length", length)
        check_int("num_samples", num_samples)
        if seed is None or seed.shape[1] == 0:
            B = next((t.shape[0] for t in (seed, controls, labels) if t is not None), 1)
            seed = self.dummy.new_zeros(B, 1, self.spec.joints, self.spec.dims)
        S = seed.shape[1]
        if S >= length:
            out = seed[:, :length]
        else:
            out = torch.cat([seed, seed[:, -1:].expand(-1, length - S, -1, -1)], 1)
        return out.repeat_interleave(num_samples, 0) if num_samples > 1 else out.clone()

    @torch.no_grad()
    def predict(self, batch: Batch) -> Tensor:
        T = batch.pose.shape[1]
        return self.generate(batch.pose[:, :min(self.seed_frames, T)], length=T)

"""Feature normalisation with train-split statistics (written by the ``split`` stage).

For 2-D representations with ``depth_scale`` (the c-SkeletonGAN / GlocalNet
Human3.6M benchmark), centred joints are first multiplied by
``depth / mean_depth`` (the centre joint's camera depth over its mean over the
training set), which removes the subject's distance to the camera; then every
dimension is standardised by the train mean and std. 3-D poses are only
standardised.

Shapes: ``pose`` ``[..., J, D]``, ``root`` ``[..., 3]`` (``root[..., 2]`` is the depth for 2-D).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


def depth_scaled(pose: np.ndarray, depth: np.ndarray, mean_depth: float) -> np.ndarray:
    """``pose * depth / mean_depth`` with ``depth`` broadcast over joints and dims."""
    return pose * (np.asarray(depth)[..., None, None] / mean_depth)


@dataclass
class Normaliser:
    mean: np.ndarray          # [J, D]
    std: np.ndarray           # [J, D]
    mean_depth: float | None  # set for depth-scaled 2-D representations

    @classmethod
    def load(cls, stats_path: str | Path) -> "Normaliser":
        s = np.load(stats_path)
        md = float(s["mean_depth"]) if "mean_depth" in s.files else None
        return cls(s["pose_mean"], s["pose_std"], md)

    def __call__(self, pose: np.ndarray, root: np.ndarray | None = None) -> np.ndarray:
        if self.mean_depth is not None:
            if root is None:
                raise ValueError("depth-scaled normalisation needs the root (its depth)")
            pose = depth_scaled(pose, root[..., 2], self.mean_depth)
        return (pose - self.mean) / self.std

    def inverse(self, z: np.ndarray, root: np.ndarray | None = None) -> np.ndarray:
        pose = z * self.std + self.mean
        if self.mean_depth is not None:
            if root is None:
                raise ValueError("depth-scaled normalisation needs the root (its depth)")
            pose = depth_scaled(pose, 1.0 / root[..., 2], 1.0 / self.mean_depth)
        return pose

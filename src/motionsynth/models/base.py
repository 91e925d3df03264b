"""The interface every model implements, and the batch it trains on.

Shapes at every boundary are ``[batch, time, joints, dims]``:

* ``Batch.pose``     float32 ``[B, T, J, D]``: the window's dense frames, normalised
  with train-split statistics (``D`` = 3 for 3-D data, 2 for 2-D views);
* ``Batch.controls`` float32 ``[B, T, 3]`` normalised (forward, sideways, turn) or ``None``;
* ``Batch.labels``   int64 ``[B]`` class indices, or ``None`` for unlabelled data;
* ``Batch.every``    sparse-pose stride ``k`` of the window (GlocalNet family): the
  sparse poses are ``pose[:, ::k]``; 1 for dense-only families.

``DataSpec`` tells a model the sizes it is built for (and the skeleton, ``parents``, for models whose
layers follow the bones); a model is constructed as
``Model(spec, **hyperparameters)`` from its Hydra config.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator

import torch
from torch import Tensor, nn


def check_int(name: str, value, minimum: int = 1) -> int:
    """A model hyperparameter that must be an integer >= ``minimum`` (a one-line error naming it)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def average_beta(decay: float, updates: int) -> float:
    """The weight of the old average in an exponential moving average of weights after ``updates``
    earlier updates: ``min(decay, (1 + n) / (10 + n))``, so the early average is not held at the initial
    weights. One rule for the GANs' generator average (:mod:`.adversarial`) and the trainer's
    ``train.average_decay``."""
    return min(decay, (1.0 + updates) / (10.0 + updates))


@dataclass(frozen=True)
class DataSpec:
    joints: int               # J
    dims: int                 # D (3 or 2)
    num_classes: int = 0      # 0: no class labels
    controls: int = 0         # 3 where the dataset has control signals, else 0
    fps: float = 30.0
    window: int = 240         # frames per training window (dense)
    every: int = 1            # sparse stride k of the training windows (GlocalNet family)
    parents: tuple[int, ...] | None = None   # the skeleton: each joint's parent index (-1: none kept), if known

    @property
    def pose_features(self) -> int:
        return self.joints * self.dims


@dataclass
class Batch:
    pose: Tensor
    controls: Tensor | None = None
    labels: Tensor | None = None
    every: int = 1
    extra: dict = field(default_factory=dict)

    def to(self, device: torch.device | str) -> "Batch":
        mv = lambda t: t.to(device, non_blocking=True) if isinstance(t, Tensor) else t  # noqa: E731
        return Batch(mv(self.pose), mv(self.controls), mv(self.labels), self.every,
                     {k: mv(v) for k, v in self.extra.items()})

    @property
    def size(self) -> int:
        return int(self.pose.shape[0])


class MotionModel(nn.Module):
    """Base class of every model.

    Subclasses implement :meth:`loss` (the training objective, with a dict of
    named float terms for logging) and :meth:`generate`. ``seed_frames`` is the
    number of ground-truth frames a model is given before it predicts (the
    evaluation protocol reads it; VAE-LSTM: 0 or 4, baselines: 60 on locomotion).
    """

    #: which window family of ``prepare`` the model trains on: "vae_lstm" or "glocal"
    family: str = "vae_lstm"
    #: whether the model consumes control signals when the dataset has them
    uses_controls: bool = False
    #: whether the model conditions on class labels when the dataset has them
    uses_labels: bool = False

    def __init__(self, spec: DataSpec):
        super().__init__()
        self.spec = spec

    @classmethod
    def check_hparams(cls, hparams: dict) -> None:
        """Refuse, before any data is read, hyperparameters the constructor cannot take: names it does
        not accept (``ValueError`` naming them). Models with values to check extend this (the
        constructor checks again, for direct use)."""
        import inspect

        accepted, open_ended = set(), False
        for klass in cls.__mro__:
            if klass is MotionModel or "__init__" not in vars(klass):
                continue
            params = inspect.signature(vars(klass)["__init__"]).parameters
            accepted |= {n for n, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)} - {"self", "spec"}
            if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
                break                           # no **kwargs: the base classes take nothing more from here
        else:
            open_ended = True
        unknown = sorted(set(hparams) - accepted)
        if unknown and not open_ended:
            raise ValueError(f"{cls.__name__} takes no hyperparameter(s) {unknown}; it takes {sorted(accepted)}")

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        raise NotImplementedError

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        """Synthesize motion.

        ``seed`` ``[B, S, J, D]`` ground-truth frames (``S`` may be 0 / ``None``);
        ``controls`` ``[B, length, 3]`` for control-driven models; ``labels`` ``[B]``
        or ``[B, length]`` (a class per frame, for transitions). Returns
        ``[B * num_samples, length, J, D]``: the full sequence, seed frames
        included, so that ``out[:, :S] == seed`` for models that copy their seed.
        """
        raise NotImplementedError

    @staticmethod
    def flat(pose: Tensor) -> Tensor:
        """``[B, T, J, D]`` -> ``[B, T, J*D]``."""
        return pose.reshape(pose.shape[0], pose.shape[1], -1)

    def unflat(self, x: Tensor) -> Tensor:
        """``[B, T, J*D]`` -> ``[B, T, J, D]``."""
        return x.reshape(x.shape[0], x.shape[1], self.spec.joints, self.spec.dims)


@contextmanager
def one_thread(device: torch.device | str) -> Iterator[None]:
    """Run the block on one intra-op CPU thread, then restore the process's thread count.

    Step-by-step roll-outs (recurrent baselines, the VAE-LSTM cell) are hundreds of small kernels,
    each a thread barrier with more threads. Measured on the 2-core machine: a paper-size VAE-LSTM
    roll-out of 1,000 characters takes 0.15 s on one thread, 0.32 s on two, and 3.0 s on two when
    another process keeps a core busy; the locomotion evaluation suite's baseline roll-outs took
    128 s on two threads next to a training job and 14 s on one. Whole-sequence work (convolutions,
    one nn.LSTM call over a window) keeps all threads.
    """
    n = torch.get_num_threads()
    if torch.device(device).type != "cpu" or n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)

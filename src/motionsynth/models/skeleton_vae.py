"""SkeletonVAE: a conditional sequence VAE over SkeletonGAN's generator (GlocalNet Table 3's baseline row).

GlocalNet's Table 3 lists "SkeletonVAE" beside SkeletonGAN, citing Cai et al. (ECCV 2018); the numbers
in the table go back to the c-SkeletonGAN paper. Neither public code base (Cai et al.'s, as carried by
the c-SkeletonGAN authors' repository) holds a SkeletonVAE, and we could not read the papers' bodies,
so **this model is ours**, labelled as such in the report: the variational counterpart of
:mod:`.skeleton_gan` with the same generator, trained by maximum likelihood instead of a discriminator.

* **Decoder** (the generator): SkeletonGAN's latent walk and pose decoder (:class:`~.skeleton_gan.LatentWalk`,
  :class:`~.skeleton_gan.PoseDecoder`, the same sizes): ``z_t = z_{t-1} + clip(W LSTM([eps_t, c]), -1, 1)``,
  pose ``t`` = ``G0([z_t, c])``.
* **Encoder** ``q(z_0, eps | x, c)``: a bi-directional LSTM (``encoder_hidden`` per direction) over
  ``[x_t, x_{t+1} - x_t, c]`` (SkeletonGAN's discriminator input); its output at step ``t`` gives the mean
  and log-variance of ``eps_{t+1}`` (``noise_dim``), its two final states those of ``z_0`` (``z_dim``).
* **Prior**: ``N(0, I)`` for ``z_0`` and every ``eps_t`` (SkeletonGAN draws ``z_0`` from ``U(-1, 1)``; a VAE
  needs the prior it trains against).
* **Loss** (per clip, mean over the batch): the squared error of the ``clip`` poses summed over frames
  and coordinates (a Gaussian likelihood with unit variance in the normalised space) plus ``beta`` times
  the KL divergence summed over ``z_0`` and the steps; ``kl_warmup``: the KL weight rises linearly from 0
  to ``beta`` over that fraction of the budget (the usual remedy for an unused latent; a departure from
  a plain VAE, as for our VAE-LSTM).
* **Training**: our trainer's ordinary path (one optimiser, Adam (0.5, 0.9) and lr 1e-4 as SkeletonGAN's
  sequence stage, batch 32), real clips as the GANs cut them; selection by the validation MMD of prior
  samples (:mod:`.adversarial`), as for the GANs, not by the ELBO.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .adversarial import ClipGenerator, _count
from .base import Batch, DataSpec
from .skeleton_gan import LatentWalk, PoseDecoder


class SkeletonVAE(ClipGenerator):
    """SkeletonVAE (module docstring). Hyperparameters: ``z_dim``, ``noise_dim``, ``hidden`` (walk LSTM),
    ``width`` (pose decoder), ``encoder_hidden``, ``beta``, ``kl_warmup``, plus
    :class:`~.adversarial.ClipGenerator`'s ``seed_poses``, ``clip``, ``val_per_class``."""

    def __init__(self, spec: DataSpec, z_dim: int = 12, noise_dim: int = 64, hidden: int = 256, width: int = 1024,
                 encoder_hidden: int = 256, beta: float = 1.0, kl_warmup: float = 0.2, seed_poses: int = 10,
                 clip: int = 50, val_per_class: int = 100):
        super().__init__(spec, seed_poses=seed_poses, clip=clip, val_per_class=val_per_class)
        for name, v in (("z_dim", z_dim), ("noise_dim", noise_dim), ("hidden", hidden), ("width", width),
                        ("encoder_hidden", encoder_hidden)):
            _count(name, v, 1)
        if isinstance(beta, bool) or not isinstance(beta, (int, float)) or not beta > 0:
            raise ValueError(f"beta must be a number > 0, got {beta!r}")
        if isinstance(kl_warmup, bool) or not isinstance(kl_warmup, (int, float)) or not 0 <= kl_warmup < 1:
            raise ValueError(f"kl_warmup must lie in [0, 1), got {kl_warmup!r}")
        F_, C = spec.pose_features, self.num_classes
        self.beta, self.kl_warmup, self.progress = float(beta), float(kl_warmup), 1.0
        self.decoder = PoseDecoder(z_dim, C, width, F_)
        self.walk = LatentWalk(z_dim, noise_dim, C, hidden)
        self.encoder = nn.LSTM(2 * F_ + C, encoder_hidden, batch_first=True, bidirectional=True)
        self.to_eps = nn.Linear(2 * encoder_hidden, 2 * noise_dim)
        self.to_z0 = nn.Linear(2 * encoder_hidden, 2 * z_dim)

    def set_progress(self, step: int, total: int) -> None:
        self.progress = step / max(total, 1)

    @property
    def kl_weight(self) -> float:
        if self.kl_warmup <= 0:
            return self.beta
        return self.beta * min(self.progress / self.kl_warmup, 1.0)

    def decode(self, onehot: Tensor, noise: tuple[Tensor, Tensor]) -> Tensor:
        z, _ = self.walk(onehot, noise)
        N, T = z.shape[:2]
        x = self.decoder(torch.cat([z, onehot[:, None].expand(-1, T, -1)], -1))
        return x.reshape(N, T, self.spec.joints, self.spec.dims)

    def sample(self, labels: Tensor, length: int) -> Tensor:
        onehot = self.one_hot(labels)
        N, dev = onehot.shape[0], onehot.device
        noise = (torch.randn(N, self.walk.z_dim, device=dev), torch.randn(N, length - 1, self.walk.noise_dim, device=dev))
        return self.decode(onehot, noise)

    def encode(self, x: Tensor, onehot: Tensor) -> tuple[tuple[Tensor, Tensor], tuple[Tensor, Tensor]]:
        """``(mean, logvar)`` of ``z_0`` ``[N, z_dim]`` and of the steps ``[N, T - 1, noise_dim]``."""
        f = x.flatten(2)
        h, (hn, _) = self.encoder(torch.cat([f[:, :-1], f[:, 1:] - f[:, :-1],
                                             onehot[:, None].expand(-1, f.shape[1] - 1, -1)], -1))
        z0 = self.to_z0(torch.cat([hn[0], hn[1]], -1)).chunk(2, -1)
        eps = self.to_eps(h).chunk(2, -1)
        return z0, eps

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        real = self.real_clips(batch)
        onehot = self.one_hot(self.labels_of(batch))
        (m0, lv0), (me, lve) = self.encode(real, onehot)
        draw = lambda m, lv: m + torch.randn_like(m) * (0.5 * lv).exp()        # noqa: E731
        x = self.decode(onehot, (draw(m0, lv0), draw(me, lve)))
        kl_of = lambda m, lv: 0.5 * (m ** 2 + lv.exp() - 1 - lv).flatten(1).sum(1)   # noqa: E731
        rec = ((x - real) ** 2).flatten(1).sum(1).mean()
        kl = (kl_of(m0, lv0) + kl_of(me, lve)).mean()
        w = self.kl_weight
        return rec + w * kl, {"reconstruction": float(rec.detach()), "kl": float(kl.detach()), "kl_weight": w}

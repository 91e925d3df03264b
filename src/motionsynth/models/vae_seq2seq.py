"""Vae Seq2Seq: Seq2Seq whose final encoder state parameterises a Gaussian latent (GlocalNet Table 1's row).

GlocalNet (Battan et al. 2021) lists "Vae Seq2Seq" in its Table 1 without a recipe. This is
:class:`~.seq2seq.Seq2Seq` (Martinez et al. 2017: tied GRU, residual velocity, sampling-based
loss) with a variational bottleneck between the encoder and the decoder:

    h_S = GRU-encoder(x_1 .. x_S)                          the seed's final state (every layer)
    mu, log sigma^2 = W_mu h_S, W_s h_S                    q(z | seed) = N(mu, sigma^2)
    z = mu + sigma * eps,  eps ~ N(0, I)                   reparameterised sample
    h_0^dec = tanh(W_z z)                                  the decoder starts from z (every layer)
    x^_{t+1} = x_in_t + W h_t + b                          Seq2Seq's residual decoder, from frame S
    L = mean_h w_h ||x^_h - x_h||^2 + beta * KL(q(z | seed) || N(0, I)) / F    w_h = h^-p / mean(h^-p)

with ``h`` the predicted frame's horizon, ``p = horizon_power`` and ``F`` the features per frame
(the KL is per window, the MSE per coordinate, so ``beta`` is the weight of one window's KL against
one frame's squared error).

Generation draws ``z`` from ``q(z | seed)`` (``sample_from: posterior``, the default: the samples
keep the seed's information and differ by ``sigma * eps``) or from the prior ``N(0, I)``
(``sample_from: prior``); every draw of :meth:`generate` is a different sample, so the evaluation
treats the model as stochastic (mean +- std over its seeds) and reports its sample spread.

Choices that are ours (the paper gives none):

* the latent replaces the encoder's final state as the decoder's initial state; the decoder's first
  input is the last seed frame, as in Seq2Seq;
* ``latent_size``, ``beta`` (default 1: the plain ELBO) and a linear KL warm-up over the first
  ``kl_warmup`` share of the training budget (0: none), as the VAE-LSTM's;
* the output layer starts at zero (an untrained model is zero-velocity), as Seq2Seq's;
* only the sampling-based loss: ``scheduled_sampling`` is refused;
* the MSE term weights the ``h``-th predicted frame ``1/h`` (``horizon_power: 1``, inherited from
  Seq2Seq; the weights average 1, so ``beta`` keeps its meaning): on validation it lowered
  ``rel_zv`` on ``cmu_aclstm`` and ``bandai1`` for both seeds tried (``conf/model/vae_seq2seq.yaml``).

Shapes: ``pose`` ``[B, T, J, D]`` -> seed ``[B, S, Fy]`` -> ``z`` ``[B, latent_size]`` -> decoder
state ``[L, B, H]`` -> outputs ``[B, T-1, Fy]`` (frames ``S..T-1`` from the decoder).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from .base import Batch, DataSpec
from .recurrent import check_int, generate_samples, mask_seed_length
from .seq2seq import Seq2Seq

SAMPLE_FROM = ("posterior", "prior")


class VAESeq2Seq(Seq2Seq):

    @classmethod
    def check_hparams(cls, hparams: dict) -> None:
        """The names (:meth:`MotionModel.check_hparams`) and the latent's values; called by
        :func:`motionsynth.training.run.build` before any data is read."""
        super().check_hparams(hparams)
        if "latent_size" in hparams:
            check_int("latent_size", hparams["latent_size"])
        beta, warm = hparams.get("beta", 1.0), hparams.get("kl_warmup", 0.0)
        if isinstance(beta, bool) or not isinstance(beta, (int, float)) or not (math.isfinite(beta) and beta >= 0):
            raise ValueError(f"vae_seq2seq: beta must be a number >= 0, got {beta!r}")
        if isinstance(warm, bool) or not isinstance(warm, (int, float)) or not 0 <= warm < 1:
            raise ValueError(f"vae_seq2seq: kl_warmup must be a share of the budget in [0, 1), got {warm!r}")
        if hparams.get("sample_from", "posterior") not in SAMPLE_FROM:
            raise ValueError(f"vae_seq2seq: sample_from must be one of {SAMPLE_FROM}, got {hparams['sample_from']!r}")
        if hparams.get("scheduled_sampling"):
            raise ValueError("vae_seq2seq: scheduled_sampling must be false (only the sampling-based loss)")

    def __init__(self, spec: DataSpec, hidden_size: int = 1024, num_layers: int = 1, latent_size: int = 64,
                 beta: float = 1.0, kl_warmup: float = 0.0, sample_from: str = "posterior", **kwargs):
        self.check_hparams({"latent_size": latent_size, "beta": beta, "kl_warmup": kl_warmup,
                            "sample_from": sample_from, **kwargs})
        super().__init__(spec, hidden_size, num_layers, **kwargs)
        self.latent_size, self.beta, self.kl_warmup, self.sample_from = latent_size, float(beta), float(kl_warmup), sample_from
        n = hidden_size * num_layers
        self.to_mu = nn.Linear(n, latent_size)
        self.to_logvar = nn.Linear(n, latent_size)
        self.from_z = nn.Linear(latent_size, n)
        self._kl: Tensor | None = None

    def kl_weight(self) -> float:
        if self.kl_warmup <= 0:
            return self.beta
        return self.beta * min(1.0, self.progress / self.kl_warmup)

    def _latent_state(self, state, B: int):
        """The encoder's final state -> ``q(z | seed)`` -> a sample -> the decoder's initial state."""
        h = torch.stack(state[0], 1).reshape(B, -1)                       # [B, L*H]
        mu, logvar = self.to_mu(h), self.to_logvar(h).clamp(-12.0, 8.0)
        if self.training or self.sample_from == "posterior":
            z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        else:
            z = torch.randn_like(mu)
        self._kl = 0.5 * (mu.pow(2) + logvar.exp() - 1.0 - logvar).sum(-1).mean()
        h0 = torch.tanh(self.from_z(z)).view(B, self.num_layers, self.hidden_size)
        return (list(h0.unbind(1)),)

    def _rollout(self, inp: Tensor, cond: Tensor | None, mask: Tensor | None) -> Tensor:
        """Encoder over the ground-truth seed (one GRU call), then the decoder from ``z`` over the
        self-fed steps. The seed's own outputs (frames ``1..S-1``) come from the encoder states."""
        B, N, _ = inp.shape
        S = mask_seed_length(mask, "vae_seq2seq")
        x = inp[:, :S] if cond is None else torch.cat([inp[:, :S], cond[:, :S]], -1)
        enc, state = self.core.sequence(self.encoder(x[:, :S - 1]), None) if S > 1 else (None, None)
        if state is None:
            state = self.core.zero_state(B, inp)
        state = self._latent_state(state, B)
        outs = [] if enc is None else [self._output(enc, inp[:, :S - 1])]
        # the decoder: its first input is the last seed frame (step S-1), then its own outputs
        step = self.core.stepper()
        prev = inp[:, S - 1]
        for t in range(S - 1, N):
            xt = prev if cond is None else torch.cat([prev, cond[:, t]], -1)
            h, state = step(self.encoder(xt), state)
            prev = self._output(h, prev)
            outs.append(prev[:, None])
        return torch.cat(outs, 1)

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        mse, logs = super().loss(batch)
        kl = self._kl
        w = self.kl_weight()
        loss = mse + w * kl / self.state_dim
        logs.update(mse=float(mse.detach()), kl=float(kl.detach()), kl_weight=w)
        return loss, logs

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        """As Seq2Seq's, but every one of the ``num_samples`` copies draws its own latent."""
        return generate_samples(self, seed, controls, labels, length, num_samples)

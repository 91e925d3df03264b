"""SkeletonGAN: the pose-sequence GAN of Cai et al. (ECCV 2018), a GlocalNet Table 3 baseline.

Cai et al.'s first stage ("Deep video generation, prediction and completion of human action
sequences", arXiv 1711.08682) generates a pose sequence from noise: a latent trajectory is walked
by small steps and every latent point is decoded to a pose by one shared pose decoder. Later papers
(c-SkeletonGAN, SA-GCN, GlocalNet) list it as "SkeletonGAN". Sources: the abstract, and the code of
the c-SkeletonGAN authors (zheshiyige/Learning-Diverse-Stochastic-Human-Action-Generators-by-
Learning-Smooth-Latent-Transitions), whose README says it is built on Cai et al.'s code; the pieces
that are c-SkeletonGAN's own (its action classifier) live in :mod:`.cskeleton_gan`. We could not read
either paper's body here: no equation numbers are cited, sizes and steps are the code's.

Generator (labels ``[N]`` -> ``[N, T, J, D]``):

* a **pose decoder** ``G0([z, c])``: ``z_dim`` (12) latent and the one-hot class, one hidden layer of
  ``width`` (1024) with batch normalisation and ReLU, linear to the ``J * D`` coordinates; the same
  decoder for every frame;
* a **latent walk**: ``z_0 ~ U(-1, 1)``; an LSTM (``hidden`` 256) reads per-step noise
  ``eps_t ~ N(0, I)`` (``noise_dim`` 64) with the class and outputs steps ``dz_t = clip(W h_t, -1, 1)``;
  ``z_t = z_{t-1} + dz_t``; pose ``t`` is ``G0([z_t, c])``.

Training, two stages in one run (the stage is set from the trainer's step, ``set_progress``):

1. **Pose stage** (the first ``pretrain_steps`` steps): ``G0`` alone, as a class-conditional WGAN-GP
   on single poses (``poses_per_window`` random poses of every window: 2 x 32 = the code's batch of
   64): a critic ``[pose, c] -> width -> ReLU -> 1``, ``critic_steps`` (5) critic updates, gradient
   penalty weight ``gp_weight`` (10) on random interpolates, then one decoder update; the same noise
   for all of them (the code's). Learning rate ``train.player_lr`` of ``decoder`` and ``critic``
   (the code's 1e-3).
2. **Sequence stage**: ``G0`` frozen (eval mode: its batch-norm statistics from stage 1); the latent
   walk is trained against a sequence discriminator, a bi-directional LSTM (``d_hidden`` 256 per
   direction) over ``[x_t, x_{t+1} - x_t, c]`` whose outputs at every step are concatenated and mapped
   ``-> width -> ReLU -> 1`` logit. Loss: sigmoid cross-entropy, real 1, fake 0 (no smoothing); the
   generator's non-saturating loss plus ``shift_weight`` (0.1) times the sum of squared latent steps
   over the batch (a sum, as the code has it) and ``smooth_weight`` times the batch mean of the summed
   squared pose differences. One discriminator update, then ``g_steps`` (2) generator updates with
   the same noise. Learning rate ``train.lr`` (the code's 1e-4) for the walk and the discriminator.

Adam with betas (0.5, 0.9) throughout; linear layers start from N(0, 0.02) and zero bias (the code's).

Choices that are ours
---------------------
* One run of our trainer holds both stages (the code runs two programs and restores ``G0`` from a
  hand-picked checkpoint); the budgets are ours (the code: 100,000 decoder steps of batch 64, then
  12,500 sequence iterations of batch 32).
* ``smooth_weight`` is 0 here: the 1e-4 smoothness term is in the c-SkeletonGAN code and we cannot
  tell whether Cai et al. had it (:mod:`.cskeleton_gan` sets it). ``shift_weight`` 0.1 is in both.
* In the sequence stage ``G0`` runs in eval mode (its stage-1 running statistics); the code keeps
  batch statistics per frame there while not updating them.
* The lr halvings of the code (every 25,000 / 15,000 steps) lie beyond our budgets: a constant lr.
* Selection on the validation split (:mod:`.adversarial`); the code has no selection (a checkpoint is
  picked by hand). Validation rounds in the pose stage score a walk that has not been trained: they are
  not selectable (:attr:`SkeletonGAN.selectable`; the trainer neither keeps them as ``best.pt`` nor
  counts them for patience). A probe showed why this matters: after 300 pose steps the untrained walk
  scored MMD_seq 0.44 and velocity MMD_seq 0.36 on validation, better on the velocity term than the
  first 600 sequence steps (0.37-0.41 and 0.68-0.74), so selection would otherwise keep the pose stage.
* The lr of the pose stage and that of the sequence stage are per player (``decoder``, ``critic``;
  ``generator``, ``discriminator``).

Shapes: latents ``[N, T, z_dim]``, LSTM ``[N, T - 1, hidden]``, poses ``[N, T, J * D]``; the
discriminator reads ``[N, T - 1, 2 * J * D + C]``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .adversarial import AdversarialModel, Update, _count, bce_logits
from .base import Batch, DataSpec


def normal_init(module: nn.Module, std: float = 0.02) -> nn.Module:
    """Every linear layer of ``module`` from N(0, ``std``), zero bias (the reference code's ``linear``)."""
    for m in module.modules():
        if isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, 0.0, std)
            nn.init.zeros_(m.bias)
    return module


class PoseDecoder(nn.Module):
    """``G0``: ``[..., z_dim + C] -> [..., F]``, one hidden layer with batch normalisation."""

    def __init__(self, z_dim: int, classes: int, width: int, features: int):
        super().__init__()
        self.hidden = nn.Linear(z_dim + classes, width)
        self.norm = nn.BatchNorm1d(width, momentum=0.01, eps=1e-3)     # TF's decay 0.99, epsilon 1e-3
        self.out = nn.Linear(width, features)
        normal_init(self)

    def forward(self, zc: Tensor) -> Tensor:
        lead = zc.shape[:-1]
        h = torch.relu(self.norm(self.hidden(zc.reshape(-1, zc.shape[-1]))))
        return self.out(h).reshape(*lead, -1)


class LatentWalk(nn.Module):
    """The latent trajectory ``z_0 .. z_{T-1}`` (``[N, T, z_dim]``) and its steps ``dz`` from noise."""

    def __init__(self, z_dim: int, noise_dim: int, classes: int, hidden: int):
        super().__init__()
        self.z_dim, self.noise_dim = z_dim, noise_dim
        self.lstm = nn.LSTM(noise_dim + classes, hidden, batch_first=True)
        with torch.no_grad():                                 # TF's forget_bias 1.0
            self.lstm.bias_ih_l0[hidden:2 * hidden].fill_(1.0)
        self.step = normal_init(nn.Linear(hidden, z_dim))

    def noise(self, n: int, T: int, device) -> tuple[Tensor, Tensor]:
        return (torch.rand(n, self.z_dim, device=device) * 2 - 1, torch.randn(n, T - 1, self.noise_dim, device=device))

    def forward(self, onehot: Tensor, noise: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor]:
        z0, eps = noise
        h, _ = self.lstm(torch.cat([eps, onehot[:, None].expand(-1, eps.shape[1], -1)], -1))
        dz = self.step(h).clamp(-1.0, 1.0)
        return torch.cat([z0[:, None], z0[:, None] + dz.cumsum(1)], 1), dz


class SequenceCritic(nn.Module):
    """Bi-LSTM over ``[x_t, x_{t+1} - x_t, c]``, every step's output concatenated, -> one logit."""

    def __init__(self, features: int, classes: int, clip: int, hidden: int, width: int):
        super().__init__()
        self.lstm = nn.LSTM(2 * features + classes, hidden, batch_first=True, bidirectional=True)
        with torch.no_grad():
            for b in (self.lstm.bias_ih_l0, self.lstm.bias_ih_l0_reverse):
                b[hidden:2 * hidden].fill_(1.0)
        self.head = normal_init(nn.Sequential(nn.Linear((clip - 1) * 2 * hidden, width), nn.ReLU(), nn.Linear(width, 1)))

    def forward(self, x: Tensor, onehot: Tensor | None) -> Tensor:
        x = x.flatten(2)
        steps = [x[:, :-1], x[:, 1:] - x[:, :-1]]
        if onehot is not None:
            steps.append(onehot[:, None].expand(-1, x.shape[1] - 1, -1))
        h, _ = self.lstm(torch.cat(steps, -1))
        return self.head(h.flatten(1))[:, 0]


class SkeletonGAN(AdversarialModel):
    """SkeletonGAN (module docstring). Hyperparameters: ``z_dim``, ``noise_dim``, ``hidden`` (walk LSTM),
    ``width`` (decoder, critics' heads), ``d_hidden`` (sequence critic per direction), ``pretrain_steps``
    (the pose stage), ``critic_steps``, ``gp_weight``, ``poses_per_window``, ``g_steps``, ``shift_weight``,
    ``smooth_weight``, plus :class:`~.adversarial.ClipGenerator`'s ``seed_poses``, ``clip``, ``val_per_class``."""

    def __init__(self, spec: DataSpec, z_dim: int = 12, noise_dim: int = 64, hidden: int = 256, width: int = 1024,
                 d_hidden: int = 256, pretrain_steps: int = 1000, critic_steps: int = 5, gp_weight: float = 10.0,
                 poses_per_window: int = 2, g_steps: int = 2, shift_weight: float = 0.1, smooth_weight: float = 0.0,
                 seed_poses: int = 10, clip: int = 50, val_per_class: int = 100):
        super().__init__(spec, seed_poses=seed_poses, clip=clip, val_per_class=val_per_class)
        for name, v, lo in (("z_dim", z_dim, 1), ("noise_dim", noise_dim, 1), ("hidden", hidden, 1), ("width", width, 1),
                            ("d_hidden", d_hidden, 1), ("pretrain_steps", pretrain_steps, 0),
                            ("critic_steps", critic_steps, 1), ("poses_per_window", poses_per_window, 1),
                            ("g_steps", g_steps, 1)):
            _count(name, v, lo)
        for name, v in (("gp_weight", gp_weight), ("shift_weight", shift_weight), ("smooth_weight", smooth_weight)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
                raise ValueError(f"{name} must be a number >= 0, got {v!r}")
        F_, C = spec.pose_features, self.num_classes
        self.pretrain_steps, self.critic_steps, self.gp_weight = pretrain_steps, critic_steps, float(gp_weight)
        self.poses_per_window, self.g_steps = poses_per_window, g_steps
        self.shift_weight, self.smooth_weight = float(shift_weight), float(smooth_weight)
        self.decoder = PoseDecoder(z_dim, C, width, F_)
        self.walk = LatentWalk(z_dim, noise_dim, C, hidden)
        self.pose_critic = normal_init(nn.Sequential(nn.Linear(F_ + C, width), nn.ReLU(), nn.Linear(width, 1)))
        self.critic = SequenceCritic(F_, C, self.clip, d_hidden, width)
        self.step_index = 0

    # ------------------------------------------------------------------ players and stages
    def players(self) -> dict[str, list[nn.Parameter]]:
        return {"generator": list(self.walk.parameters()), "decoder": list(self.decoder.parameters()),
                "critic": list(self.pose_critic.parameters()), "discriminator": list(self.critic.parameters())}

    def set_progress(self, step: int, total: int) -> None:
        self.step_index = int(step)

    @property
    def pose_stage(self) -> bool:
        return self.step_index < self.pretrain_steps

    @property
    def selectable(self) -> bool:
        """Rounds of the pose stage are no checkpoint candidates: the latent walk is not trained yet (the
        trainer logs them with ``selectable: 0``)."""
        return not self.pose_stage

    # ------------------------------------------------------------------ generation
    def decode(self, z: Tensor, onehot: Tensor) -> Tensor:
        """Poses ``[N, T, J, D]`` of latents ``[N, T, z_dim]`` and classes ``[N, C]``."""
        N, T = z.shape[:2]
        x = self.decoder(torch.cat([z, onehot[:, None].expand(-1, T, -1)], -1))
        return x.reshape(N, T, self.spec.joints, self.spec.dims)

    def sample(self, labels: Tensor, length: int, noise: tuple[Tensor, Tensor] | None = None) -> Tensor:
        return self.walk_and_decode(self.one_hot(labels), length, noise)[0]

    def walk_and_decode(self, onehot: Tensor, length: int, noise=None) -> tuple[Tensor, Tensor]:
        noise = noise if noise is not None else self.walk.noise(onehot.shape[0], length, onehot.device)
        z, dz = self.walk(onehot, noise)
        return self.decode(z, onehot), dz

    # ------------------------------------------------------------------ training
    def adversarial_step(self, batch: Batch, update: Update) -> dict[str, float]:
        return self._pose_step(batch, update) if self.pose_stage else self._sequence_step(batch, update)

    def _pose_step(self, batch: Batch, update: Update) -> dict[str, float]:
        B, T = batch.pose.shape[:2]
        t = torch.randint(0, T, (B, self.poses_per_window), device=batch.pose.device)
        real = batch.pose[torch.arange(B, device=t.device)[:, None], t].flatten(2).flatten(0, 1)   # [B*k, F]
        onehot = self.one_hot(self.labels_of(batch)).repeat_interleave(self.poses_per_window, 0)
        z = torch.rand(real.shape[0], self.walk.z_dim, device=real.device) * 2 - 1
        critic = lambda x: self.pose_critic(torch.cat([x, onehot], -1))[:, 0]   # noqa: E731
        peak = 0.0
        for _ in range(self.critic_steps):
            with torch.no_grad():
                fake = self.decoder(torch.cat([z, onehot], -1))
            a = torch.rand(real.shape[0], 1, device=real.device)
            mix = (real + a * (fake - real)).requires_grad_(True)
            grad, = torch.autograd.grad(critic(mix).sum(), mix, create_graph=True)
            cr, cf = critic(real), critic(fake)
            c_loss = cf.mean() - cr.mean() + self.gp_weight * ((grad.norm(dim=1) - 1) ** 2).mean()
            update("critic", c_loss)
            peak = max(peak, float(cr.detach().abs().max()), float(cf.detach().abs().max()))
        g_loss = -critic(self.decoder(torch.cat([z, onehot], -1))).mean()
        update("decoder", g_loss)
        return {"d_loss": float(c_loss.detach()), "g_loss": float(g_loss.detach()),
                "wasserstein": float((cr.mean() - cf.mean()).detach()),
                "stage": 1.0, "logit_absmax": peak}

    def generator_terms(self, fake: Tensor, dz: Tensor, real: Tensor, onehot: Tensor, labels: Tensor) -> dict[str, Tensor]:
        """The sequence stage's generator loss terms (c-SkeletonGAN adds its classifier's)."""
        return {"adv": bce_logits(self.critic(fake, onehot), 1.0),
                "shift": self.shift_weight * (dz ** 2).sum(),
                "smooth": self.smooth_weight * ((fake[:, 1:] - fake[:, :-1]) ** 2).flatten(1).sum(1).mean()}

    def _sequence_step(self, batch: Batch, update: Update) -> dict[str, float]:
        self.decoder.eval()                                     # frozen, stage-1 statistics
        real = self.real_clips(batch)
        labels = self.labels_of(batch)
        onehot = self.one_hot(labels)
        noise = self.walk.noise(real.shape[0], self.clip, real.device)
        fake, dz = self.walk_and_decode(onehot, self.clip, noise)
        dr, df = self.critic(real, onehot), self.critic(fake.detach(), onehot)
        d_loss = bce_logits(dr, 1.0) + bce_logits(df, 0.0)
        update("discriminator", d_loss)
        peak = max(float(dr.detach().abs().max()), float(df.detach().abs().max()))
        for i in range(self.g_steps):
            if i:                                               # the same noise, the walk's new weights
                fake, dz = self.walk_and_decode(onehot, self.clip, noise)
            terms = self.generator_terms(fake, dz, real, onehot, labels)
            g_loss = sum(terms.values())
            update("generator", g_loss)
        return {"d_loss": float(d_loss.detach()), "g_loss": float(g_loss.detach()), "stage": 2.0, "logit_absmax": peak,
                "d_real": float(torch.sigmoid(dr.detach()).mean()), "d_fake": float(torch.sigmoid(df.detach()).mean()),
                **{f"g_{k}": float(v.detach()) for k, v in terms.items()}}

    def train(self, mode: bool = True) -> "SkeletonGAN":
        super().train(mode)
        if mode and not self.pose_stage:
            self.decoder.eval()
        for p in self.decoder.parameters():                    # frozen after the pose stage
            p.requires_grad_(self.pose_stage)
        return self

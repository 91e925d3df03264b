"""cRBM: the conditional restricted Boltzmann machine of Taylor, Hinton and Roweis (NIPS 2006).

The VAE-LSTM paper's Tables 1-2 baseline "CRBM [1]". Gaussian visible units ``v`` (one frame, unit
variance: the features are normalised with train-split statistics), binary hidden units ``h``, and
autoregressive connections from the previous ``order`` frames ``u = [v_{t-1} .. v_{t-N}]`` (plus the
conditioning ``c``: given controls, class one-hot) to both layers, as dynamic biases:

    b^ = b + A [u; c],   c^ = c_h + B [u; c]                                     (Taylor et al., eqs. 1-3)
    E(v, h | u) = 1/2 ||v - b^||^2 - c^.h - v.W^T h
    p(h_j = 1 | v, u) = sigmoid(c^_j + (W v)_j)                                   (eq. 4)
    p(v | h, u) = N(b^ + W^T h, I)                                                (eq. 5)
    F(v | u) = 1/2 ||v - b^||^2 - sum_j softplus(c^_j + (W v)_j)                   free energy

Training is contrastive divergence with ``cd_k`` steps of alternating Gibbs sampling started at the
data (CD-1 and CD-15 are the configs ``crbm`` and ``crbm_cd15``). Its update for every parameter
``theta`` is ``<dF/dtheta>_data - <dF/dtheta>_recon``, which is exactly the gradient of the surrogate

    L_CD = mean_t [F(v_t | u_t) - F(sg(v~_t) | u_t)]     (sg: no gradient through the chain's end v~)

so the model trains through the shared trainer and optimiser by ``loss.backward()``
(``tests/test_model_crbm.py`` checks the gradient against the closed-form CD update). The loss
value is not an objective to select on: the trainer selects on the validation roll-out criterion,
and the reconstruction error ``recon_mse`` is logged beside it.

Generation (Taylor et al. Sec. 3.2): frame by frame, the past ``order`` frames (seed, then the
model's own frames) fix the dynamic biases; ``gibbs_steps`` alternating Gibbs steps start from the
previous frame; the last step takes the visible mean from the hidden probabilities, not a sample
(Taylor's mean-field final step; the visibles are mean-field in every step, no Gaussian noise is
added to them). Every roll-out samples the hidden states anew: the model is stochastic (the
evaluation suites measure it so and report mean +- std over their seeds). The frame loop runs on
one thread (:func:`~.base.one_thread`: thousands of small kernels, each a thread barrier with
more; a validation roll-out took 47 s on 2 threads next to another job and 3.6 s on one), and
hidden states are drawn as ``u < p`` with uniform ``u`` (:meth:`CRBM._sample`: faster than
``torch.bernoulli`` on CPU). The number of Gibbs steps hardly matters for our trained models
(validation ``rel_zv`` 0.2228 / 0.2221 / 0.2222 with 1 / 5 / 30 steps, CD-1): see below.

Protocols as the recurrent baselines': under ``control_mode: predict`` (VAE-LSTM Table 1) the 3
control signals are part of the visible frame (the model generates its own controls); under
``given`` (Table 2) the ground-truth controls of the frame being generated join the conditioning.
Class one-hots, when the dataset has classes, join the conditioning too.

Choices that are ours: the visible reconstruction in the CD chain is the mean ``b^ + W^T h`` (Taylor's
code, which also uses mean-field visibles), hidden states are sampled in the chain; the seed is
padded with its first frame when shorter than ``order``; initial weights N(0, 0.01^2).

Departures from the paper's training (``conf/model/crbm.yaml``, ``crbm_cd15.yaml``, and the crops
in ``conf/dataset/bandai2_locomotion.yaml: training.model_overrides``), for a budget of about 80 s
per stage on 2 CPU cores where Taylor et al. train for hundreds of epochs:

* learning rate 2e-2 (Taylor: 1e-3; SGD, momentum 0.9 and weight decay 2e-4 kept) after 20 warm-up
  steps, cosine decay to 5 %; CD-1: 2,000 steps on 120-frame crops of the 240-frame windows; CD-15
  (about 4x the cost per frame): 1,500 steps on 60-frame crops (900 and 560 before: validation
  ``rel_zv`` 0.22 and 0.25 then, 0.20 and 0.21 now, still falling). Measured on the validation split
  (``val/rel_zv``, :mod:`motionsynth.training.criteria`; zero-velocity = 1): after 600 CD-1 steps lr
  1e-3 reached 0.44, 3e-3 0.32, 1.2e-2 0.26, 2e-2 0.24; SGD with momentum 0.97 (0.23) and Adam at
  3e-3 (0.21) ended a little lower, but their roll-outs diverged on the way (``rel_zv`` 1e12 and
  2e3 at some validations), so the paper's optimiser stays. A 40-step run (all of it inside the
  warm-up) scored 8.7: untrained, not broken (the mean pose scores 10.2). Trained, the first
  generated frame's error is 1/7 of zero-velocity's (validation, CD-1).
* **Whitened conditioning** (``whiten``, ours; ``sizes.default`` and ``smoke``, not ``paper``). The
  conditioning ``[v_{t-1} .. v_{t-6}]`` of 60-fps frames (linearly up-sampled 30-fps capture) is
  nearly collinear: 271 of the 400 eigenvalues of its covariance lie below 1e-3 (the largest: 79), so
  gradient descent on the raw autoregressive weights ``A`` is ill-conditioned and improves slowly
  (raw conditioning, validation ``rel_zv``: 0.199 after 2,000 CD-1 steps, 0.175 after 8,000, still
  falling). With ``whiten: e`` the dynamic biases read ``(u - m) P`` instead of ``u``, where ``m`` is
  the train split's mean conditioning and ``P = V (L + e max(L))^-1/2 V^T`` its ZCA whitening with a
  floor under the eigenvalues (:meth:`CRBM.fit_statistics`, fitted once before the first step). It
  is an invertible linear change of the conditioning, so the model family is Taylor's (``A P^T`` is
  an ordinary ``A``, :meth:`CRBM.dynamic_weights` folds it so); what changes is the optimisation (and
  what the initialisation and weight decay mean). Validation ``rel_zv`` on ``bandai2_locomotion``,
  CD-1, 2,000 steps: raw 0.199; floor ``e`` 1e-2 0.189, 3e-3 0.175, **1e-3 0.164**, 1e-4 0.60 (its
  roll-outs diverge early: the floor keeps the near-null directions, the up-sampling's, quiet). With
  given controls 0.272 -> 0.225; CD-15 (1,500 steps) 0.213 -> 0.172, given controls 0.292 -> 0.223.
  The least-squares linear autoregression on the same past (no hidden units) scores 0.16.
* The runs still do not meet the ``converged`` test. Whitened CD-1 at 3,000 / 4,000 / 6,000 steps:
  0.160 / 0.159 / 0.156, still 2-4 % better over the last 20 % of each, while the roll-out criterion
  moves 2-3 % from one validation to the next late in training (0.156 then 0.161 at 5,400 and
  6,000 steps of the 6,000-step run): the budgets stay at 2,000 and 1,500 steps. At this budget
  ``W`` and ``B`` barely leave their initialisation (std 0.011 and 0.0099 after 2,000 whitened CD-1
  steps, from 0.01; the CD-1 reconstruction is already close to the data once ``A``
  predicts well): the trained cRBM acts mostly as its autoregressive part, and its samples under
  different seeds differ little.

Shapes: ``pose`` ``[B, T, J, D]`` -> frames ``[B, T, Fy]`` -> past ``[B, T-N, N*Fy]`` (one unfold, no
loop over frames in training) -> ``v``, ``h`` ``[B, T-N, Fy]``, ``[B, T-N, hidden_size]``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .base import Batch, DataSpec, MotionModel, one_thread
from .recurrent import (CONTROL_MODES, check_family, check_int, default_seed_frames, generate_samples,
                        rollout_output, seed_inputs, train_crop)


class CRBM(MotionModel):
    family = None  # type: ignore[assignment]  # the dataset's window family (training.family)
    uses_controls = True
    uses_labels = True

    def __init__(self, spec: DataSpec, hidden_size: int = 150, order: int = 3, cd_k: int = 1,
                 gibbs_steps: int = 30, control_mode: str = "predict", seed_frames: int | None = None,
                 family: str | None = None, train_window: int | None = None, init_std: float = 0.01,
                 whiten: float | None = None):
        super().__init__(spec)
        self.hidden_size = check_int("hidden_size", hidden_size)
        self.order = check_int("order", order)
        self.cd_k = check_int("cd_k", cd_k)
        self.gibbs_steps = check_int("gibbs_steps", gibbs_steps)
        if control_mode not in CONTROL_MODES:
            raise ValueError(f"control_mode must be one of {CONTROL_MODES}, got {control_mode!r}")
        if not (isinstance(init_std, (int, float)) and init_std > 0):
            raise ValueError(f"init_std must be a number > 0, got {init_std!r}")
        if whiten is not None and not (isinstance(whiten, (int, float)) and not isinstance(whiten, bool)
                                       and 0 < whiten <= 1):
            raise ValueError(f"whiten must be null or a number in (0, 1] (the eigenvalue floor as a fraction "
                             f"of the largest), got {whiten!r}")
        self.whiten = None if whiten is None else float(whiten)
        self.train_window = None if train_window is None else check_int("train_window", train_window, order + 1)
        self.control_mode = control_mode
        self.seed_frames = default_seed_frames(spec, seed_frames)
        self.family = check_family(family)
        self.pose_dim = spec.pose_features
        self.ctrl_dim = spec.controls
        self.predict_controls = control_mode == "predict" and spec.controls > 0
        self.given_controls = control_mode == "given" and spec.controls > 0
        self.state_dim = self.pose_dim + (self.ctrl_dim if self.predict_controls else 0)                    # Fy
        self.cond_dim = self.order * self.state_dim + (self.ctrl_dim if self.given_controls else 0) + spec.num_classes
        g = lambda *s: nn.Parameter(torch.randn(*s) * init_std)  # noqa: E731
        self.W = g(hidden_size, self.state_dim)            # visible-hidden
        self.A = g(self.state_dim, self.cond_dim)          # past (+ conditioning) -> visible biases
        self.B = g(hidden_size, self.cond_dim)             # past (+ conditioning) -> hidden biases
        self.b_v = nn.Parameter(torch.zeros(self.state_dim))
        self.b_h = nn.Parameter(torch.zeros(hidden_size))
        # whiten: the conditioning is used as (u - cond_mean) @ cond_proj (fit_statistics; identity until then)
        self.register_buffer("cond_mean", torch.zeros(self.cond_dim))
        self.register_buffer("cond_proj", torch.eye(self.cond_dim))
        self.register_buffer("cond_fitted", torch.zeros((), dtype=torch.long))

    # ------------------------------------------------------------------ features
    def _frames(self, pose: Tensor, controls: Tensor | None) -> Tensor:
        y = self.flat(pose)
        if self.predict_controls:
            if controls is None:
                raise ValueError("control_mode 'predict' on a dataset with controls needs the batch's controls")
            y = torch.cat([y, controls[:, :y.shape[1]].to(y.dtype)], -1)
        return y

    def _extra(self, controls: Tensor | None, labels: Tensor | None, B: int, T: int, like: Tensor) -> Tensor | None:
        """Conditioning beyond the past frames, for frames ``0..T-1``: ``[B, T, Fc']`` or ``None``."""
        parts = []
        if self.given_controls:
            if controls is None or controls.shape[1] < T:
                got = None if controls is None else tuple(controls.shape)
                raise ValueError(f"control_mode 'given' needs controls [B, {T}, 3], got {got}")
            parts.append(controls[:, :T].to(like.dtype))
        if self.spec.num_classes > 0:
            if labels is None:
                raise ValueError(f"CRBM is class-conditioned ({self.spec.num_classes} classes): pass labels [B] or [B, T]")
            labels = labels.to(like.device).long()
            oh = F.one_hot(labels, self.spec.num_classes).to(like.dtype)
            parts.append(oh[:, None].expand(B, T, -1) if labels.dim() == 1 else oh[:, :T])
        return torch.cat(parts, -1) if parts else None

    def _past(self, y: Tensor) -> Tensor:
        """``[B, T, Fy]`` -> the previous ``order`` frames of frames ``order..T-1``, newest first:
        ``[B, T-order, order*Fy]``."""
        N = self.order
        win = y.unfold(1, N, 1)[:, :-1]                     # [B, T-N, Fy, N]: frames t-N .. t-1
        return win.flip(-1).transpose(-1, -2).reshape(y.shape[0], y.shape[1] - N, N * y.shape[2])

    # ------------------------------------------------------------------ the energy model
    def dynamic_weights(self) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``(A', B', b', c')`` with ``b^ = b' + u A'^T`` and ``c^ = c' + u B'^T`` for the raw conditioning
        ``u``. Without ``whiten``: ``A, B, b, c``. With it the model's ``A``, ``B`` act on the whitened
        ``(u - m) P``, folded into the weights: ``A' = A P^T``, ``b' = b - m A'^T`` (likewise ``B``, ``c``);
        a ``[*, C] x [C, C]`` product per step instead of one per frame."""
        if self.whiten is None:
            return self.A, self.B, self.b_v, self.b_h
        A, B = self.A @ self.cond_proj.t(), self.B @ self.cond_proj.t()
        return A, B, self.b_v - self.cond_mean @ A.t(), self.b_h - self.cond_mean @ B.t()

    def biases(self, cond: Tensor, weights: tuple[Tensor, Tensor, Tensor, Tensor] | None = None
               ) -> tuple[Tensor, Tensor]:
        """Dynamic biases ``b^``, ``c^`` from the conditioning ``[..., cond_dim]`` (eqs. 2-3); ``weights``:
        :meth:`dynamic_weights`, when the caller has them already."""
        A, B, bv, bh = self.dynamic_weights() if weights is None else weights
        return bv + cond @ A.t(), bh + cond @ B.t()

    @torch.no_grad()
    def fit_statistics(self, train, batch_size: int = 256) -> None:
        """``whiten``: fit the conditioning's whitening on ``train`` (a
        :class:`~motionsynth.training.data.WindowData` of the train split), once. ``cond_mean`` is the
        mean of the conditioning over every frame of every train window (whole windows, float64 sums) and
        ``cond_proj = V (L + whiten * max(L))^-1/2 V^T`` from the eigendecomposition ``V L V^T`` of its
        covariance (ZCA, with a floor under the eigenvalues). The trainer calls it before the first step
        and after every round; it is a no-op once fitted (``best.pt`` and ``last.pt`` carry it), and
        without ``whiten``."""
        if self.whiten is None or int(self.cond_fitted):
            return
        C = self.cond_dim
        s1 = torch.zeros(C, dtype=torch.float64)
        s2 = torch.zeros(C, C, dtype=torch.float64)
        n = 0
        was_training = self.training
        self.eval()                                       # whole windows, no training crop
        try:
            for idx in train.batch_indices(batch_size, False, 0):
                _, cond = self._windows(train.batch(idx))
                u = cond.reshape(-1, C).double().cpu()
                s1 += u.sum(0)
                s2 += u.T @ u
                n += u.shape[0]
        finally:
            self.train(was_training)
        if n < 2:
            raise ValueError(f"CRBM.fit_statistics: the train split gives {n} conditioning frames, need >= 2")
        mean = s1 / n
        lam, V = torch.linalg.eigh(s2 / n - torch.outer(mean, mean))
        lam = lam.clamp(min=0.0)
        lam = lam + self.whiten * float(lam.max())
        if float(lam.max()) <= 0:
            raise ValueError("CRBM.fit_statistics: the train split's conditioning is constant")
        self.cond_mean.copy_(mean)
        self.cond_proj.copy_((V * lam.rsqrt()) @ V.T)
        self.cond_fitted.fill_(1)

    def hidden_prob(self, v: Tensor, ch: Tensor) -> Tensor:
        """``p(h = 1 | v, u)`` (eq. 4) for ``v`` ``[..., Fy]`` and hidden biases ``c^`` ``[..., hidden_size]``."""
        return torch.sigmoid(ch + v @ self.W.t())

    def visible_mean(self, h: Tensor, bv: Tensor) -> Tensor:
        """The mean of ``p(v | h, u)`` (eq. 5)."""
        return bv + h @ self.W

    def free_energy(self, v: Tensor, cond: Tensor) -> Tensor:
        """``F(v | cond)`` per frame ``[...]``."""
        return self._free_energy(v, *self.biases(cond))

    def _free_energy(self, v: Tensor, bv: Tensor, ch: Tensor) -> Tensor:
        return 0.5 * (v - bv).pow(2).sum(-1) - F.softplus(ch + v @ self.W.t()).sum(-1)

    @staticmethod
    def _sample(p: Tensor) -> Tensor:
        """Binary states with probabilities ``p``: 1 where ``u < p``, ``u ~ U[0, 1)`` (the Bernoulli draw;
        ``sign(p - u)`` clamped at 0 is 3x faster on CPU than ``(u < p).float()``, itself 3x faster than
        ``torch.bernoulli``, measured; the same states for the same random stream)."""
        return (p - torch.rand_like(p)).sign_().clamp_(min=0.0)

    @torch.no_grad()
    def gibbs(self, v: Tensor, cond: Tensor, steps: int, mean_last: bool = False,
              biases: tuple[Tensor, Tensor] | None = None) -> Tensor:
        """``steps`` alternating Gibbs steps from ``v`` ``[..., Fy]``: sample ``h ~ p(h | v)`` (eq. 4),
        take the visible mean (eq. 5); with ``mean_last`` the final step uses the hidden probabilities
        instead of a sample. ``biases``: the dynamic biases of ``cond`` when the caller has them already.
        Each half-step is one ``addmm`` over all frames (the leading dimensions flattened)."""
        bv, ch = self.biases(cond) if biases is None else biases
        shape = v.shape
        v = v.reshape(-1, shape[-1])
        bv = bv.expand(shape).reshape(-1, shape[-1])
        ch = ch.expand(*shape[:-1], ch.shape[-1]).reshape(-1, ch.shape[-1])
        Wt = self.W.t()
        for i in range(steps):
            ph = torch.addmm(ch, v, Wt).sigmoid_()
            h = ph if (mean_last and i == steps - 1) else self._sample(ph)
            v = torch.addmm(bv, h, self.W)
        return v.reshape(shape)

    def _windows(self, batch: Batch) -> tuple[Tensor, Tensor]:
        """Visible frames ``order..T-1`` and their conditioning, ``[B, T-N, Fy]`` and ``[B, T-N, cond_dim]``."""
        pose, controls, labels = train_crop(batch, self.train_window if self.training else None)
        T = pose.shape[1]
        if T <= self.order:
            raise ValueError(f"CRBM of order {self.order} needs windows of > {self.order} frames, got {T}")
        y = self._frames(pose, controls)
        cond = self._past(y)
        extra = self._extra(controls, labels, y.shape[0], T, y)
        if extra is not None:
            cond = torch.cat([cond, extra[:, self.order:]], -1)
        return y[:, self.order:], cond

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        """CD-``cd_k``: the free-energy surrogate whose gradient is the CD update (module docstring)."""
        v0, cond = self._windows(batch)
        bv, ch = self.biases(cond)                         # once: the chain and both free energies share them
        vk = self.gibbs(v0, cond, self.cd_k, biases=(bv.detach(), ch.detach()))
        loss = (self._free_energy(v0, bv, ch) - self._free_energy(vk, bv, ch)).mean()
        err = (vk - v0).pow(2)
        logs = {"recon_mse": float(err.mean()), "pose_mse": float(err[..., :self.pose_dim].mean())}
        return loss, logs

    # ------------------------------------------------------------------ synthesis
    @torch.no_grad()
    def rollout(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                length: int = 240) -> tuple[Tensor, Tensor | None]:
        """One sample to ``length`` frames from ``seed`` ``[B, S, J, D]`` and its controls
        ``[B, length, 3]`` (normalised; under ``predict`` the seed's then the generated ones), as
        :meth:`RecurrentBaseline.rollout`. Without a seed it starts from the mean pose."""
        seed, controls, seed_ctrl = seed_inputs(self, seed, controls, labels, length)
        B, S = seed.shape[:2]
        if S >= length:
            return seed[:, :length], (controls[:, :length] if controls is not None and self.ctrl_dim else None)
        y = self._frames(seed, seed_ctrl)                                   # [B, S, Fy]
        extra = self._extra(controls, labels, B, length, y)
        frames = [y[:, 0]] * max(self.order - S, 0) + list(y.unbind(1))    # padded with the first frame
        weights = self.dynamic_weights()
        with one_thread(y.device):                 # thousands of small kernels: one thread (base.one_thread)
            for t in range(S, length):
                past = torch.cat(frames[-1:-self.order - 1:-1], -1)          # newest first
                cond = past if extra is None else torch.cat([past, extra[:, t]], -1)
                frames.append(self.gibbs(frames[-1], cond, self.gibbs_steps, mean_last=True,
                                         biases=self.biases(cond, weights)))
        return rollout_output(self, seed, torch.stack(frames[-(length - S):], 1), seed_ctrl, controls, length)

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        """``[B*num_samples, length, J, D]``; the samples of one input differ (the hidden units are
        sampled), ``out[:, :S] == seed``."""
        return generate_samples(self, seed, controls, labels, length, num_samples)

    @torch.no_grad()
    def predict(self, batch: Batch) -> Tensor:
        T = batch.pose.shape[1]
        return self.generate(batch.pose[:, :min(self.seed_frames, T)], batch.controls, batch.labels, length=T)

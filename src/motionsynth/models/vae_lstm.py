"""VAE-LSTM: the recurrent variational autoencoder of Habibie et al. 2017,
"A Recurrent Variational Autoencoder for Human Motion Synthesis" (BMVC), sections 3-4.

Architecture (Fig. 1), with the paper's sizes (``sizes.paper`` in ``conf/model/vae_lstm.yaml``)::

    controls C [B,T,3] --dropout--> control-signal encoder (eq. 6) ------> h^c [B,T/4,128]
    poses    X [B,T,63] -dropout--> inference network (eq. 6) -> (mu, logvar) [B,T/4,128] each
                                    z_t = mu_t + sigma_t * eps                  (eq. 3)
    (z_t or c_{t-1}, h^c_t) --> modified LSTM cell (eqs. 7-9) --> c_t; canvas m_c = [c_1 .. c_{T/4}]
    canvas [B,T/4,128] --> 2 x (upsample x2, conv 25, ELU) --> 1x1 conv --> X_hat [B,T,63]

Shapes: ``B`` batch, ``T`` frames (240 in the paper, any multiple of 4 here), ``T' = T/4``
pooled steps, ``P = J*D`` pose features (63 = 21 joints x 3 in the paper), ``H`` LSTM units
(128), ``Hc`` control features (128). Every tensor inside is time-major ``[B, T, C]``, like
the interface; convolutions run on that layout directly (:func:`conv_time`).

Where the paper is vague, and what this file does
--------------------------------------------------
* **Pooling factor.** Sec. 4.2 says "both pooling window and stride are of size 1, thus reducing
  the dimensionality from 240 to 60 frames"; a stride of 1 cannot reduce anything, and
  240 -> 60 with two pooling layers (Sec. 4.3: "as we use two max pooling layers in the
  encoder, this corresponds to 4 initial frames") needs window = stride = 2 in each.
  So each encoder block is conv (width 25, 'same' zero padding) -> ELU -> max-pool(2, 2), and
  the overall factor is ``2 ** blocks`` = 4. Eq. 6 applies ELU before the pool; ELU is
  monotone, so ``pool(elu(x)) == elu(pool(x))`` and we pool first (half the ELU work).
* **Inference network input.** Fig. 1 and Sec. 4.2 ("(63, 25)*64") feed it the 63 joint
  coordinates only, so it does not see the controls: q(z_t | x) (Sec. 3.2). Here its input
  has ``spec.joints * spec.dims`` channels.
* **Posterior parameters.** The inference network's last block has 256 channels; we read
  256 = 2 x 128 (mean and log-variance of a 128-d latent) but, rather than splitting the
  ELU'd features (which would bound mu and log sigma below by -1), add a per-step linear map
  (a 1x1 conv) from those features to ``(mu, logvar)``, each ``[B, T', H]``.
* **Latent size.** Eq. 9 applies the same ``W_c`` to ``z_t`` (training) and to ``c_{t-1}``
  (test), so dim z = dim c = ``hidden`` (128). It is not a separate hyperparameter.
* **Training as generation runs** (ours, ``train_mode: rollout``, the presets' setting). The paper
  trains with the cell state set to a fresh posterior latent ``z_t`` at every pooled step (below,
  ``train_mode: paper``) but generates from ONE latent ``z_1`` with the cell fed back on itself. Trained
  the paper's way, the model learnt to ignore its latent (posterior and prior rows agreed to 8 digits,
  KL 0.011 nats per window): the decoder never needs ``z_t`` because the controls and the convolutional
  decoder explain the window, and generation sees a state the cell was never trained on. In ``rollout``
  mode training does what Algorithm 1 does: ``z_1 ~ q(z_1 | first 4 frames)`` (the Table 1 protocol's
  posterior, :meth:`first_posterior`), then ``c_1 = cell(z_1, h_1)``, ``c_t = cell(c_{t-1}, h_t)``
  with gradients through all ``T'`` steps (:meth:`VaeLstmCell.unroll`), the KL of that single latent.
* **The latent at every step** (ours, ``latent_every_step``): ``z_1`` also enters every step's gates and
  candidate through a linear map ``U z_1`` added to the control terms (:meth:`with_latent`). Without it
  the eq. 9 cell (no additive memory: ``c_t = ELU(f * W_c c_{t-1} + ...)``) forgot ``z_1`` within a few
  steps: prior and posterior rows agreed to 4 digits from frame 70 on, and prior samples differed by
  1.4 mm. With it the posterior (4 frames) halves the prior's frame-70 pose error on validation windows.
* **Eq. 9, training case** (``train_mode: paper``). "We set the cell state of the LSTM at every time step equal to
  the corresponding latent code": the state fed into step t is ``z_t`` in place of
  ``c_{t-1}``, in the gates (eqs. 7-8) as well as in eq. 9. Algorithm 1 writes the cell as
  one function ``RNN^dec(state, h^c_t)`` whose state is ``z_1`` at t=1 and ``c(t-1)`` after;
  during training the state is ``z_t`` at every t. So training has no recurrence: all T'
  steps are computed in parallel. At test time (eq. 9, test case) the cell runs on its own
  cell state from a single ``z_1``: ``c_1 = cell(z_1, h_1)``, ``c_t = cell(c_{t-1}, h_t)``.
  The cell never sees its own output as input during training: that train/test gap is the
  paper's design, and the reason for ``train_mode: rollout`` above.
* **alpha in eq. 9** is "the non-linear activation function" of eq. 6, i.e. ELU (Sec. 4.2:
  "throughout the model we adopt ELU"), not tanh. Eq. 9 has no bias terms; the gate biases
  of eqs. 7-8 (``b_ic + b_ih``, ``b_fc + b_fh``) are merged into one vector per gate.
* **Output decoder.** Sec. 3.3: "the inverse of the encoding network"; Sec. 4.2 lists
  (128, 25)*128 and (66, 25)*128 convolutions, upsampling and activations. The paper's 66
  output channels include the 3 controls; controls are inputs at test time, so we
  reconstruct the pose only: 2 x (nearest x2 upsampling, conv width 25 -> ``dec_channels``,
  ELU), then a 1x1 conv to the P pose features with no activation (normalised poses are
  unbounded). Nearest upsampling followed by a conv is computed exactly in polyphase form
  (:class:`UpConv`): half the FLOPs of upsampling first.
* **Reconstruction likelihood.** "The negative log probability under a Gaussian" (eq. 5,
  L_x) with a fixed, isotropic variance ``recon_var`` (default 1 = the variance of every
  feature after normalisation), up to its additive constant ``P/2 log(2 pi recon_var)``
  per frame, which is dropped: ``L_x = sum (x - x_hat)^2 / (2 recon_var)``.
  Smaller ``recon_var`` weighs reconstruction more against the KL (like beta = recon_var).
* **Loss scale.** ``loss = (L_x + L_z) / (B*T*P) + l1_term``: the negative ELBO of eq. 5
  (one sample per step, eq. 4's per-step KL summed over steps and latent dimensions),
  divided by the number of pose scalars, so it reads in nats per coordinate.
* **"l1 = 0.1 regularization"** (Sec. 4.2) is read as ``0.1 * sum_W mean(|W|)`` over the
  weight tensors (biases excluded), the per-layer cost ``gamma * mean(|W|)`` of the
  Theano framework of Holden et al. [9, 10] that the paper builds on. The stacked gate
  matrices of the cell count as one tensor each (``[W_ic; W_fc; W_c]``, ``[W_ih; W_fh; W_h]``).
* **Dropout** (Sec. 4.2: "dropout on both the joint positions and control signals") is
  applied to the two encoder inputs during training only; the rate is not given: 0.2.
* **KL warm-up** (ours, ``kl_warmup``): the KL weight rises linearly from 0 to ``beta`` (1) over
  the first 20 % of the training budget (the trainer reports the progress, :meth:`set_progress`);
  validation always reports the full ELBO. Optional free bits (``free_bits`` nats per latent
  dimension, averaged over the batch, below which the KL is not penalised) and a KL weight
  ``beta`` != 1 exist for experiments; the presets use neither (measured: free bits 1.0 and beta 0.25
  raised the KL from 38 to 63 / 84 nats per window without changing the sample spread).
* **Posterior from 4 frames** (Table 1): the inference network is run on the first
  ``factor`` (= 4) seed frames alone, with the same zero 'same' padding it sees at window
  boundaries in training, giving one pooled step and so ``q(z_1 | x_1:4)``. Further seed
  frames are not used unless ``posterior_max_frames`` > 4 (ours, off in the presets: then training
  draws the posterior from a random prefix of up to that many frames, its pooled features
  averaged, and generation uses as many seed frames; measured: a KL of 55 nats, a sample spread
  of 1.3 cm, and a worse 4-frame posterior). Generated sequences are
  the model's own output everywhere: seed frames are conditioning, not copied into it.
  The paper's alternative of a fresh prior sample z_t per step at test time ("both
  approaches work equally well") is not implemented.
* **The prior that generation samples** (ours, ``prior: aggregate``, the presets' setting; ``standard``
  is the paper's ``z_1 ~ N(0, I)``). After every training round the trainer calls
  :meth:`fit_statistics`: the train split's windows are encoded (``q(z_1 | first 4 frames)``, eval mode)
  and ``z_1`` is then drawn from the Gaussian with the mean and covariance of that aggregate posterior,
  ``N(m, L L^T)`` with ``L L^T = Cov_x[mu(x)] + E_x[diag sigma^2(x)]`` (ex-post density estimation,
  Ghosh et al. 2020; the buffers ``prior_mean``, ``prior_scale`` travel in the checkpoint). Why: the
  KL to ``N(0, I)`` does not make the aggregate posterior standard. Measured on the default model
  (7,000 steps, train split): its informative dimensions have posterior means spread with variance up
  to 2.6, so ``N(0, I)`` draws sit in the middle of where real windows are encoded and decode to
  near-average motion. Validation windows (155), 10 draws each with their own controls: sample spread
  0.92 cm from ``N(0, I)``, 2.03 cm from the fitted Gaussian, 2.1 cm from other windows' posterior
  means; a prior draw's root-relative error at frame 210 rises from 0.0024 to 0.0036 m^2 (diverse
  draws lie further from the one true motion); the 4-frame posterior rows do not change. On the test
  split (the committed run of ``cda5b9e``): sample spread 0.96 -> 2.09 cm, FID 0.247 -> 0.226, the prior
  row of Table 1 at frame 210 0.00272 -> 0.00374 m^2. Training is unchanged (the KL stays to
  ``N(0, I)``); only what generation samples without seed frames changes. Before any fit the buffers
  are ``N(0, I)``'s.
  Also measured (not adopted): the paper's ``l1`` 0.1 -> 0.01 / 0 lowered the validation loss
  (0.0645 -> 0.0538 / 0.0509) and left the ``N(0, I)`` spread at 1.0 / 1.1 cm.

Speed (generation of a crowd is the use case; ``bench/generate_vae_lstm.py``)
----------------------------------------------------------------------------
All characters are one batch; only the T' = T/4 roll-out steps loop in Python. The control
half of every gate (``[W_ih; W_fh; W_h] h^c_t``) is one matmul over all steps before the
loop; each step is one fused ``[W_ic; W_fc; W_c]`` matmul and four in-place elementwise
kernels (:meth:`VaeLstmCell.rollout`), on one thread (:func:`~.base.one_thread`). Convolutions
run channels-last on the time-major layout (:func:`conv_time`), the decoder's upsampling
convolutions in polyphase form (:class:`UpConv`, ~half the FLOPs), and ELUs work in place
when no graph is recorded.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .base import Batch, DataSpec, MotionModel, one_thread

TRAIN_MODES = ("rollout", "paper")
PRIORS = ("standard", "aggregate")


def _elu(x: Tensor) -> Tensor:
    """ELU, in place when no graph is being recorded (generation)."""
    return F.elu(x) if torch.is_grad_enabled() else F.elu_(x)


def conv_time(x: Tensor, weight: Tensor, bias: Tensor | None, padding: int) -> Tensor:
    """A 1-D convolution along time of a time-major ``[B, T, C_in]`` tensor -> ``[B, T', C_out]``.

    ``weight`` is ``[C_out, C_in, K]`` as in ``nn.Conv1d``. It runs as a 2-D conv of the
    channels-last view ``[B, C_in, 1, T]`` of ``x`` (no copy); oneDNN/cuDNN then write the
    output channels-last, i.e. ``[B, T', C_out]`` contiguous, so no layout copies are needed
    between layers (and it is faster on CPU than ``conv1d`` on ``[B, C, T]``).
    """
    y = F.conv2d(x.transpose(1, 2).unsqueeze(2), weight.unsqueeze(2), bias, padding=(0, padding))
    return y.squeeze(2).transpose(1, 2)


class TimeConv(nn.Conv1d):
    """``nn.Conv1d`` with 'same' padding (odd width) applied to time-major ``[B, T, C]`` tensors."""

    def __init__(self, c_in: int, c_out: int, kernel: int):
        super().__init__(c_in, c_out, kernel, padding=kernel // 2)

    def forward(self, x: Tensor) -> Tensor:
        return conv_time(x, self.weight, self.bias, self.padding[0])


class ConvEncoder(nn.Module):
    """Eq. 6 with ``len(channels)`` blocks: conv (odd width, 'same') -> ELU -> max-pool(2, 2).

    ``[B, T, c_in]`` -> ``[B, T / 2**len(channels), channels[-1]]``.
    """

    def __init__(self, c_in: int, channels: list[int], kernel: int):
        super().__init__()
        widths = [c_in, *channels]
        self.convs = nn.ModuleList(TimeConv(a, b, kernel) for a, b in zip(widths, widths[1:]))

    def forward(self, x: Tensor) -> Tensor:
        for conv in self.convs:
            y = conv(x)
            B, T, C = y.shape
            x = _elu(y.reshape(B, T // 2, 2, C).amax(dim=2))  # Psi(alpha(x (x) W + b)): ELU is monotone
        return x


class UpConv(nn.Module):
    """Nearest-neighbour x2 upsampling followed by a 'same' conv of odd width ``K`` (the
    decoder's "upsampling + convolution", Sec. 3.3 / 4.2), computed exactly in polyphase form.

    With ``p = K // 2`` and ``u[n] = x[n // 2]``, output frame ``2m + r`` (``r`` in {0, 1}) is
    ``sum_k w[k] u[2m + r + k - p] = sum_d v_r[d] x[m + d]`` with
    ``v_r[d] = sum_{k : (r + k - p) // 2 = d} w[k]`` and ``|d| <= q = (p + 1) // 2``. Both phases
    are one conv of the low-rate input with ``2 * c_out`` filters of width ``2q + 1`` (13 for
    K = 25); in the time-major layout its ``[B, L, 2, c_out]`` output *is* the interleaved
    ``[B, 2L, c_out]`` sequence. FLOPs: ``2 * c_in * c_out * (2q + 1) * 2L`` instead of
    ``2 * c_in * c_out * K * 2L``. The parameters are the K-tap filter of ``self.conv``;
    :meth:`reference` computes the same thing the slow way. ``[B, L, c_in] -> [B, 2L, c_out]``.
    """

    def __init__(self, c_in: int, c_out: int, kernel: int):
        super().__init__()
        self.conv = nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2)  # holds the parameters
        p = kernel // 2
        self.q = (p + 1) // 2
        fold = torch.zeros(2, 2 * self.q + 1, kernel)  # fold[r, d + q, k] = 1 where (r + k - p) // 2 == d
        for r in range(2):
            for k in range(kernel):
                fold[r, (r + k - p) // 2 + self.q, k] = 1.0
        self.register_buffer("fold", fold, persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        B, L, _ = x.shape
        c_out, c_in, _ = self.conv.weight.shape
        w = torch.einsum("oik,rjk->roij", self.conv.weight, self.fold).reshape(2 * c_out, c_in, 2 * self.q + 1)
        y = conv_time(x, w, self.conv.bias.repeat(2), self.q)   # [B, L, 2 * c_out], channel r * c_out + o
        return y.reshape(B, 2 * L, c_out)

    def reference(self, x: Tensor) -> Tensor:
        return self.conv(x.repeat_interleave(2, dim=1).transpose(1, 2)).transpose(1, 2)


class VaeLstmCell(nn.Module):
    """The modified LSTM cell of eqs. 7-9 (no output gate; the cell state is the output).

    ``cell(s, g) = ELU(f * W_c s + i * W_h h)`` with ``i = sigmoid(W_ic s + W_ih h + b_i)``,
    ``f = sigmoid(W_fc s + W_fh h + b_f)``: ``s`` is ``z_t`` in training and ``c_{t-1}`` at
    test time. The control half ``g = [W_ih h, W_fh h, W_h h]`` does not depend on the state,
    so it is computed for all steps at once (:meth:`control_terms`), and the three state
    matrices are one fused ``[3H, H]`` matmul per step.
    """

    def __init__(self, hidden: int, ctrl_features: int):
        super().__init__()
        self.hidden = hidden
        self.state = nn.Linear(hidden, 3 * hidden, bias=False)          # [W_ic; W_fc; W_c]
        self.ctrl = nn.Linear(ctrl_features, 3 * hidden, bias=False)    # [W_ih; W_fh; W_h]
        self.gate_bias = nn.Parameter(torch.zeros(2 * hidden))          # [b_ic + b_ih; b_fc + b_fh]

    def control_terms(self, hc: Tensor) -> Tensor:
        """``h^c`` ``[..., Hc]`` -> ``g = [W_ih h, W_fh h, W_h h]`` ``[..., 3H]`` (gate biases added in the step)."""
        return self.ctrl(hc)

    def forward(self, s: Tensor, g: Tensor) -> Tensor:
        """One step for any leading shape: ``s`` ``[..., H]``, ``g`` ``[..., 3H]`` -> ``c`` ``[..., H]``."""
        H = self.hidden
        a = self.state(s)                                                                     # [W_ic s, W_fc s, W_c s]
        i, f = torch.sigmoid(a[..., :2 * H] + g[..., :2 * H] + self.gate_bias).chunk(2, dim=-1)  # eqs. 7, 8
        return F.elu(f * a[..., 2 * H:] + i * g[..., 2 * H:])                                  # eq. 9

    def unroll(self, z1: Tensor, g: Tensor) -> Tensor:
        """Eq. 9 test case WITH gradients (training in ``train_mode: rollout``): ``c_1 = cell(z_1, g_1)``,
        ``c_t = cell(c_{t-1}, g_t)``. ``z1`` ``[B, H]``, ``g`` ``[B, T', 3H]`` -> canvas ``[B, T', H]``;
        the same numbers as :meth:`rollout` (which is this loop without a graph, in place)."""
        c, out = z1, []
        for t in range(g.shape[1]):
            c = self(c, g[:, t])
            out.append(c)
        return torch.stack(out, 1)

    @torch.no_grad()
    def rollout(self, z1: Tensor, g: Tensor) -> Tensor:
        """Eq. 9 test case / Algorithm 1 (no gradients): ``z1`` ``[B, H]``, ``g`` ``[B, T', 3H]`` ->
        canvas ``[B, T', H]``. The same arithmetic as :meth:`forward`, fed back on itself, with
        the step's six kernels working in place (this loop is the generation hot path)."""
        H = self.hidden
        w = self.state.weight.t()                        # [H, 3H] = [W_ic; W_fc; W_c]^T
        g = g.transpose(0, 1).clone(memory_format=torch.contiguous_format)  # [T', B, 3H], a slab per step
        g[..., :2 * H] += self.gate_bias                                     # (a copy: the caller's g is kept)
        canvas = g.new_empty(g.shape[0], g.shape[1], H)  # [T', B, H]
        c = z1
        with one_thread(g.device):
            for t in range(g.shape[0]):                      # the unavoidable recurrence (T' = T/4 steps)
                a = torch.mm(c, w)                                        # [W_ic c, W_fc c, W_c c]
                gates = a[:, :2 * H].add_(g[t, :, :2 * H]).sigmoid_()    # eqs. 7, 8: [i, f]
                c = torch.mul(a[:, 2 * H:], gates[:, H:], out=canvas[t])  # f * W_c c_{t-1}
                F.elu_(c.addcmul_(gates[:, :H], g[t, :, 2 * H:]))         # eq. 9: + i * W_h h_t, ELU
        return canvas.transpose(0, 1).contiguous()


class VAELSTM(MotionModel):
    """Habibie et al. 2017 VAE-LSTM (see the module docstring).

    Hyperparameters: ``ctrl_channels`` control-encoder widths (paper 64, 128);
    ``inf_channels`` inference-network widths (paper 64, 256); ``hidden`` LSTM units =
    latent size (paper 128); ``dec_channels`` upsampling-decoder widths (paper 128, 128);
    ``kernel`` odd conv width (paper 25); ``dropout`` input dropout rate; ``l1`` weight of
    the mean-|W| penalty (paper 0.1); ``recon_var`` the Gaussian likelihood's variance;
    ``seed_frames`` frames ``predict`` conditions on: 0 (prior sample, Algorithm 1) or
    >= 4 (posterior of the first pooled step, Table 1); ``prior`` what generation without
    seed frames samples: ``standard`` ``N(0, I)`` (the paper) or ``aggregate`` (the Gaussian of the
    train split's aggregate posterior, :meth:`fit_statistics`). The three width lists must have
    the same length ``n`` (paper 2): the time factor is ``2 ** n``.
    """

    family = "vae_lstm"
    uses_controls = True
    uses_labels = False

    def __init__(self, spec: DataSpec, ctrl_channels: list[int] = (64, 128), inf_channels: list[int] = (64, 256),
                 hidden: int = 128, dec_channels: list[int] = (128, 128), kernel: int = 25, dropout: float = 0.2,
                 l1: float = 0.1, recon_var: float = 1.0, seed_frames: int = 4, train_mode: str = "rollout",
                 kl_warmup: float = 0.0, free_bits: float = 0.0, latent_every_step: bool = False,
                 posterior_max_frames: int | None = None, beta: float = 1.0, prior: str = "standard"):
        super().__init__(spec)
        ctrl_channels, inf_channels, dec_channels = list(ctrl_channels), list(inf_channels), list(dec_channels)
        self.factor = 2 ** len(ctrl_channels)
        problems = []
        if spec.controls != 3:
            problems.append(f"VAE-LSTM needs the 3 control signals (spec.controls == 3), got {spec.controls}")
        if not (len(ctrl_channels) == len(inf_channels) == len(dec_channels) >= 1):
            problems.append(f"ctrl_channels, inf_channels and dec_channels need the same number (>= 1) of blocks, "
                            f"got {ctrl_channels}, {inf_channels}, {dec_channels}")
        sizes = {"ctrl_channels": ctrl_channels, "inf_channels": inf_channels, "dec_channels": dec_channels,
                 "hidden": [hidden], "kernel": [kernel]}
        for name, vals in sizes.items():
            if not all(isinstance(v, int) and v > 0 for v in vals):
                problems.append(f"{name} must be positive integers, got {vals}")
        if isinstance(kernel, int) and kernel % 2 == 0:
            problems.append(f"kernel must be odd for 'same' padding, got {kernel}")
        if not 0.0 <= dropout < 1.0:
            problems.append(f"dropout must be in [0, 1), got {dropout}")
        if not l1 >= 0.0:
            problems.append(f"l1 must be >= 0, got {l1}")
        if not recon_var > 0.0:
            problems.append(f"recon_var must be > 0, got {recon_var}")
        if spec.window <= 0 or spec.window % self.factor:
            problems.append(f"spec.window must be a positive multiple of the pooling factor {self.factor}, "
                            f"got {spec.window}")
        if not (seed_frames == 0 or self.factor <= seed_frames < spec.window):
            problems.append(f"seed_frames must be 0 (prior) or in [{self.factor}, window={spec.window}) "
                            f"(posterior of the first pooled step), got {seed_frames}")
        if train_mode not in TRAIN_MODES:
            problems.append(f"train_mode must be one of {TRAIN_MODES}, got {train_mode!r}")
        if not (isinstance(kl_warmup, (int, float)) and 0.0 <= kl_warmup <= 1.0):
            problems.append(f"kl_warmup must be a fraction of the budget in [0, 1], got {kl_warmup!r}")
        if not (isinstance(beta, (int, float)) and beta > 0.0):
            problems.append(f"beta must be > 0 (the KL weight after the warm-up), got {beta!r}")
        if not (isinstance(free_bits, (int, float)) and free_bits >= 0.0):
            problems.append(f"free_bits must be >= 0 (nats per latent dimension), got {free_bits!r}")
        if prior not in PRIORS:
            problems.append(f"prior must be one of {PRIORS}, got {prior!r}")
        if problems:
            raise ValueError("VAELSTM: " + "; ".join(problems))

        self.hidden, self.dropout, self.l1, self.recon_var = hidden, float(dropout), float(l1), float(recon_var)
        self.seed_frames = int(seed_frames)
        self.train_mode, self.kl_warmup, self.free_bits = train_mode, float(kl_warmup), float(free_bits)
        self.beta = float(beta)
        self.prior = prior
        pmax = self.factor if posterior_max_frames is None else posterior_max_frames
        if not (isinstance(pmax, int) and self.factor <= pmax <= spec.window and pmax % self.factor == 0):
            raise ValueError(f"VAELSTM: posterior_max_frames must be a multiple of {self.factor} in "
                             f"[{self.factor}, window={spec.window}], got {posterior_max_frames!r}")
        self.posterior_max_frames = pmax
        if latent_every_step and train_mode != "rollout":
            raise ValueError("VAELSTM: latent_every_step needs train_mode 'rollout' (one z_1 per window)")
        self.progress = 1.0                                  # share of the training budget done (set_progress)
        P = spec.pose_features
        self.ctrl_encoder = ConvEncoder(spec.controls, ctrl_channels, kernel)         # Sec. 3.2, eq. 6
        self.inference = ConvEncoder(P, inf_channels, kernel)                       # Sec. 3.2, eq. 6
        self.posterior_head = nn.Linear(inf_channels[-1], 2 * hidden)               # -> (mu, logvar)
        self.cell = VaeLstmCell(hidden, ctrl_channels[-1])                          # eqs. 7-9
        # ours (latent_every_step): z_1 also enters every step's gates and candidate, like h^c
        self.latent_gates = nn.Linear(hidden, 3 * hidden, bias=False) if latent_every_step else None
        widths = [hidden, *dec_channels]
        self.ups = nn.ModuleList(UpConv(a, b, kernel) for a, b in zip(widths, widths[1:]))  # Sec. 3.3
        self.out = nn.Linear(dec_channels[-1], P)                                   # 1x1 conv
        # what generation samples z_1 from without seed frames: N(prior_mean, prior_scale prior_scale^T);
        # N(0, I) until fit_statistics (prior: aggregate) sets them
        self.register_buffer("prior_mean", torch.zeros(hidden))
        self.register_buffer("prior_scale", torch.eye(hidden))

    # ------------------------------------------------------------------ pieces
    def encode_controls(self, controls: Tensor) -> Tensor:
        """``[B, T, 3]`` -> control terms ``g`` ``[B, T', 3H]`` of the cell (from ``h^c`` ``[B, T', Hc]``)."""
        return self.cell.control_terms(self.ctrl_encoder(controls))

    def with_latent(self, g: Tensor, z1: Tensor) -> Tensor:
        """The control terms ``g`` ``[B, T', 3H]``, plus ``U z_1`` at every step with ``latent_every_step``."""
        return g if self.latent_gates is None else g + self.latent_gates(z1)[:, None]

    def posterior(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Flat poses ``[B, T, P]`` -> ``mu, logvar`` ``[B, T', H]`` of q(z_t | x)."""
        return self.posterior_head(self.inference(x)).chunk(2, dim=-1)

    def decode(self, canvas: Tensor) -> Tensor:
        """CNN^dec: canvas ``[B, T', H]`` -> flat poses ``[B, T, P]``."""
        h = canvas
        for up in self.ups:
            h = _elu(up(h))
        return self.out(h)

    def _check_controls(self, controls: Tensor | None, length: int) -> None:
        if controls is None:
            raise ValueError("VAE-LSTM is driven by control signals: controls [B, T, 3] are required")
        if controls.dim() != 3 or controls.shape[-1] != self.spec.controls:
            raise ValueError(f"controls must be [B, T, {self.spec.controls}], got {tuple(controls.shape)}")
        if length <= 0 or length % self.factor:
            raise ValueError(f"length must be a positive multiple of the pooling factor {self.factor}, got {length}")

    # ------------------------------------------------------------------ training
    def set_progress(self, step: int, total: int) -> None:
        """Called by the trainer before every optimiser step (the KL warm-up)."""
        self.progress = step / total if total > 0 else 1.0

    def kl_weight(self) -> float:
        """The KL term's weight: ``beta * min(1, progress / kl_warmup)`` while training; 1 when evaluating
        (validation reports the ELBO itself)."""
        if not self.training:
            return 1.0
        if self.kl_warmup <= 0.0:
            return self.beta
        return self.beta * min(1.0, self.progress / self.kl_warmup)

    def first_posterior(self, x: Tensor, frames: int | None = None) -> tuple[Tensor, Tensor]:
        """``q(z_1 | x_1..x_K)``: the inference network on the first ``K = frames`` frames alone (default
        ``factor``; with the zero 'same' padding of a window boundary), its features averaged over the
        ``K / factor`` pooled steps, then the posterior head: ``x`` ``[B, >= K, P]`` -> ``mu, logvar`` ``[B, H]``."""
        K = self.factor if frames is None else frames
        return self.posterior_head(self.inference(x[:, :K]).mean(1)).chunk(2, dim=-1)

    @torch.no_grad()
    def fit_statistics(self, train, batch_size: int = 256) -> None:
        """``prior: aggregate``: fit the generation prior to the aggregate posterior of ``train`` (a
        :class:`~motionsynth.training.data.WindowData` of the train split; module docstring). Called by the
        trainer after every round; a no-op for ``prior: standard``."""
        if self.prior != "aggregate":
            return
        firsts = [train.batch(idx).pose[:, :self.factor] for idx in train.batch_indices(batch_size, False, 0)]
        self.fit_prior(torch.cat(firsts))

    @torch.no_grad()
    def fit_prior(self, first: Tensor, batch_size: int = 256) -> None:
        """Set ``prior_mean`` and ``prior_scale`` to the mean and the Cholesky factor of the covariance of
        the mixture ``(1/N) sum_n q(z_1 | first[n])``: ``Cov[mu] + mean(diag sigma^2)``, from the first
        ``factor`` frames ``first`` ``[N, >= factor, J, D]`` of N windows, encoded in eval mode (float64 sums)."""
        if first.shape[0] < 2:
            raise ValueError(f"fit_prior needs >= 2 windows, got {first.shape[0]}")
        was_training = self.training
        self.eval()
        try:
            parts = [self.first_posterior(self.flat(p.to(self.prior_mean.device)), self.factor)
                     for p in first.split(batch_size)]
        finally:
            self.train(was_training)
        mu = torch.cat([m for m, _ in parts]).double()                         # [N, H]
        var = torch.cat([lv for _, lv in parts]).double().exp()
        mean = mu.mean(0)
        d = mu - mean
        cov = d.T @ d / len(mu) + torch.diag(var.mean(0))
        self.prior_mean.copy_(mean)
        self.prior_scale.copy_(torch.linalg.cholesky(cov))

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        x = self.flat(batch.pose)                                        # [B, T, P]
        self._check_controls(batch.controls, x.shape[1])
        x_in = F.dropout(x, self.dropout, self.training)                 # Sec. 4.2 input dropout
        c_in = F.dropout(batch.controls, self.dropout, self.training)
        g = self.encode_controls(c_in)                                   # [B, T', 3H]
        if self.train_mode == "paper":                                   # eq. 9, training case: z_t at every step
            mu, logvar = self.posterior(x_in)                            # [B, T', H]
            z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)      # eq. 3
            canvas = self.cell(z, g)                                     # all steps at once
        else:                                                            # train as Algorithm 1 generates
            K = self.factor                                              # the seed's frames: a random prefix
            if self.training and self.posterior_max_frames > self.factor:
                K *= int(torch.randint(1, self.posterior_max_frames // self.factor + 1, ()))
            mu, logvar = self.first_posterior(x_in, K)                   # [B, H]
            z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)      # eq. 3
            canvas = self.cell.unroll(z, self.with_latent(g, z))         # eq. 9, test case
        x_hat = self.decode(canvas)                                      # [B, T, P]
        n = x.numel()
        sq = (x_hat - x).pow(2).sum()
        nll = 0.5 * sq / self.recon_var                                  # L_x, up to a constant
        kl_d = 0.5 * (mu.pow(2) + logvar.exp() - logvar - 1.0)           # eq. 4, per latent dim (and step)
        kl_d = kl_d.reshape(-1, kl_d.shape[-1])
        kl = kl_d.sum()
        if self.free_bits > 0:                                           # free bits: no penalty below the floor
            kl_pen = torch.clamp(kl_d.mean(0), min=self.free_bits).sum() * kl_d.shape[0]
        else:
            kl_pen = kl
        reg = sum(p.abs().mean() for p in self.parameters() if p.dim() > 1)
        beta = self.kl_weight()
        loss = (nll + beta * kl_pen) / n + self.l1 * reg                 # eq. 5 + Sec. 4.2 l1
        windows = mu.shape[0]
        logs = {"nll": nll.item() / n, "kl": kl.item() / n, "mse": sq.item() / n,
                "kl_per_window": kl.item() / windows, "kl_weight": beta, "l1": reg.item()}
        return loss, logs

    # ------------------------------------------------------------------ synthesis
    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        """Algorithm 1. ``seed`` None or ``[B, 0, J, D]``: ``z_1`` from the prior (``N(0, I)``, or with
        ``prior: aggregate`` the fitted ``N(prior_mean, prior_scale prior_scale^T)``);
        ``[B, S >= 4, J, D]``: ``z_1 ~ q(z_1 | first 4 frames)``. ``controls`` ``[B, length, 3]``.
        Returns ``[B * num_samples, length, J, D]`` (sample ``s`` of item ``b`` at ``b * num_samples + s``)."""
        self._check_controls(controls, length)
        if controls.shape[1] != length:
            raise ValueError(f"controls cover {controls.shape[1]} frames but length={length}")
        if num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples}")
        B = controls.shape[0]
        g = self.encode_controls(controls.repeat_interleave(num_samples, dim=0))  # [B*ns, T', 3H]
        if seed is None or seed.shape[1] == 0:
            z1 = torch.randn(B * num_samples, self.hidden, device=g.device, dtype=g.dtype)
            if self.prior == "aggregate":
                z1 = torch.addmm(self.prior_mean, z1, self.prior_scale.T)
        else:
            if seed.shape[0] != B:
                raise ValueError(f"seed has {seed.shape[0]} items but controls {B}")
            if seed.shape[1] < self.factor:
                raise ValueError(f"the posterior of the first pooled step needs {self.factor} seed frames, "
                                 f"got {seed.shape[1]} (pass 0 frames to sample the prior)")
            K = min(seed.shape[1], self.posterior_max_frames) // self.factor * self.factor
            mu, logvar = self.first_posterior(self.flat(seed), K)              # [B, H]
            mu, logvar = mu.repeat_interleave(num_samples, 0), logvar.repeat_interleave(num_samples, 0)
            z1 = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)            # eq. 3
        canvas = self.cell.rollout(z1, self.with_latent(g, z1))                 # eq. 9, test case
        return self.unflat(self.decode(canvas))

    @torch.no_grad()
    def predict(self, batch: Batch) -> Tensor:
        """The batch window from its first ``seed_frames`` frames and its ground-truth controls."""
        seed = batch.pose[:, :self.seed_frames] if self.seed_frames else None
        return self.generate(seed, batch.controls, length=batch.pose.shape[1])

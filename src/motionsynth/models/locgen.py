"""LocGen: the second (dense, class-agnostic) stage of GlocalNet (Battan et al. 2021, section 3.2).

LocGen turns a sparse pose trajectory (GloGen's output, or a window's every ``k``-th
frame) into a dense one. The sparse poses are first linearly interpolated with ``M``
in-between poses per gap (eq. 3), then the same bi-LSTM encoder / decoder network as
GloGen (:class:`~motionsynth.models.glogen.BiSeq2Seq`, no class prior) transforms the
interpolated trajectory into natural-looking in-between poses (eq. 4). ``M`` is chosen
at generation time: the pace control of section 3 / the conclusion.

Shapes
------
* sparse input ``[B, n, J, D]``; interpolated / dense output ``[B, (n - 1) * (M + 1) + 1, J, D]``;
  internally flat ``F = J * D``: network ``[B, L, F] -> [B, L, F]``.
* Training: from the dense window ``batch.pose [B, T, J, D]`` and its stride
  ``k = batch.every`` (``M = k - 1``), the sparse poses ``pose[:, ::k]`` are interpolated
  back to ``T`` frames and LocGen learns to output ``pose`` (teacher-free: the network is
  not auto-regressive on its own outputs, the whole sequence is one LSTM pass).
* :meth:`predict` returns dense ``[B, T, J, D]`` from the batch's sparse poses only.
  ``seed_frames = 0``: LocGen does not get a dense seed prefix; it sees the sparse
  (key) frames ``pose[:, ::k]`` of the whole window; validation scores the in-between frames
  only (:meth:`LocGen.scored_frames`: keyframes are exact).

Choices where the paper is vague (and why)
------------------------------------------
* **Interpolation (eq. 3)**: the paper writes ``X~_j = a_j X_i + (1 - a_j) X_{i+1}`` with
  ``a_j = j / M``, ``1 <= j <= M``. Taken literally this runs backwards (``j = 1`` lies next
  to ``X_{i+1}``) and ``j = M`` gives ``X_i`` itself, a duplicate of the key pose rather than
  an in-between. We use the reading that goes from ``X_i`` to ``X_{i+1}`` with ``M`` poses
  strictly between them, uniformly spaced in time:
  ``X~_j = (1 - a_j) X_i + a_j X_{i+1}``, ``a_j = j / (M + 1)``, ``j = 1..M``
  (dense frame ``i * (M + 1) + j``). With ``M = k - 1`` this is exactly the linear
  interpolation of the dense window between its keyframes.
* **What the network sees / outputs (eq. 4)**: eq. 4 maps the ``M`` interpolated poses of a gap
  to ``M`` generated poses; we run the network over the *whole* interpolated sequence
  (keyframes included) in one bi-LSTM pass, so every in-between sees both of its key poses
  and its neighbouring gaps (no seams at keyframes), with one vectorised call for any ``n``
  and ``M``. The output is a **residual** over the interpolation (``residual=True``;
  zero-initialised output layer: an untrained LocGen is eq. 3's linear interpolation), and
  the key poses are **kept exactly** (eq. 4 generates only the in-betweens ``Y``): the
  network's output is masked to zero at keyframes. ``residual=False`` outputs the in-between
  poses directly (keyframes still kept).
* **Architecture**: "LocGen has the same architecture as GloGen except ... no class prior":
  1-layer bi-LSTM encoder (``hidden`` = output width of both directions, 200 in section 4.2),
  the decoder is a 1-layer bi-LSTM whose input sequence is all encoder states, then a
  linear layer; dropout 0.25 on the encoder states and decoder outputs.
* **Loss**: as GloGen, ``lambda_joint * L_J + lambda_flow * L_MF`` (eqs. 5-8, MSE of dense poses
  and of their frame-to-frame motion flow, over all frames of the window).
* **Pace control**: training sees the data's stride ``k`` (``M = k - 1``); ``extra_strides``
  (e.g. ``[2, 3]``) add the same window sub-sampled at other strides to the loss (one
  vectorised pass per stride, averaged), so that LocGen also learns other ``M``. Any ``M >= 0``
  works at generation time; ``M = 0`` returns the sparse poses unchanged.
* Datasets with ``every = 1`` (the H3.6M 2-D benchmark windows) have no in-betweens: LocGen's
  output is then its input and its loss is 0 unless ``extra_strides`` are given.
* **Optimiser**: as GloGen (AdamW, lr 0.002, section 4.2).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .base import Batch, DataSpec, MotionModel
from .glogen import BiSeq2Seq, GloGen, _check_int, check_seq2seq_hparams, joint_and_flow_loss


def interpolate(sparse: Tensor, M: int) -> tuple[Tensor, Tensor]:
    """Eq. 3 (read from ``X_i`` to ``X_{i+1}``): ``sparse [B, n, F]`` -> dense ``[B, (n-1)(M+1)+1, F]``
    and the in-between mask ``[(n-1)(M+1)+1]`` (False at keyframes)."""
    B, n, feats = sparse.shape
    a = torch.arange(M + 1, dtype=sparse.dtype, device=sparse.device) / (M + 1)     # a_j = j/(M+1), j=0..M
    a = a[None, None, :, None]
    seg = (1 - a) * sparse[:, :-1, None] + a * sparse[:, 1:, None]                  # [B, n-1, M+1, F]
    dense = torch.cat([seg.reshape(B, (n - 1) * (M + 1), feats), sparse[:, -1:]], 1)
    mask = torch.ones(dense.shape[1], dtype=torch.bool, device=sparse.device)
    mask[::M + 1] = False
    return dense, mask


class LocGen(MotionModel):
    """GlocalNet stage 2: sparse -> dense poses by interpolation + bi-LSTM Seq2Seq (section 3.2).

    Hyperparameters: ``hidden`` (bi-LSTM output width, even), ``dropout``, ``lambda_joint`` /
    ``lambda_flow`` (eq. 5), ``extra_strides`` (additional training strides for pace
    control), ``residual`` (predict offsets from the interpolation).
    """

    family = "glocal"
    uses_controls = False
    uses_labels = False

    def __init__(self, spec: DataSpec, hidden: int = 200, dropout: float = 0.25, lambda_joint: float = 1.0,
                 lambda_flow: float = 1.0, extra_strides: list[int] | tuple[int, ...] | None = None,
                 residual: bool = True):
        super().__init__(spec)
        check_seq2seq_hparams(hidden, dropout, lambda_joint, lambda_flow)
        strides = [] if extra_strides is None else list(extra_strides)
        for s in strides:
            _check_int("extra_strides[]", s, 2)
        if not isinstance(residual, bool):
            raise ValueError(f"residual must be true or false, got {residual!r}")
        _check_int("spec.every", spec.every, 1)
        self.extra_strides = sorted(set(strides) - {spec.every})
        self.seed_frames = 0
        self.lambda_joint, self.lambda_flow, self.residual = float(lambda_joint), float(lambda_flow), residual
        self.net = BiSeq2Seq(spec.pose_features, spec.pose_features, hidden, float(dropout))

    def densify(self, sparse: Tensor, M: int) -> Tensor:
        """``sparse [B, n, F]`` -> dense ``[B, (n-1)(M+1)+1, F]``: eq. 3 then eq. 4, keyframes kept."""
        interp, mask = interpolate(sparse, M)                                 # eq. 3
        out = self.net(interp)                                                # eq. 4 (whole sequence)
        if not self.residual:
            out = out - interp
        return interp + out * mask[None, :, None].to(out.dtype)

    def _stride_loss(self, dense: Tensor, k: int) -> tuple[Tensor, Tensor]:
        n = (dense.shape[1] - 1) // k + 1
        tgt = dense[:, :(n - 1) * k + 1]
        pred = self.densify(tgt[:, ::k], k - 1)
        return joint_and_flow_loss(pred, tgt)                                 # eqs. 6-8

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        dense = self.flat(batch.pose)                                         # [B, T, F]
        strides = [batch.every] + [s for s in self.extra_strides if s != batch.every and s < dense.shape[1]]
        terms = [self._stride_loss(dense, k) for k in strides]
        l_j = torch.stack([a for a, _ in terms]).mean()
        l_mf = torch.stack([b for _, b in terms]).mean()
        loss = self.lambda_joint * l_j + self.lambda_flow * l_mf             # eq. 5
        return loss, {"L_J": float(l_j.detach()), "L_MF": float(l_mf.detach())}

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int | None = None, num_samples: int = 1, M: int | None = None) -> Tensor:
        """Dense poses from sparse ones: ``seed [B, n, J, D]`` (SPARSE poses) ->
        ``[B * num_samples, length, J, D]``, ``length`` defaulting to ``(n - 1) * (M + 1) + 1``.

        ``M`` in-between poses per gap (default ``spec.every - 1``): the pace control.
        Frame ``i * (M + 1)`` of the output is sparse pose ``i``. ``labels`` are ignored.
        """
        M = self.spec.every - 1 if M is None else _check_int("M", M, 0)
        _check_int("num_samples", num_samples, 1)
        J, D = self.spec.joints, self.spec.dims
        if seed is None or seed.dim() != 4 or seed.shape[2:] != (J, D) or seed.shape[1] < 1:
            raise ValueError(f"LocGen needs sparse poses [B, n >= 1, {J}, {D}], got "
                             f"{None if seed is None else tuple(seed.shape)}")
        n = int(seed.shape[1])
        full = (n - 1) * (M + 1) + 1
        if length is None:
            length = full
        _check_int("length", length, 1)
        if length > full:
            raise ValueError(f"{n} sparse poses with M = {M} give {full} dense frames < length {length}; "
                             f"pass >= {-(-(length - 1) // (M + 1)) + 1} sparse poses")
        if num_samples > 1:
            seed = seed.repeat_interleave(num_samples, 0)
        sp = self.flat(seed)
        if M == 0 or n == 1:
            dense = sp
        else:
            dense = self.densify(sp, M)
        return self.unflat(dense[:, :length])

    def scored_frames(self, T: int) -> Tensor:
        """The frames validation scores (``val/pred_mse``, LocGen's selection criterion): only the
        in-betweens it generates, ``t % every != 0`` up to the last keyframe. Keyframes are copied
        exactly and would only dilute the error."""
        k, t = self.spec.every, torch.arange(T)
        return (t % k != 0) & (t <= (T - 1) // k * k)

    @torch.no_grad()
    def predict(self, batch: Batch) -> Tensor:
        """Dense ``[B, T, J, D]`` from the window's sparse poses ``pose[:, ::every]`` (``M = every - 1``).
        Frames after the last keyframe (windows that do not end on one) hold the last pose."""
        k = batch.every
        T = batch.pose.shape[1]
        dense = self.generate(batch.pose[:, ::k], M=k - 1)
        if dense.shape[1] < T:
            dense = torch.cat([dense, dense[:, -1:].expand(-1, T - dense.shape[1], -1, -1)], 1)
        return dense


@torch.no_grad()
def glocal_generate(glogen: GloGen, locgen: LocGen, seed_sparse: Tensor | None, labels: Tensor | None,
                    n_sparse: int, M: int | None = None) -> Tensor:
    """GlocalNet (Fig. 2): GloGen rolls out ``n_sparse`` sparse poses from ``seed_sparse
    [B, t_in, J, D]`` and ``labels`` (``[B]`` or ``[B, n_sparse]`` for transitions), then LocGen
    fills ``M`` in-betweens per gap: returns dense ``[B, (n_sparse - 1) * (M + 1) + 1, J, D]``."""
    sparse = glogen.generate(seed_sparse, labels=labels, length=n_sparse)
    return locgen.generate(sparse, M=M)

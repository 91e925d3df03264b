"""GloGen: the first (sparse, class-aware) stage of GlocalNet (Battan et al. 2021, section 3.1).

GloGen is an auto-regressive Seq2Seq network of bi-directional LSTMs over *sparse*
poses (every ``k``-th frame of a motion): it maps a chunk of ``t`` sparse poses
(each concatenated with a one-hot class prior) to the next ``t`` sparse poses,

    H_{i+1..i+t} = GloGenEncoder(X_{i+1..i+t})                      (eq. 1)
    X_{i+t+1..i+2t} = GloGenDecoder(H_{i+1..i+t})                    (eq. 2)

and long sparse trajectories are rolled out by feeding each predicted chunk back
as the next input chunk. Class transitions (Fig. 1b, section 4.4 "Synthesis for
Sequence of Activities") come from changing the one-hot prior between chunks.

Shapes
------
* ``batch.pose`` ``[B, T, J, D]`` dense window; its sparse poses are
  ``batch.pose[:, ::batch.every]`` ``[B, n, J, D]`` (``n = (T - 1) // k + 1``).
* Internally poses are flat, ``F = J * D``; the encoder input is ``[N, t, F + C]``
  (``C = spec.num_classes``; no one-hot when ``C == 0``), encoder states
  ``[N, t, hidden]``, decoder output ``[N, t, F]``.
* Training pairs: every chunk pair of the sparse window, ``[B * P, 2t, F]``
  (``P = (n - 2t) // pair_stride + 1``), one teacher-forced batch.
* :meth:`generate` ``seed [B, S >= t, J, D]`` sparse poses -> ``[B * num_samples, length, J, D]``
  sparse poses, seed included.
* :meth:`predict` / :meth:`target`: ``[B, t_in + t_out, J, D]`` SPARSE poses aligned with
  ``batch.pose[:, ::batch.every]`` (the prefix of length ``t_in + t_out``); the first
  ``t_in = seed_frames`` are the ground-truth seed. The trainer compares ``predict(batch)``
  with ``model.target(batch)`` (not ``batch.pose``) because the model lives on sparse poses.

Choices where the paper is vague (and why)
------------------------------------------
* **Chunk length** ``t`` is ``t_in`` (the paper feeds ``t`` initial poses and predicts the next
  ``t``; with H3.6M's 10 input / 50 predicted poses, ``t = 10`` and 5 chunks are rolled out;
  with NTU-3D's 5 / 15, ``t = 5`` and 3 chunks). ``t_out`` (a multiple of ``t_in``) is the
  evaluation horizon of :meth:`predict`; ``t_out = None`` takes the rest of the window,
  rounded down to a multiple of ``t_in``. NOTE for the H3.6M Table-3 setting use
  ``t_in=10, t_out=50``; the presets use the NTU-3D setting ``t_in=5`` (section 4.2).
* **Encoder width**: "the output dimension of our Encoder is 200" (section 4.2) is read as the
  bi-LSTM's *output* (the concatenation of both directions), i.e. ``hidden = 200`` total and
  ``hidden // 2 = 100`` units per direction (``hidden`` must be even).
* **How the decoder consumes all encoder states** (eq. 2, "we feed all the output states of
  the encoder ... as input to the GloGen decoder instead of just the last state"): the
  encoder's state sequence ``H_1..H_t`` is the decoder's *input sequence* (one state per
  step); the decoder (a 1-layer bi-LSTM, section 4.2, same width) starts from the encoder's
  final ``(h, c)`` of both directions (the usual Seq2Seq hand-over), and a linear layer maps
  its output at step ``j`` to the pose ``X_{i+t+j}``. Being bi-directional, every output step
  sees every input pose.
* **Output parameterisation**: with ``residual=True`` (default) the decoder predicts the
  offset of each output pose from the last input pose ``X_{i+t}`` (the output layer is
  zero-initialised, so an untrained model is the zero-velocity baseline). ``residual=False``
  predicts the poses directly, as the paper literally says ("the decoder output is considered
  as the set of predicted t number of poses").
* **Dropout 0.25 "for the layers"**: applied to the encoder states (decoder input) and to the
  decoder outputs (before the linear layer); a 1-layer LSTM has no inner dropout.
* **Losses** (eqs. 5-8, "We use MSE loss to calculate our objective function"):
  ``L_J`` (eq. 6) is the mean squared error between predicted and ground-truth poses of the
  output chunk; ``L_MF`` (eq. 7) is the mean squared error between predicted and ground-truth
  *motion flow* (frame-to-frame velocity) over the ``t - 1`` consecutive pairs inside the
  chunk. Eq. 8 writes the predicted flow as ``X_{i+1} - X^_i`` (ground truth minus
  prediction), which is not a velocity of the prediction; we read it as the predicted flow
  ``V^_i = X^_{i+1} - X^_i`` against the ground-truth flow ``V_i = X_{i+1} - X_i``.
  ``L = lambda_joint * L_J + lambda_flow * L_MF`` (eq. 5); the paper gives no lambdas, its
  Table 2 row "L_J + L_MF" reads as ``1, 1``.
* **Training windows**: all chunk pairs ``(X_{i+1..i+t}, X_{i+t+1..i+2t})`` of the sparse
  window at offsets ``i = 0, pair_stride, 2 * pair_stride, ...`` (``pair_stride = 1``: every
  sliding pair), stacked into one teacher-forced batch (``Tensor.unfold``; no frame loop).
  The window's single class label is used for every pair.
* **Class switching** (Fig. 1b): with per-step labels ``[B, length]`` the chunk generated at
  output positions ``[p, p + t)`` uses class ``labels[:, p]`` (the class of its first frame),
  concatenated to the ``t`` input poses that produce it, as section 4.4 describes.
* **Seed**: ``seed`` may hold more than ``t`` poses (all are copied to the output, the last
  ``t`` start the roll-out). ``seed=None`` starts from ``t`` copies of the zero pose (the
  train-split mean pose in normalised units). GloGen is deterministic: ``num_samples``
  copies are identical.
* **Optimiser** (section 4.2): AdamW, lr 0.002, dropout 0.25; weight decay 0.01 (AdamW's
  default; the paper names none); batch size 64 (NTU-3D / CMU).

Speed (CPU training)
--------------------
A training step is almost all bi-LSTM (eqs. 1-2): profiled at the H3.6M setting (``t_in`` 10,
``t_out`` 50, ``pair_stride`` 5: 9 chunk pairs a window, hidden 200), the four LSTM directions'
forward and backward take ~85 % of a step, dropout's masks ~6 %, the losses (eqs. 5-8, the
motion-flow pairs included) and the optimiser under 2 %: nothing in the loss is slow. PyTorch runs
a CPU LSTM that needs gradients on oneDNN (``mkldnn_rnn_layer``) by default. On one thread its
native kernel (a batched matmul per step, autograd through the cell) computes the same function
faster at these sizes (``[B * P, t]`` sequences of 10 steps, 100 units a direction): a step 16-19 %
shorter (paired, interleaved steps, batch 64 and 100), mostly in the backward. With more threads
the native kernel opens a parallel region per operation and time step (oneDNN: one per layer);
measured with a busy process on the second core it was 10-70 % slower, so there PyTorch's default
is kept. :class:`BiSeq2Seq` therefore runs its LSTMs on the native kernel while gradients are
recorded on the CPU by a single-threaded process (:func:`native_cpu_rnn`: tests, parallel jobs,
``train.threads=1``); inference, several threads and GPUs keep the default. Same maths: loss and
gradients agree with the default kernel's to float rounding (``tests/test_model_glocal.py`` pins
both against a plain reference computation).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .base import Batch, DataSpec, MotionModel, check_int as _check_int


def _check_float(name: str, value, minimum: float = 0.0, maximum: float | None = None,
                 open_max: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= minimum
    if ok and maximum is not None:
        ok = value < maximum if open_max else value <= maximum
    if not ok or value != value:
        rng = f"in [{minimum}, {maximum}{')' if open_max else ']'}" if maximum is not None else f">= {minimum}"
        raise ValueError(f"{name} must be a number {rng}, got {value!r}")
    return float(value)


def check_seq2seq_hparams(hidden: int, dropout: float, lambda_joint: float, lambda_flow: float) -> None:
    """Validation shared by GloGen and LocGen (same architecture, same loss)."""
    _check_int("hidden", hidden, 2)
    if hidden % 2:
        raise ValueError(f"hidden is the bi-LSTM output width (both directions) and must be even, got {hidden}")
    _check_float("dropout", dropout, 0.0, 1.0, open_max=True)
    _check_float("lambda_joint", lambda_joint)
    _check_float("lambda_flow", lambda_flow)
    if lambda_joint + lambda_flow <= 0:
        raise ValueError("lambda_joint + lambda_flow must be > 0 (nothing to learn otherwise)")


#: the torch thread count up to which training runs the LSTMs on the native kernel (module docstring, "Speed")
NATIVE_RNN_MAX_THREADS = 1


@contextmanager
def native_cpu_rnn(x: Tensor) -> Iterator[None]:
    """Run the LSTMs inside on PyTorch's native CPU kernel instead of oneDNN while gradients are recorded
    for a CPU tensor ``x`` on a single thread (module docstring, "Speed": the same function, faster to
    train there); elsewhere (no gradients, several threads, GPUs, oneDNN already off) nothing changes.
    The global oneDNN switch is restored on leaving, also after an error."""
    if (x.device.type != "cpu" or not torch.is_grad_enabled() or not torch.backends.mkldnn.enabled
            or torch.get_num_threads() > NATIVE_RNN_MAX_THREADS):
        yield
        return
    torch.backends.mkldnn.enabled = False
    try:
        yield
    finally:
        torch.backends.mkldnn.enabled = True


class BiSeq2Seq(nn.Module):
    """The GloGen / LocGen network: bi-LSTM encoder -> bi-LSTM decoder fed with ALL encoder states.

    ``x [N, L, in_features] -> [N, L, out_features]``. ``hidden`` is the bi-LSTM output width
    (both directions together, ``hidden // 2`` per direction).
    """

    def __init__(self, in_features: int, out_features: int, hidden: int, dropout: float):
        super().__init__()
        half = hidden // 2
        self.encoder = nn.LSTM(in_features, half, num_layers=1, batch_first=True, bidirectional=True)
        self.decoder = nn.LSTM(hidden, half, num_layers=1, batch_first=True, bidirectional=True)
        self.drop = nn.Dropout(dropout)
        self.out = nn.Linear(hidden, out_features)
        nn.init.zeros_(self.out.weight)  # start at the residual's base (zero velocity / interpolation)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: Tensor) -> Tensor:
        with native_cpu_rnn(x):                                 # the same LSTMs, faster to train on a CPU
            states, (h, c) = self.encoder(x)                    # eq. 1: H_1..H_L  [N, L, hidden]
            y, _ = self.decoder(self.drop(states), (h, c))      # eq. 2: all states in, one per step
        return self.out(self.drop(y))                           # [N, L, out_features]


def joint_and_flow_loss(pred: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """``L_J`` (eq. 6) and ``L_MF`` (eqs. 7-8) as mean squared errors over ``[N, L, F]``."""
    l_j = F.mse_loss(pred, target)
    if pred.shape[1] > 1:
        l_mf = F.mse_loss(pred[:, 1:] - pred[:, :-1], target[:, 1:] - target[:, :-1])
    else:
        l_mf = pred.sum() * 0.0
    return l_j, l_mf


class GloGen(MotionModel):
    """GlocalNet stage 1: class-conditioned sparse-pose Seq2Seq (section 3.1).

    Hyperparameters: ``t_in`` (chunk length ``t`` = seed poses), ``t_out`` (evaluation horizon in
    sparse poses, a multiple of ``t_in``; ``None``: rest of the window), ``hidden`` (bi-LSTM
    output width, even), ``dropout``, ``lambda_joint`` / ``lambda_flow`` (eq. 5),
    ``pair_stride`` (offset between training chunk pairs), ``residual`` (predict offsets from
    the last input pose).
    """

    family = "glocal"
    uses_controls = False
    uses_labels = True

    def __init__(self, spec: DataSpec, t_in: int = 5, t_out: int | None = None, hidden: int = 200,
                 dropout: float = 0.25, lambda_joint: float = 1.0, lambda_flow: float = 1.0,
                 pair_stride: int = 1, residual: bool = True):
        super().__init__(spec)
        t = _check_int("t_in", t_in, 1)
        check_seq2seq_hparams(hidden, dropout, lambda_joint, lambda_flow)
        _check_int("pair_stride", pair_stride, 1)
        if not isinstance(residual, bool):
            raise ValueError(f"residual must be true or false, got {residual!r}")
        every = _check_int("spec.every", spec.every, 1)
        n_sparse = (spec.window - 1) // every + 1
        if n_sparse < 2 * t:
            raise ValueError(f"GloGen needs windows of >= 2 * t_in = {2 * t} sparse poses; the data's windows have "
                             f"{n_sparse} ({spec.window} frames every {every}); lower t_in")
        if t_out is None:
            t_out = (n_sparse - t) // t * t
        _check_int("t_out", t_out, 1)
        if t_out % t:
            raise ValueError(f"t_out must be a multiple of t_in = {t} (whole chunks are rolled out), got {t_out}")
        if t + t_out > n_sparse:
            raise ValueError(f"t_in + t_out = {t + t_out} exceeds the window's {n_sparse} sparse poses")
        self.t, self.t_out = t, int(t_out)
        self.seed_frames = t
        self.num_classes = int(spec.num_classes)
        self.lambda_joint, self.lambda_flow = float(lambda_joint), float(lambda_flow)
        self.pair_stride, self.residual = pair_stride, residual
        feats = spec.pose_features
        self.net = BiSeq2Seq(feats + self.num_classes, feats, hidden, float(dropout))

    # ------------------------------------------------------------------ core
    def _labels(self, labels: Tensor | None, n: int) -> Tensor | None:
        if self.num_classes == 0:
            return None
        if labels is None:
            raise ValueError(f"GloGen was built for {self.num_classes} classes and needs labels (the class prior)")
        labels = labels.long().reshape(-1)
        if labels.numel() != n:
            raise ValueError(f"expected {n} labels, got {labels.numel()}")
        if labels.numel() and (int(labels.min()) < 0 or int(labels.max()) >= self.num_classes):
            raise ValueError(f"labels must lie in [0, {self.num_classes}), got {labels.min()}..{labels.max()}")
        return labels

    def step(self, chunk: Tensor, labels: Tensor | None) -> Tensor:
        """One chunk ahead: ``chunk [N, t, F]`` (+ class ``labels [N]``) -> next chunk ``[N, t, F]``."""
        x = chunk
        if self.num_classes:
            onehot = F.one_hot(labels, self.num_classes).to(chunk.dtype)          # [N, C]
            x = torch.cat([chunk, onehot[:, None].expand(-1, chunk.shape[1], -1)], dim=-1)
        out = self.net(x)                                                        # eqs. 1-2
        return out + chunk[:, -1:] if self.residual else out

    def sparse(self, batch: Batch) -> Tensor:
        """The window's sparse poses ``[B, n, J, D]``."""
        return batch.pose[:, ::batch.every]

    def target(self, batch: Batch) -> Tensor:
        """Ground truth that :meth:`predict` is compared with: ``[B, t_in + t_out, J, D]`` sparse poses."""
        return self.sparse(batch)[:, :self.t + self.t_out]

    # ------------------------------------------------------------------ interface
    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        sp = self.flat(self.sparse(batch))                                   # [B, n, F]
        B, n, feats = sp.shape
        t = self.t
        if n < 2 * t:
            raise ValueError(f"window has {n} sparse poses; GloGen needs >= 2 * t_in = {2 * t}")
        labels = self._labels(batch.labels, B)
        pairs = sp.unfold(1, 2 * t, self.pair_stride)                        # [B, P, F, 2t]
        P = pairs.shape[1]
        pairs = pairs.permute(0, 1, 3, 2).reshape(B * P, 2 * t, feats)       # [B*P, 2t, F]
        lab = labels.repeat_interleave(P) if labels is not None else None
        pred = self.step(pairs[:, :t], lab)                                  # teacher forced
        l_j, l_mf = joint_and_flow_loss(pred, pairs[:, t:])                  # eqs. 6-8
        loss = self.lambda_joint * l_j + self.lambda_flow * l_mf            # eq. 5
        return loss, {"L_J": float(l_j.detach()), "L_MF": float(l_mf.detach())}

    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int | None = None, num_samples: int = 1) -> Tensor:
        """Roll out sparse poses: ``seed [B, S >= t_in, J, D]`` -> ``[B * num_samples, length, J, D]``.

        ``labels`` ``[B]`` (one class) or ``[B, length]`` (a class per output pose: the chunk
        starting at pose ``p`` uses ``labels[:, p]``). ``length`` defaults to ``t_in + t_out``.
        """
        t = self.t
        length = self.t + self.t_out if length is None else _check_int("length", length, 1)
        _check_int("num_samples", num_samples, 1)
        J, D = self.spec.joints, self.spec.dims
        if seed is None:
            B = 1 if labels is None else int(labels.shape[0])
            p = next(self.parameters())
            seed = torch.zeros(B, t, J, D, dtype=p.dtype, device=p.device)
        if seed.dim() != 4 or seed.shape[2:] != (J, D):
            raise ValueError(f"seed must be [B, S, {J}, {D}], got {tuple(seed.shape)}")
        B, S = int(seed.shape[0]), int(seed.shape[1])
        if S < t:
            raise ValueError(f"GloGen needs a seed of >= t_in = {t} sparse poses, got {S}")
        if length < S:
            raise ValueError(f"length ({length}) must be >= the seed's {S} poses")
        per_step = labels is not None and labels.dim() == 2
        if per_step and labels.shape != (B, length):
            raise ValueError(f"per-step labels must be [B, length] = [{B}, {length}], got {tuple(labels.shape)}")
        if not per_step:
            labels = self._labels(labels, B)
        else:
            self._labels(labels.reshape(-1), B * length)
        if num_samples > 1:
            seed = seed.repeat_interleave(num_samples, 0)
            labels = labels.repeat_interleave(num_samples, 0) if labels is not None else None
        x = self.flat(seed)
        chunks, cur, pos = [x], x[:, -t:], S
        while pos < length:                         # auto-regressive roll-out, one chunk per step
            lab = None
            if labels is not None:
                lab = labels[:, pos] if per_step else labels
            cur = self.step(cur, lab)
            chunks.append(cur)
            pos += t
        return self.unflat(torch.cat(chunks, 1)[:, :length])

    @torch.no_grad()
    def predict(self, batch: Batch) -> Tensor:
        """The first ``t_in + t_out`` SPARSE poses of the window given its first ``t_in`` (and its label)."""
        sp = self.sparse(batch)
        if sp.shape[1] < self.t + self.t_out:
            raise ValueError(f"window has {sp.shape[1]} sparse poses; predict needs t_in + t_out = "
                             f"{self.t + self.t_out}")
        return self.generate(sp[:, :self.t], labels=batch.labels, length=self.t + self.t_out)

"""Shared machinery of the recurrent baselines (ERD, LSTM-3LR, Seq2Seq, acLSTM, scheduled sampling).

Every recurrent baseline is an *encoder - recurrent core - decoder* next-frame predictor
(Fragkiadaki et al. 2015, Sec. 3, the ERD view that contains the others as special cases):

    x_t   = [s_t, c_t]                                  input of step t
    e_t   = f_enc(x_t)                                  MLP, or the identity (LSTM-3LR, Seq2Seq, acLSTM)
    h_t   = RNN(e_t, h_{t-1})                           nn.LSTM (ERD, LSTM-3LR, acLSTM) / nn.GRU (Seq2Seq)
    s^_{t+1} = f_dec(h_t) [+ s_t]                       MLP / linear; "+ s_t" = residual velocity (Seq2Seq;
                                                        the others' ``residual`` option)

Features of a frame (``Fy`` = size of ``s_t``, ``Fc`` = size of ``c_t``):

* ``s_t`` (the *state*, what the model predicts and feeds back): the flattened pose
  ``J*D``, plus the 3 control signals when the dataset has them and
  ``control_mode == "predict"`` (VAE-LSTM paper, Table 1 protocol: the model predicts
  pose and controls jointly and feeds its own predicted controls back);
* ``c_t`` (conditioning, input only): the 3 ground-truth controls of the frame being
  predicted (``t+1``) when ``control_mode == "given"`` (Table 2 protocol), and the one-hot
  class when ``spec.num_classes > 0`` (also of frame ``t+1``, so that per-frame labels
  ``[B, T]`` drive transitions in :meth:`RecurrentBaseline.generate`).

Training schemes (which input each step sees: the ground-truth frame ``s_t`` or the
model's own previous prediction ``s^_t``), all expressed by one boolean *ground-truth mask*
over the ``N = T-1`` input steps and run by :meth:`RecurrentBaseline._rollout`:

* teacher forcing (ERD, LSTM-3LR): mask all true -> ONE nn.LSTM call over the whole
  window (cuDNN / oneDNN path);
* auto-conditioning (acLSTM, Li et al. 2017 Sec. 3): ``ground_truth_len`` true, then
  ``condition_len`` false, repeated;
* sampling-based loss (Seq2Seq, Martinez et al. 2017 Sec. 4): true for the seed
  (encoder) frames, false for every decoder step;
* scheduled sampling (Bengio et al. 2015 Sec. 2.4), an option of every recurrent
  baseline: each input of each sequence is the ground truth with probability
  ``eps_i = k / (k + exp(i / k))`` (inverse-sigmoid decay, Bengio's Sec. 2.4 / Fig. 2),
  else the model's previous prediction. ``i`` counts training steps (``ss_unit: step``,
  Bengio's unit; a persistent buffer ``ss_step``, so resumed runs continue the
  schedule) or epochs (``ss_unit: epoch``, the trainer calls :meth:`set_epoch`). With the
  acLSTM mask the coin applies to its ground-truth frames; with Seq2Seq to its decoder
  steps (so that ``eps -> 0`` is exactly Martinez's sampling-based loss).

Speed. Runs of steps that take the ground truth for the whole batch go through the
nn.LSTM / nn.GRU module in one call (16 or more steps, or any run when no gradient is
needed). Self-fed steps need a Python step loop; there the step uses the module's own
weights (``weight_ih_l*`` ...) functionally. With autograd, a per-step ``x @ W.T`` makes
the backward compute and accumulate a full ``dW`` at every step (a rank-``B`` update of
each 4096 x 2048 weight at the paper size), which is what makes per-step LSTM training
slow on CPUs. :class:`_DeferredMM` / :class:`_DeferredWeight` keep the forward and the
per-step input gradients exact but compute each weight's gradient ONCE per backward, as
one GEMM over all steps (``dW = G^T X``): same result up to float summation order
(tests compare against plain autograd in float64). ``step_impl`` selects the
implementation: ``"deferred"`` (default, fastest), ``"cell"`` (``lstm_cell`` /
``gru_cell`` per layer: the LSTMCell-stack of the acLSTM reference code) or
``"module"`` (the nn.LSTM module called on one step with ``(h, c)`` carried). Two more
things make the deferred path fast: its GEMMs (the 32-row step GEMMs and the one
weight-gradient GEMM) go through oneDNN (:func:`gemm_nt`), which on this project's AMD
EPYC machines runs twice as fast as MKL's sgemm (MKL takes its AVX2 path on AMD: 185 vs
388 GFLOP/s for a 4096^2 fp32 matmul on 2 threads), and short ground-truth runs go layer by
layer with each layer's input projection as one GEMM over the run. Measured for acLSTM at
the paper size (3 x 1024, B=32, 100-frame windows = 99 steps, 57 x 3 joints, forward +
backward + Adam, 2 threads, median after warm-up, ``bench/train.py``): deferred 14.3-19.1
sequences/s (412 GFLOP per step, 55 % of the oneDNN matmul rate); the same with MKL GEMMs
8.7-9.0; cell 6.3, module 4.5; the authors' LSTMCell code 6.2 (issue 3) to 8.2.

Shapes: ``pose`` ``[B, T, J, D]``, state frames ``[B, T, Fy]``, conditioning
``[B, T-1, Fc]`` (aligned with the input steps), rollout outputs ``[B, T-1, Fy]``
(``out[:, t]`` predicts frame ``t+1``).
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.autograd import Function
from torch.autograd.function import once_differentiable

from .base import Batch, DataSpec, MotionModel, check_int

CONTROL_MODES = ("given", "predict")
FAMILIES = (None, "vae_lstm", "glocal")
STEP_IMPLS = ("deferred", "cell", "module")
#: ground-truth runs at least this long go through the nn.LSTM / nn.GRU module in one call
#: while training (shorter runs, e.g. acLSTM's 5-frame segments, stay in the step loop:
#: a oneDNN RNN call has a per-call cost of several steps at the paper size)
MODULE_RUN = 16


# ----------------------------------------------------------------------------- validation
def check_sizes(name: str, value) -> tuple[int, ...]:
    if isinstance(value, int):
        value = (value,)
    try:
        sizes = tuple(value)
    except TypeError:
        raise ValueError(f"{name} must be a list of positive integers, got {value!r}") from None
    for v in sizes:
        check_int(f"every entry of {name}", v)
    return sizes


def check_family(family) -> str | None:
    if family not in FAMILIES:
        raise ValueError(f"family must be one of {FAMILIES} (None: the dataset's training.family), got {family!r}")
    return family


def default_seed_frames(spec: DataSpec, seed_frames) -> int:
    """``None``: 60 frames on long (>= 120-frame, locomotion) windows, the VAE-LSTM paper's
    baseline protocol; else ``window // 6`` (10 of the 60-frame 2-D benchmark windows:
    GlocalNet's 10 observed + 50 predicted poses)."""
    if seed_frames is None:
        return 60 if spec.window >= 120 else max(1, spec.window // 6)
    return check_int("seed_frames", seed_frames)


def mlp(sizes: Sequence[int], activate_last: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if activate_last or i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


# ----------------------------------------------------------------------------- deferred weight gradients
def _onednn_linear_available() -> bool:
    """Whether this build has oneDNN's dense linear op (x86 CPU wheels do)."""
    try:
        y = torch.ops.mkldnn._linear_pointwise(torch.ones(1, 2), torch.ones(2, 2), None, "none", [], "")
        return bool(torch.allclose(y, torch.full((1, 2), 2.0)))
    except Exception:  # noqa: BLE001 - any failure: use plain addmm / mm
        return False


_ONEDNN = _onednn_linear_available()


def _onednn_ok(*ts: Tensor) -> bool:
    return _ONEDNN and all(t.device.type == "cpu" and t.dtype == torch.float32 for t in ts)


def gemm_nt(x: Tensor, w: Tensor, bias: Tensor | None = None) -> Tensor:
    """``x @ w^T (+ bias)`` for ``x`` ``[M, K]``, ``w`` ``[N, K]`` (both contiguous).

    float32 on CPU goes through oneDNN (``mkldnn::_linear_pointwise``), else ``addmm``:
    equal up to float summation order. On this project's AMD EPYC machines MKL's sgemm
    takes its AVX2 path while oneDNN uses AVX-512, which doubles the throughput of the
    32-row step GEMMs (105 -> 210 GFLOP/s on 2 threads) and of the weight-gradient GEMM
    (209 -> 455 GFLOP/s); see ``bench/train.py``."""
    if _onednn_ok(x, w):
        return torch.ops.mkldnn._linear_pointwise(x, w, bias, "none", [], "")
    return x.mm(w.t()) if bias is None else torch.addmm(bias, x, w.t())


class _Packed:
    """A weight ``W`` ``[N, K]`` for ``x @ W^T``, held for a forward (or a backward) pass."""

    __slots__ = ("w",)

    def __init__(self, w: Tensor):
        self.w = w.contiguous()

    def __call__(self, x: Tensor, bias: Tensor | None = None) -> Tensor:
        return gemm_nt(x.contiguous(), self.w, bias)


class _Store:
    """(output gradient, input) pairs of every :class:`_DeferredMM` on one weight, and the
    packed weights of the forward (``W``) and of the backward (``W^T``, packed lazily)."""

    __slots__ = ("grads", "inputs", "fwd", "bwd")

    def __init__(self, fwd: _Packed):
        self.grads: list[Tensor] = []
        self.inputs: list[Tensor] = []
        self.fwd, self.bwd = fwd, None


class _DeferredWeight(Function):
    """Identity on ``(weight, bias)``. Every :class:`_DeferredMM` consumes its outputs, so
    autograd runs this backward after all of theirs: it then computes the weight gradient
    of all steps in one GEMM, ``dW = sum_t g_t^T x_t = G^T X``, and ``db = sum G``."""

    @staticmethod
    def forward(ctx, weight: Tensor, bias: Tensor, store: _Store):
        ctx.store = store
        ctx.set_materialize_grads(False)
        return weight.view_as(weight), bias.view_as(bias)

    @staticmethod
    @once_differentiable
    def backward(ctx, gw, gb):
        store = ctx.store
        if store.grads:  # G^T X as one GEMM of the transposed stacks (G^T [N, R], X^T [K, R])
            gt = torch.cat([g.t() for g in store.grads], 1)
            dw, db = gemm_nt(gt, torch.cat([x.t() for x in store.inputs], 1)), gt.sum(1)
            gw = dw if gw is None else gw + dw
            gb = db if gb is None else gb + db
        store.grads, store.inputs, store.bwd = [], [], None
        return gw, gb, None


class _DeferredMM(Function):
    """``x @ W^T + b`` whose backward returns the input gradient only and leaves the
    weight gradient to :class:`_DeferredWeight` (``W``, ``b`` must come from it)."""

    @staticmethod
    def forward(ctx, x: Tensor, weight: Tensor, bias: Tensor, store: _Store):
        ctx.save_for_backward(x)
        ctx.store = store
        return store.fwd(x, bias)

    @staticmethod
    @once_differentiable
    def backward(ctx, g):
        (x,) = ctx.saved_tensors
        store = ctx.store
        store.grads.append(g)
        store.inputs.append(x)
        if not ctx.needs_input_grad[0]:
            return None, None, None, None
        if store.bwd is None:  # dX = g @ W = g @ (W^T)^T: W^T made contiguous once per backward
            store.bwd = _Packed(store.fwd.w.t())
        return store.bwd(g), None, None, None


class _Linear:
    """One weight of a step: deferred weight gradient (training) or plain, packed GEMM."""

    __slots__ = ("w", "b", "store", "fwd")

    def __init__(self, w: Tensor, b: Tensor, deferred: bool):
        self.fwd = _Packed(w.detach())
        self.store = _Store(self.fwd) if deferred else None
        self.w, self.b = _DeferredWeight.apply(w, b, self.store) if deferred else (w, b)

    def __call__(self, x: Tensor) -> Tensor:
        if self.store is None:
            return self.fwd(x, self.b) if not torch.is_grad_enabled() else torch.addmm(self.b, x, self.w.t())
        return _DeferredMM.apply(x, self.w, self.b, self.store)


# ----------------------------------------------------------------------------- recurrent core
State = tuple  # (list of h per layer,) for GRU, (list of h, list of c) for LSTM


class RecurrentCore(nn.Module):
    """A multi-layer ``nn.LSTM`` / ``nn.GRU`` (batch first) that runs either whole
    sequences (one module call) or single steps with the module's own weights."""

    def __init__(self, cell: str, input_size: int, hidden_size: int, num_layers: int, step_impl: str = "deferred"):
        super().__init__()
        if cell not in ("lstm", "gru"):
            raise ValueError(f"cell must be 'lstm' or 'gru', got {cell!r}")
        if step_impl not in STEP_IMPLS:
            raise ValueError(f"step_impl must be one of {STEP_IMPLS}, got {step_impl!r}")
        self.cell, self.step_impl = cell, step_impl
        self.hidden_size, self.num_layers = hidden_size, num_layers
        self.rnn = (nn.LSTM if cell == "lstm" else nn.GRU)(input_size, hidden_size, num_layers, batch_first=True)

    # state conversion: module format (stacked [L, B, H]) <-> per-layer lists
    def _pack(self, state: State | None):
        if state is None:
            return None
        if self.cell == "lstm":
            return torch.stack(state[0]), torch.stack(state[1])
        return torch.stack(state[0])

    def _unpack(self, st) -> State:
        if self.cell == "lstm":
            return list(st[0].unbind(0)), list(st[1].unbind(0))
        return (list(st.unbind(0)),)

    def zero_state(self, batch: int, like: Tensor) -> State:
        z = [like.new_zeros(batch, self.hidden_size) for _ in range(self.num_layers)]
        return (z, [t.clone() for t in z]) if self.cell == "lstm" else (z,)

    def sequence(self, x: Tensor, state: State | None) -> tuple[Tensor, State]:
        """``x`` ``[B, L, K]`` -> top-layer outputs ``[B, L, H]`` and the final state."""
        y, st = self.rnn(x, self._pack(state))
        return y, self._unpack(st)

    def stepper(self) -> "_Stepper":
        """A step function bound to this forward pass (its deferred weights live until the
        backward that consumes them)."""
        return _Stepper(self)


class _Stepper:
    """Steps (and short ground-truth runs) of a :class:`RecurrentCore` with its weights."""

    def __init__(self, core: RecurrentCore):
        r, self.core = core.rnn, core
        self.lstm = core.cell == "lstm"
        self.impl = core.step_impl
        params = [[getattr(r, f"{n}_l{i}") for n in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")]
                  for i in range(core.num_layers)]
        if self.impl == "deferred":
            deferred = torch.is_grad_enabled() and any(p.requires_grad for p in r.parameters())
            self.ih = [_Linear(w, b, deferred) for w, _, b, _ in params]
            self.hh = [_Linear(w, b, deferred) for _, w, _, b in params]
        else:
            self.params = params

    def _cell(self, i: int, gi: Tensor, h: Tensor, c: Tensor | None) -> tuple[Tensor, Tensor | None]:
        """Layer ``i`` from its input projection ``gi = W_ih x + b_ih`` (PyTorch's LSTM / GRU
        equations, gate order i, f, g, o / r, z, n)."""
        gh = self.hh[i](h)
        if self.lstm:
            i, f, g, o = (gi + gh).chunk(4, 1)
            c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
            return torch.sigmoid(o) * torch.tanh(c), c
        ir, iz, inn = gi.chunk(3, 1)
        hr, hz, hn = gh.chunk(3, 1)
        r, z = torch.sigmoid(ir + hr), torch.sigmoid(iz + hz)
        n = torch.tanh(inn + r * hn)
        return n + z * (h - n), None  # (1 - z) * n + z * h

    def __call__(self, x: Tensor, state: State) -> tuple[Tensor, State]:
        """One step: ``x`` ``[B, K]`` -> top-layer ``h`` ``[B, H]`` and the new state."""
        if self.impl == "module":
            y, st = self.core.sequence(x.unsqueeze(1), state)
            return y[:, 0], st
        hs, new_h = state[0], []
        cs, new_c = (state[1], []) if self.lstm else (None, None)
        inp = x
        for i in range(len(hs)):
            if self.impl == "cell":  # the LSTMCell / GRUCell stack
                if self.lstm:
                    h, c = torch._VF.lstm_cell(inp, (hs[i], cs[i]), *self.params[i])
                else:
                    h, c = torch._VF.gru_cell(inp, hs[i], *self.params[i]), None
            else:
                h, c = self._cell(i, self.ih[i](inp), hs[i], cs[i] if self.lstm else None)
            new_h.append(h)
            if self.lstm:
                new_c.append(c)
            inp = h
        return inp, ((new_h, new_c) if self.lstm else (new_h,))

    def run(self, x: Tensor, state: State) -> tuple[Tensor, State]:
        """A ground-truth run ``x`` ``[B, L, K]`` -> ``[B, L, H]``. Deferred: layer by layer,
        each layer's input projection one GEMM over the run (its weight is read once, not
        ``L`` times), only ``W_hh`` per step."""
        if self.impl == "module":
            return self.core.sequence(x, state)
        if self.impl == "cell":
            ys = []
            for t in range(x.shape[1]):
                y, state = self(x[:, t], state)
                ys.append(y)
            return torch.stack(ys, 1), state
        B, L, _ = x.shape
        hs, cs = list(state[0]), (list(state[1]) if self.lstm else None)
        inp = x
        for i in range(len(hs)):
            gi = self.ih[i](inp.reshape(B * L, -1)).view(B, L, -1)
            h, c, ys = hs[i], (cs[i] if self.lstm else None), []
            for g_t in gi.unbind(1):
                h, c = self._cell(i, g_t, h, c)
                ys.append(h)
            hs[i] = h
            if self.lstm:
                cs[i] = c
            inp = torch.stack(ys, 1)
        return inp, ((hs, cs) if self.lstm else (hs,))


def runs(col: Tensor) -> list[tuple[int, int, bool]]:
    """Maximal runs ``(start, end, value)`` of a boolean vector."""
    vals = col.tolist()
    out, s = [], 0
    for t in range(1, len(vals) + 1):
        if t == len(vals) or vals[t] != vals[s]:
            out.append((s, t, bool(vals[s])))
            s = t
    return out


# ----------------------------------------------------------------------------- roll-out plumbing
def seed_inputs(model: MotionModel, seed: Tensor | None, controls: Tensor | None, labels: Tensor | None,
                length: int) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """The start of a roll-out of a next-frame model (``pose_dim``, ``ctrl_dim``, ``predict_controls``):
    the seed on the model's device and dtype (no seed: one mean pose, zeros in normalised units), the
    controls likewise, and the seed's controls under ``predict`` (``controls[:, :S]``, else zeros)."""
    check_int("length", length)
    p = next(model.parameters())
    if seed is None or seed.shape[1] == 0:
        B = next((t.shape[0] for t in (seed, controls, labels) if t is not None), 1)
        seed = p.new_zeros(B, 1, model.spec.joints, model.spec.dims)
    seed = seed.to(p)
    B, S = seed.shape[:2]
    if controls is not None:
        controls = controls.to(p)
    seed_ctrl = None
    if model.predict_controls and S < length:
        seed_ctrl = controls[:, :S] if controls is not None else p.new_zeros(B, S, model.ctrl_dim)
    return seed, controls, seed_ctrl


def rollout_output(model: MotionModel, seed: Tensor, gen: Tensor, seed_ctrl: Tensor | None,
                   controls: Tensor | None, length: int) -> tuple[Tensor, Tensor | None]:
    """The seed followed by the generated state frames ``gen`` ``[B, length-S, Fy]`` as poses
    ``[B, length, J, D]``, and the roll-out's controls: under ``predict`` the seed's then the generated
    ones, under ``given`` the given ones, else ``None``."""
    out = torch.cat([seed, model.unflat(gen[..., :model.pose_dim].contiguous())], 1)
    if model.predict_controls:
        return out, torch.cat([seed_ctrl, gen[..., model.pose_dim:]], 1)
    return out, (controls[:, :length] if model.given_controls else None)


# ----------------------------------------------------------------------------- the baseline base class
class RecurrentBaseline(MotionModel):
    """Encoder-recurrent-decoder next-frame predictor; subclasses choose the core, the
    sizes and the training mask (see the module docstring).

    Hyperparameters common to all recurrent baselines:

    * ``hidden_size``, ``num_layers``: the recurrent core;
    * ``encoder_sizes`` / ``decoder_sizes``: hidden sizes of the input / output MLPs
      (empty: identity encoder, linear decoder);
    * ``control_mode``: ``"predict"`` (default) or ``"given"``, see the module docstring;
    * ``seed_frames``: ground-truth frames given to :meth:`predict` (``None``: 60 on
      locomotion-length windows, ``window // 6`` on short ones);
    * ``family``: ``None`` (default: the windows the dataset config names in
      ``training.family``; the class attribute is ``None`` so the trainer takes the
      dataset's), or ``"vae_lstm"`` / ``"glocal"``, recorded on the instance;
    * ``scheduled_sampling``, ``ss_k``, ``ss_unit``: Bengio et al.'s schedule;
    * ``ss_detach``: a self-fed input of scheduled sampling enters as a constant, as Bengio et al.'s
      sampled token does (no gradient flows back through it into the step that predicted it); ``false``
      (default) keeps that gradient, as acLSTM's and Seq2Seq's self-fed steps always do (validation
      measured both ways in ``conf/model/scheduled_sampling.yaml``: ``true`` is clearly worse on
      bandai2_locomotion, so the default stays);
    * ``input_noise``: Gaussian noise on the ground-truth inputs while training (Fragkiadaki
      et al.'s noise curriculum): a std, or a list of stds, each used for an equal share of the
      training budget in turn (the trainer reports the progress, :meth:`set_progress`);
    * ``step_impl``: ``"deferred"`` / ``"cell"`` / ``"module"`` (same numbers, different speed);
    * ``residual``: the decoder predicts the change from the frame fed in (``s^_{t+1} = f_dec(h_t) +
      s_t``, Martinez et al.'s residual velocity) and its last layer starts at zero, so the untrained
      model is the zero-velocity baseline. ``None`` (default): the class's choice, true for Seq2Seq
      and its variants, false for the others, which the papers (ERD, LSTM-3LR, acLSTM, Bengio et
      al.) write as pose predictors. ``true`` on ERD, acLSTM and scheduled sampling is a departure
      of ours, set per dataset where validation chose it (``model_overrides`` in
      ``conf/dataset/<name>.yaml``; the figures are in the README's *Departures*);
    * ``train_window``: train on random crops of this many frames of each window (acLSTM's authors
      train on 100-frame sequences; ``None``: whole windows). Evaluation always sees whole windows;
    * ``horizon_power`` ``p`` (ours, default 0: the papers' plain MSE): the training loss weights the
      squared error of the ``h``-th predicted step by ``h^-p``, normalised to mean 1 over the steps.
      ``p = 1`` is the selection criterion's 1/h weighting (:mod:`motionsynth.training.criteria`)
      used as the objective. Measured on ``cmu_aclstm`` (Seq2Seq, seed 0, validation split): plain
      MSE selects ``rel_zv`` 0.819 with a first predicted frame at 1.04 times zero-velocity's MSE;
      ``p = 0.5`` 0.798 (0.99); ``p = 1`` 0.773 (0.94), its 20th frame 0.63 against 0.62.
    """

    family = None  # type: ignore[assignment]  # the trainer then uses dataset.training.family
    uses_controls = True
    uses_labels = True
    #: recurrent cell of the core
    cell: str = "lstm"
    #: residual velocity: the decoder predicts s_{t+1} - s_t (Martinez et al. Sec. 4)
    residual: bool = False

    def __init__(self, spec: DataSpec, hidden_size: int, num_layers: int, *, encoder_sizes: Sequence[int] = (),
                 decoder_sizes: Sequence[int] = (), control_mode: str = "predict", seed_frames: int | None = None,
                 family: str | None = None, scheduled_sampling: bool = False, ss_k: float = 100.0,
                 ss_unit: str = "step", input_noise: float | Sequence[float] = 0.0,
                 step_impl: str = "deferred", train_window: int | None = None, horizon_power: float = 0.0,
                 ss_detach: bool = False, residual: bool | None = None):
        super().__init__(spec)
        if residual is not None:   # the config's choice, else the class's (Seq2Seq: true; the others: false)
            if not isinstance(residual, bool):
                raise ValueError(f"residual must be true, false or null, got {residual!r}")
            self.residual = residual
        if not isinstance(ss_detach, bool):
            raise ValueError(f"ss_detach must be true or false, got {ss_detach!r}")
        self.ss_detach = ss_detach
        if not isinstance(horizon_power, (int, float)) or isinstance(horizon_power, bool) or horizon_power < 0:
            raise ValueError(f"horizon_power must be a number >= 0, got {horizon_power!r}")
        self.horizon_power = float(horizon_power)
        check_int("hidden_size", hidden_size)
        check_int("num_layers", num_layers)
        self.train_window = None if train_window is None else check_int("train_window", train_window, 2)
        encoder_sizes = check_sizes("encoder_sizes", encoder_sizes)
        decoder_sizes = check_sizes("decoder_sizes", decoder_sizes)
        if control_mode not in CONTROL_MODES:
            raise ValueError(f"control_mode must be one of {CONTROL_MODES}, got {control_mode!r}")
        if spec.controls not in (0, 3):
            raise ValueError(f"spec.controls must be 0 or 3, got {spec.controls!r}")
        if not isinstance(scheduled_sampling, bool):
            raise ValueError(f"scheduled_sampling must be true or false, got {scheduled_sampling!r}")
        if not (isinstance(ss_k, (int, float)) and not isinstance(ss_k, bool) and math.isfinite(ss_k) and ss_k >= 1):
            raise ValueError(f"ss_k must be a number >= 1 (Bengio et al.'s inverse-sigmoid k), got {ss_k!r}")
        if ss_unit not in ("step", "epoch"):
            raise ValueError(f"ss_unit must be 'step' or 'epoch', got {ss_unit!r}")
        noise = [input_noise] if isinstance(input_noise, (int, float)) else list(input_noise)
        if not noise or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0 for v in noise):
            raise ValueError(f"input_noise must be a std >= 0 or a non-empty list of them, got {input_noise!r}")
        self.hidden_size, self.num_layers = hidden_size, num_layers
        self.control_mode = control_mode
        self.seed_frames = default_seed_frames(spec, seed_frames)
        self.family = check_family(family)
        self.scheduled_sampling, self.ss_k, self.ss_unit = scheduled_sampling, float(ss_k), ss_unit
        self.noise_levels = [float(v) for v in noise]
        self.epoch, self.progress = 0, 0.0
        if scheduled_sampling:
            self.register_buffer("ss_step", torch.zeros((), dtype=torch.long))

        self.pose_dim = spec.pose_features
        self.ctrl_dim = spec.controls
        self.predict_controls = control_mode == "predict" and spec.controls > 0
        self.given_controls = control_mode == "given" and spec.controls > 0
        self.state_dim = self.pose_dim + (self.ctrl_dim if self.predict_controls else 0)          # Fy
        self.cond_dim = (self.ctrl_dim if self.given_controls else 0) + spec.num_classes          # Fc
        self.input_dim = self.state_dim + self.cond_dim
        self.encoder = mlp((self.input_dim, *encoder_sizes), activate_last=True) if encoder_sizes else nn.Identity()
        core_in = encoder_sizes[-1] if encoder_sizes else self.input_dim
        self.core = RecurrentCore(self.cell, core_in, hidden_size, num_layers, step_impl)
        self.decoder = mlp((hidden_size, *decoder_sizes, self.state_dim), activate_last=False)
        if self.residual:  # an untrained residual model is zero-velocity (see Seq2Seq's docstring)
            nn.init.zeros_(self.decoder[-1].weight)
            nn.init.zeros_(self.decoder[-1].bias)

    # ------------------------------------------------------------------ schedules
    def set_epoch(self, epoch: int) -> None:
        """Called by the trainer at the start of every training epoch (noise curriculum,
        scheduled sampling with ``ss_unit: epoch``)."""
        self.epoch = int(epoch)

    def set_progress(self, step: int, total: int) -> None:
        """Called by the trainer before every optimiser step: the share of the budget done."""
        self.progress = step / total if total > 0 else 0.0

    def teacher_forcing_prob(self) -> float:
        """Bengio et al. (2015) inverse-sigmoid decay ``eps_i = k / (k + exp(i / k))``."""
        if not self.scheduled_sampling:
            return 1.0
        i = self.epoch if self.ss_unit == "epoch" else int(self.ss_step)
        return self.ss_k / (self.ss_k + math.exp(min(i / self.ss_k, 700.0)))

    def noise_std(self) -> float:
        return self.noise_levels[min(int(self.progress * len(self.noise_levels)), len(self.noise_levels) - 1)]

    # ------------------------------------------------------------------ features
    def _state(self, pose: Tensor, controls: Tensor | None) -> Tensor:
        """``[B, T, J, D]`` (+ ``[B, T, 3]``) -> state frames ``[B, T, Fy]``."""
        y = self.flat(pose)
        if self.predict_controls:
            if controls is None:
                raise ValueError("control_mode 'predict' on a dataset with controls needs the batch's controls")
            y = torch.cat([y, controls[:, :y.shape[1]].to(y.dtype)], -1)
        return y

    def _cond(self, controls: Tensor | None, labels: Tensor | None, batch: int, length: int,
              like: Tensor) -> Tensor | None:
        """Conditioning of input steps ``0..length-2``: ``[B, length-1, Fc]`` (controls and
        class of the frame each step predicts), or ``None``."""
        parts = []
        n = length - 1
        if self.given_controls:
            if controls is None or controls.shape[1] < length:
                got = None if controls is None else tuple(controls.shape)
                raise ValueError(f"control_mode 'given' needs controls [B, {length}, 3], got {got}")
            parts.append(controls[:, 1:length].to(like.dtype))
        if self.spec.num_classes > 0:
            if labels is None:
                raise ValueError(f"{type(self).__name__} is class-conditioned ({self.spec.num_classes} classes): "
                                 "pass labels [B] or [B, length]")
            labels = labels.to(like.device).long()
            if labels.dim() == 1:
                oh = F.one_hot(labels, self.spec.num_classes).to(like.dtype)[:, None].expand(batch, n, -1)
            else:
                if labels.shape[1] < length:
                    raise ValueError(f"per-frame labels must cover {length} frames, got {tuple(labels.shape)}")
                oh = F.one_hot(labels[:, 1:length], self.spec.num_classes).to(like.dtype)
            parts.append(oh)
        return torch.cat(parts, -1) if parts else None

    # ------------------------------------------------------------------ the rollout
    def _output(self, h: Tensor, s: Tensor) -> Tensor:
        d = self.decoder(h)
        return d + s if self.residual else d

    def _rollout(self, inp: Tensor, cond: Tensor | None, mask: Tensor | None) -> Tensor:
        """Next-frame predictions over ``N`` input steps.

        ``inp`` ``[B, N, Fy]``: ground-truth input frames (``inp[:, t]`` = frame ``t``; only
        read where ``mask`` is true); ``cond`` ``[B, N, Fc]`` or ``None``; ``mask``: ``None``
        (teacher forcing), ``[N]`` or ``[B, N]`` bool, true = feed the ground truth, false =
        feed the previous output (``mask[..., 0]`` must be true). Returns ``[B, N, Fy]``.
        """
        B, N, _ = inp.shape
        if mask is None:  # teacher forcing: one module call over the whole sequence
            x = inp if cond is None else torch.cat([inp, cond], -1)
            h, _ = self.core.sequence(self.encoder(x), None)
            return self._output(h, inp)
        per_sample = mask.dim() == 2
        col = mask.all(0) if per_sample else mask
        if not bool(col[0]):
            raise ValueError("the first input step must be ground truth")
        grad = torch.is_grad_enabled()
        outs: list[Tensor] = []
        state: State | None = None
        step = None
        prev: Tensor | None = None
        for s, e, gt in runs(col):
            if step is None and not (gt and (e - s >= MODULE_RUN or not grad)):
                step = self.core.stepper()
                state = self.core.zero_state(B, inp) if state is None else state
            if gt:  # ground truth for the whole batch: one module call, or layer by layer
                x = inp[:, s:e] if cond is None else torch.cat([inp[:, s:e], cond[:, s:e]], -1)
                if e - s >= MODULE_RUN or not grad:
                    h, state = self.core.sequence(self.encoder(x), state)
                else:
                    h, state = step.run(self.encoder(x), state)
                o = self._output(h, inp[:, s:e])
                outs.append(o)
                prev = o[:, -1]
                continue
            for t in range(s, e):
                if per_sample:  # scheduled sampling's coins; ``ss_detach``: the prediction enters as a constant
                    s_t = torch.where(mask[:, t, None], inp[:, t], prev.detach() if self.ss_detach else prev)
                else:
                    s_t = prev
                x = s_t if cond is None else torch.cat([s_t, cond[:, t]], -1)
                h, state = step(self.encoder(x), state)
                prev = self._output(h, s_t)
                outs.append(prev.unsqueeze(1))
        return torch.cat(outs, 1)

    # ------------------------------------------------------------------ training
    def _base_mask(self, n: int, device) -> Tensor | None:
        """The scheme's ground-truth mask over ``n`` input steps (``None``: teacher forcing)."""
        return None

    def _ss_combine(self, base: Tensor, coin: Tensor) -> Tensor:
        """Scheduled sampling on top of the scheme: its ground-truth steps become coins."""
        return base[None] & coin

    def _train_mask(self, batch: int, n: int, device) -> tuple[Tensor | None, float]:
        base = self._base_mask(n, device)
        if not (self.scheduled_sampling and self.training):
            return base, 1.0
        eps = self.teacher_forcing_prob()
        if torch.is_grad_enabled():
            self.ss_step += 1
        coin = torch.rand(batch, n, device=device) < eps
        coin[:, 0] = True
        return (coin if base is None else self._ss_combine(base, coin)), eps

    def _objective(self, pose: Tensor, controls: Tensor | None, labels: Tensor | None,
                   start: int = 0) -> tuple[Tensor, dict[str, float]]:
        """MSE of the next-frame predictions ``start..T-2`` (frames ``start+1..T-1``)."""
        B, T = pose.shape[:2]
        if T < 2:
            raise ValueError(f"{type(self).__name__} needs windows of >= 2 frames, got {T}")
        y = self._state(pose, controls)
        cond = self._cond(controls, labels, B, T, y)
        inp, tgt = y[:, :-1], y[:, 1:]
        mask, eps = self._train_mask(B, T - 1, y.device)
        std = self.noise_std() if self.training else 0.0
        if std > 0:
            inp = inp + std * torch.randn_like(inp)
        out = self._rollout(inp, cond, mask)
        err = (out[:, start:] - tgt[:, start:]) ** 2
        if self.horizon_power:      # h^-p per predicted step, mean 1 (``horizon_power``, class docstring)
            w = torch.arange(1, err.shape[1] + 1, dtype=err.dtype, device=err.device) ** -self.horizon_power
            loss = (err.mean((0, 2)) * (w / w.mean())).mean()
        else:
            loss = err.mean()
        e = err.detach()
        logs = {"pose_mse": float(e[..., :self.pose_dim].mean())}
        if self.predict_controls:
            logs["ctrl_mse"] = float(e[..., self.pose_dim:].mean())
        if self.scheduled_sampling:
            logs["teacher_forcing_prob"] = eps
        return loss, logs

    def loss(self, batch: Batch) -> tuple[Tensor, dict[str, float]]:
        """The scheme's next-frame MSE; while training, on a random ``train_window``-frame crop of
        each batch's windows (one offset per batch) when ``train_window`` is set and shorter."""
        return self._objective(*train_crop(batch, self.train_window if self.training else None))

    # ------------------------------------------------------------------ synthesis
    @torch.no_grad()
    def generate(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                 length: int = 240, num_samples: int = 1) -> Tensor:
        """Roll out from ``seed`` ``[B, S, J, D]`` to ``length`` frames; ``[B*num_samples,
        length, J, D]`` with ``out[:, :S] == seed``. Deterministic: the ``num_samples``
        copies are equal. Without a seed the roll-out starts from the mean pose (zeros in
        normalised units), which is then frame 0. ``control_mode: given`` needs
        ``controls`` ``[B, length, 3]``; under ``predict`` the seed's controls are taken from
        ``controls[:, :S]`` when given, else zeros (the mean)."""
        check_int("num_samples", num_samples)
        out, _ = self.rollout(seed, controls, labels, length)
        return out.repeat_interleave(num_samples, 0) if num_samples > 1 else out

    @torch.no_grad()
    def rollout(self, seed: Tensor | None, controls: Tensor | None = None, labels: Tensor | None = None,
                length: int = 240) -> tuple[Tensor, Tensor | None]:
        """:meth:`generate` (one sample) that also returns the roll-out's controls ``[B, length, 3]``
        (normalised): under ``predict`` the seed's then the model's own predictions (what a
        trajectory is integrated from), under ``given`` the given ones; ``None`` without controls."""
        seed, controls, seed_ctrl = seed_inputs(self, seed, controls, labels, length)
        B, S = seed.shape[:2]
        if S >= length:
            return seed[:, :length], (controls[:, :length] if controls is not None and self.ctrl_dim else None)
        y = self._state(seed, seed_ctrl)                                   # [B, S, Fy]
        inp = torch.cat([y, y.new_zeros(B, length - 1 - S, y.shape[-1])], 1)
        cond = self._cond(controls, labels, B, length, y)
        mask = torch.arange(length - 1, device=y.device) < S
        pred = self._rollout(inp, cond, mask)[:, S - 1:]                   # frames S..length-1
        return rollout_output(self, seed, pred, seed_ctrl, controls, length)

    @torch.no_grad()
    def predict(self, batch: Batch) -> Tensor:
        """The window rolled out from its first ``seed_frames`` frames (ground-truth controls
        under ``given``, the batch's class labels)."""
        T = batch.pose.shape[1]
        S = min(self.seed_frames, T)
        return self.generate(batch.pose[:, :S], batch.controls, batch.labels, length=T)


def generate_samples(model, seed: Tensor | None, controls: Tensor | None, labels: Tensor | None, length: int,
                     num_samples: int) -> Tensor:
    """``num_samples`` independent roll-outs per input of a stochastic model with a ``rollout`` (each
    input repeated, then rolled out once): ``[B*num_samples, length, J, D]``, the samples of input
    ``b`` at rows ``b*num_samples ...``."""
    check_int("num_samples", num_samples)
    if num_samples > 1:
        rep = lambda t: None if t is None else t.repeat_interleave(num_samples, 0)  # noqa: E731
        seed, controls, labels = rep(seed), rep(controls), rep(labels)
    return model.rollout(seed, controls, labels, length)[0]


def mask_seed_length(mask: Tensor | None, model: str) -> int:
    """The length ``S`` of Seq2Seq's mask ``[N]`` (``S`` ground-truth seed steps, then self-fed ones),
    refusing the masks the encoder-decoder variants cannot run (teacher forcing, per-sample coins)."""
    if mask is None or mask.dim() != 1:
        raise ValueError(f"{model} needs a seed-then-self-fed mask over the input steps (the sampling-based "
                         "loss); teacher forcing and per-sample masks are not supported")
    S = int(mask.sum())
    if S < 1 or not bool(mask[:S].all()):
        raise ValueError(f"{model}: the mask must be a ground-truth seed followed by self-fed steps")
    return S


def train_crop(batch: Batch, window: int | None) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """``(pose, controls, labels)`` of ``batch``, cropped to a random ``window``-frame span (one offset
    per batch, drawn from torch's generator) when ``window`` is set and shorter than the windows: the
    training crops of the next-frame models (``train_window``)."""
    pose, controls, labels = batch.pose, batch.controls, batch.labels
    T = pose.shape[1]
    if window and window < T:
        off = int(torch.randint(0, T - window + 1, ()))
        sl = slice(off, off + window)
        pose = pose[:, sl]
        controls = controls[:, sl] if controls is not None else None
        labels = labels[:, sl] if labels is not None and labels.dim() == 2 else labels
    return pose, controls, labels

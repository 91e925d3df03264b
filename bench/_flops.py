"""FLOP counting for a training step: torch's FlopCounterMode, plus what it does not see:
nn.LSTM / nn.GRU's fused CPU kernels (counted analytically from their shapes) and oneDNN's
dense linear (``mkldnn::_linear_pointwise``, the recurrent step GEMMs; a registered formula)."""

from __future__ import annotations

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode, register_flop_formula


def _linear_pointwise_flops(x_shape, w_shape, *args, out_shape=None, **kwargs) -> int:
    """``x [.., K] @ w[N, K]^T``: 2 * rows * N * K."""
    rows = 1
    for d in x_shape[:-1]:
        rows *= d
    return 2 * rows * w_shape[0] * w_shape[1]


if hasattr(torch.ops, "mkldnn") and hasattr(torch.ops.mkldnn, "_linear_pointwise"):
    register_flop_formula(torch.ops.mkldnn._linear_pointwise)(_linear_pointwise_flops)


def _rnn_forward_flops(mod: nn.RNNBase, x: torch.Tensor) -> int:
    gates = {"LSTM": 4, "GRU": 3}.get(mod.mode, 1)
    batch_first = mod.batch_first
    B, T = (x.shape[0], x.shape[1]) if batch_first else (x.shape[1], x.shape[0])
    if x.dim() == 2:  # unbatched
        B, T = 1, x.shape[0]
    H, dirs = mod.hidden_size, 2 if mod.bidirectional else 1
    total, inp = 0, mod.input_size
    for _ in range(mod.num_layers):
        total += dirs * 2 * B * T * gates * H * (inp + H)
        inp = H * dirs
    return total


def step_flops(step) -> int:
    """FLOPs of one call of ``step()`` (forward + backward + update).

    Fused RNN modules count 3x their forward matmul FLOPs (forward, and the
    backward's input and weight gradients)."""
    rnn_fwd = []
    hooks = [m.register_forward_pre_hook(lambda mod, args: rnn_fwd.append(_rnn_forward_flops(mod, args[0])))
             for m in _modules(step) if isinstance(m, nn.RNNBase)]
    with FlopCounterMode(display=False) as fc:
        step()
    for h in hooks:
        h.remove()
    return int(fc.get_total_flops() + 3 * sum(rnn_fwd))


def _modules(step):
    model = getattr(step, "model", None)
    return list(model.modules()) if model is not None else []


def matmul_gflops(threads: int, n: int = 4096, repeats: int = 5, onednn: bool = False) -> float:
    """GFLOP/s (median) of a plain fp32 n x n matmul on ``threads`` threads: ``torch.mm``
    (MKL's sgemm), or oneDNN's linear with ``onednn=True``. On AMD CPUs MKL takes its AVX2
    path, so the oneDNN figure is the machine's real fp32 limit."""
    import time

    from motionsynth.models.recurrent import gemm_nt

    torch.set_num_threads(threads)
    a, b = torch.randn(n, n), torch.randn(n, n)
    fn = (lambda: gemm_nt(a, b)) if onednn else (lambda: a @ b)
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    ts.sort()
    return 2 * n ** 3 / ts[len(ts) // 2] / 1e9

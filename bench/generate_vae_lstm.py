"""Crowd generation with the VAE-LSTM at the paper's sizes: 1,000 characters x 240 frames from
the prior (Algorithm 1), one batch, eval mode, ``torch.inference_mode``, 2 threads, random weights.

Usage: python bench/generate_vae_lstm.py [--characters 1000] [--frames 240] [--threads 2]
Prints one JSON line per figure: wall time (median of 5 after 2 warm-up runs), its split over
the three stages, the batch's FLOPs (analytic, checked against torch's FlopCounterMode) and the
GFLOP/s achieved beside a plain fp32 4096 x 4096 matmul on the same threads.

FLOPs (2 per multiply-add; bias adds, pooling and the LSTM's elementwise gates are not counted),
for N characters, T frames, T' = T/4, kernel K, q = (K//2 + 1)//2, widths from conf/model/vae_lstm.yaml:
  control encoder  2*N*T*3*c1*K + 2*N*(T/2)*c1*c2*K
  control terms    2*N*T'*c2*3H                      ([W_ih; W_fh; W_h] h^c_t for all t at once)
  LSTM roll-out    2*N*T'*H*3H                       (one fused [W_ic; W_fc; W_c] matmul per step)
  up-conv i        2*N*L_i*c_in*2*c_out*(2q+1)       (polyphase, L_i = input length; the nominal
                                                      upsample-then-conv costs 2*N*2L_i*c_in*c_out*K)
  output           2*N*T*d2*P                        (1x1 conv to the P = 63 pose features)
  weight fold      2*K*2*(2q+1)*c_out*c_in per up-conv (K-tap filter -> 2 phase filters; independent of N)
"""

from __future__ import annotations

import argparse
import torch
from _flops import matmul_gflops
from _util import ROOT, emit, timed
from omegaconf import OmegaConf
from torch.utils.flop_counter import FlopCounterMode

from motionsynth.models.base import DataSpec
from motionsynth.models.vae_lstm import VAELSTM

BENCH = "generate_vae_lstm"


def generation_flops(m: VAELSTM, n: int, frames: int) -> dict[str, int]:
    """Analytic FLOPs of ``m.generate(None, controls [n, frames, 3])`` (see the module docstring)."""
    f = {"control_encoder": 0, "control_terms": 0, "lstm": 0, "upconv": 0, "upconv_nominal": 0, "output": 0,
         "weight_fold": 0}
    T = frames
    for conv in m.ctrl_encoder.convs:
        c_out, c_in, k = conv.weight.shape
        f["control_encoder"] += 2 * n * T * c_in * c_out * k
        T //= 2
    H = m.hidden
    f["control_terms"] = 2 * n * T * m.cell.ctrl.in_features * 3 * H
    f["lstm"] = 2 * n * T * H * 3 * H
    L = T
    for up in m.ups:
        c_out, c_in, k = up.conv.weight.shape
        f["upconv"] += 2 * n * L * c_in * 2 * c_out * (2 * up.q + 1)
        f["upconv_nominal"] += 2 * n * 2 * L * c_in * c_out * k
        f["weight_fold"] += 2 * k * 2 * (2 * up.q + 1) * c_out * c_in    # K taps -> 2 phases, once per call
        L *= 2
    f["output"] = 2 * n * L * m.out.in_features * m.out.out_features
    f["total"] = sum(v for k, v in f.items() if k != "upconv_nominal")
    f["total_nominal"] = f["total"] - f["upconv"] - f["weight_fold"] + f["upconv_nominal"]
    return f


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--characters", type=int, default=1000)
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    paper = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "model" / "vae_lstm.yaml"))["sizes"]["paper"]
    spec = DataSpec(joints=21, dims=3, num_classes=4, controls=3, fps=60.0, window=args.frames)
    torch.manual_seed(0)
    model = VAELSTM(spec, **paper).eval()                       # random weights: throughput only
    N, T = args.characters, args.frames
    controls = torch.randn(N, T, 3)

    with torch.inference_mode():
        dt, runs = timed(lambda: model.generate(None, controls, length=T), args.repeats, warmup=2)

        # where the time goes (same inputs; median of 3 each)
        g = model.encode_controls(controls)
        z1 = torch.randn(N, model.hidden)
        canvas = model.cell.rollout(z1, g)
        t_enc, _ = timed(lambda: model.encode_controls(controls), 3, 1)
        t_lstm, _ = timed(lambda: model.cell.rollout(z1, g), 3, 1)
        t_dec, _ = timed(lambda: model.decode(canvas), 3, 1)

        # the analytic count, checked against torch's counter on a small batch
        small = 8
        with FlopCounterMode(display=False) as fc:
            model.generate(None, controls[:small], length=T)
        counted = fc.get_total_flops()
    flops = generation_flops(model, N, T)
    check = generation_flops(model, small, T)["total"]
    peak = matmul_gflops(args.threads, 4096)

    common = {"characters": N, "frames": T, "threads": args.threads, "size": "paper", "sampling": "prior"}
    emit(BENCH, dt, "s", 2.0, **common, runs_s=[round(t, 3) for t in runs],
         ms_per_character=round(1e3 * dt / N, 3))
    emit(f"{BENCH}_stages", dt, "s", None, **common, control_encoder_s=round(t_enc, 3),
         lstm_rollout_s=round(t_lstm, 3), lstm_steps=T // model.factor, decoder_s=round(t_dec, 3))
    emit(f"{BENCH}_flops", flops["total"] / 1e9, "GFLOP", None, **common,
         nominal_gflop=round(flops["total_nominal"] / 1e9, 3),
         parts_gflop={k: round(v / 1e9, 3) for k, v in flops.items() if not k.startswith("total")},
         flop_counter_mode_check={"characters": small, "analytic": check, "counted": counted,
                                  "equal": check == counted})
    emit(f"{BENCH}_gflops", flops["total"] / dt / 1e9, "GFLOP/s", None, **common,
         matmul_4096_gflops=round(peak, 1), fraction_of_matmul=round(flops["total"] / dt / 1e9 / peak, 3),
         nominal_gflops=round(flops["total_nominal"] / dt / 1e9, 1))


if __name__ == "__main__":
    main()

"""Generation throughput of both model families, one JSON line per figure.

Usage: python bench/generate.py [--threads 2]
* VAE-LSTM at the paper's widths: 1,000 characters x 240 frames from the prior in one batch
  (target <= 2 s on 2 cores), with the batch's FLOPs and the GFLOP/s achieved beside a plain
  fp32 matmul (details: bench/generate_vae_lstm.py);
* GloGen + LocGen: one 10 s sequence at 30 fps (target >= 100x real time; bench/generate_glocal.py).
"""

from __future__ import annotations

import argparse

import generate_glocal
import generate_vae_lstm


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    generate_vae_lstm.main(["--threads", str(args.threads)])
    generate_glocal.main(["--threads", str(args.threads)])


if __name__ == "__main__":
    main()

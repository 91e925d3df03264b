"""GlocalNet generation speed: GloGen (61 sparse poses) + LocGen (M = 4 in-betweens) -> one
10 s sequence at 30 fps (k = 5: 301 dense frames), the default sizes, on the CPU.

Usage: python bench/generate_glocal.py [--threads 2] [--size default]
Weights are freshly initialised (speed does not depend on training). Prints JSON lines: the
real-time factor (10 s / wall, median of 7 after 2 warm-ups) and the two stages' times.
"""

from __future__ import annotations

import argparse

import torch
import yaml
from _util import ROOT, emit, median_time

from motionsynth.models.base import DataSpec
from motionsynth.models.glogen import GloGen
from motionsynth.models.locgen import LocGen, glocal_generate


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--size", default="default")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    fps, seconds, k = 30.0, 10.0, 5
    n_sparse = int(seconds * fps) // k + 1                      # 61 sparse poses -> 301 dense frames
    spec = DataSpec(joints=21, dims=3, num_classes=17, fps=fps, window=96, every=k)   # bandai1 glocal windows
    sizes = {n: yaml.safe_load((ROOT / "conf" / "model" / f"{n}.yaml").read_text())["sizes"][args.size]
             for n in ("glogen", "locgen")}
    glogen, locgen = GloGen(spec, **sizes["glogen"]).eval(), LocGen(spec, **sizes["locgen"]).eval()
    seed = torch.randn(1, glogen.t, spec.joints, spec.dims)
    labels = torch.tensor([3])
    M = k - 1

    def both():
        with torch.inference_mode():
            return glocal_generate(glogen, locgen, seed, labels, n_sparse, M)

    out = both()
    assert out.shape == (1, (n_sparse - 1) * (M + 1) + 1, spec.joints, spec.dims), out.shape
    with torch.inference_mode():
        sparse = glogen.generate(seed, labels=labels, length=n_sparse)
    t_all = median_time(both)
    t_glo = median_time(lambda: _inf(lambda: glogen.generate(seed, labels=labels, length=n_sparse)))
    t_loc = median_time(lambda: _inf(lambda: locgen.generate(sparse, M=M)))
    common = dict(threads=args.threads, size=args.size, frames=int(out.shape[1]), sparse=n_sparse)
    emit("generate_glocal_realtime_factor", seconds / t_all, "x real time", 100, wall_ms=round(t_all * 1e3, 2),
         **common)
    emit("generate_glocal_glogen_ms", t_glo * 1e3, "ms", None, **common)
    emit("generate_glocal_locgen_ms", t_loc * 1e3, "ms", None, **common)


def _inf(fn):
    with torch.inference_mode():
        return fn()


if __name__ == "__main__":
    main()

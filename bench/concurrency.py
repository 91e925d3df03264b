"""Slowdown of training stages that share the machine: one fixed stage alone, then two (and three)
copies at once, each copy as the pipeline runs it (its own process, ``train.threads`` as configured).

    python bench/concurrency.py [--dataset h36m --model glogen --steps 60] [--copies 2,3]

Prints one JSON line per figure: ``concurrency_alone`` (seconds of the fixed stage alone, median of
``--repeats``), ``concurrency_<n>_jobs`` (the mean wall time of each of ``n`` copies started together)
and its ratio to ``alone`` (target: <= 2.5 for two copies, <= 3.8 for three). Needs the prepared data of
``make run``; writes into a temp folder only (no MLflow, no checkpoints kept). Take it on an idle machine.

    GOMP_SPINCOUNT=300000 python bench/concurrency.py    # libgomp's own default: the behaviour before
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

from _util import ROOT, emit


def job(tmp: str, tag: str, args) -> subprocess.Popen:
    cmd = [sys.executable, str(ROOT / "pipelines" / "train.py"), f"dataset={args.dataset}", f"model={args.model}",
           f"train.steps={args.steps}", f"train.eval_every={args.steps}", "tracking.enabled=false",
           f"paths.models={tmp}/models/{tag}", f"paths.reports={tmp}/reports/{tag}", f"run_name={tag}",
           f"hydra.run.dir={tmp}/hydra/{tag}", "train.val_windows=64", *args.extra]
    return subprocess.Popen(cmd, cwd=ROOT, env={**os.environ, "PROGRESS": "0"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def together(tmp: str, n: int, args, k: int) -> list[float]:
    t0 = time.perf_counter()
    procs = [job(tmp, f"c{n}_{k}_{i}", args) for i in range(n)]
    ends: dict[int, float] = {}
    while len(ends) < n:                                   # each copy's own wall time
        for i, p in enumerate(procs):
            if i not in ends and p.poll() is not None:
                ends[i] = time.perf_counter() - t0
                if p.returncode:
                    raise SystemExit(f"a training copy failed:\n{p.stderr.read()[-2000:]}")
        time.sleep(0.05)
    return [ends[i] for i in range(n)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="h36m")
    ap.add_argument("--model", default="glogen")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--copies", default="2,3")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("extra", nargs="*", help="more Hydra overrides for every copy, e.g. train.threads=1")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        together(tmp, 1, args, -1)                                     # warm-up: page cache, imports
        alone = statistics.median(together(tmp, 1, args, k)[0] for k in range(args.repeats))
        emit("concurrency_alone", alone, "s", None, dataset=args.dataset, model=args.model, steps=args.steps,
             overrides=args.extra, gomp_spincount=os.environ.get("GOMP_SPINCOUNT", "(pipeline default 10000)"),
             omp_wait_policy=os.environ.get("OMP_WAIT_POLICY", "(unset)"))
        for n in (int(c) for c in args.copies.split(",") if c):
            walls = together(tmp, n, args, 0)
            mean = statistics.mean(walls)
            emit(f"concurrency_{n}_jobs", mean / alone, "x slower than alone", {2: 2.5, 3: 3.8}.get(n),
                 seconds_each=[round(w, 1) for w in walls], alone_s=round(alone, 1),
                 throughput_vs_alone=round(n * alone / max(walls), 2))


if __name__ == "__main__":
    main()

"""Training speed with the pipelines' malloc settings (:mod:`motionsynth.allocator`) against glibc's
defaults: the same training stage, the same steps, once each way, alternating, ``--repeats`` times.

    python bench/allocator.py [--runs bandai2_locomotion:lstm3lr:200,h36m:sagcn:40] [--repeats 3]

Each run is ``dataset:model:steps``: ``pipelines/train.py`` with ``train.steps=<steps>`` (one validation
round at the end), in its own process, ``MOTIONSYNTH_MALLOC=glibc`` for the defaults. Prints one JSON
line per run and setting: ``allocator_<dataset>_<model>_<setting>``, milliseconds per optimiser step
(the stage's own ``seconds`` over its steps, median of the repeats), with the child's minor page faults
per step; then ``allocator_<dataset>_<model>_speedup`` (glibc / tuned). The losses of both settings are
checked to be the same bits. Needs the prepared data of ``make run``; writes into a temp folder only.
Take it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from _util import ROOT, emit

from motionsynth.allocator import GLIBC_ENV, OPT_OUT_ENV

SETTINGS = {"tuned": {}, "glibc": {OPT_OUT_ENV: "glibc"}}


def stage(tmp: str, dataset: str, model: str, steps: int, setting: str, k: int) -> tuple[float, float, float]:
    """(ms per step, minor faults per step, final training loss) of one training stage."""
    tag = f"{dataset}_{model}_{setting}_{k}"
    cmd = [sys.executable, str(ROOT / "pipelines" / "train.py"), f"dataset={dataset}", f"model={model}",
           f"train.steps={steps}", f"train.eval_every={steps}", "tracking.enabled=false", f"run_name={tag}",
           f"paths.models={tmp}/models", f"paths.reports={tmp}/reports", f"hydra.run.dir={tmp}/hydra/{tag}"]
    env = {k: v for k, v in os.environ.items() if k not in GLIBC_ENV}
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_minflt
    out = subprocess.run(cmd, cwd=ROOT, env={**env, "PROGRESS": "0", **SETTINGS[setting]},
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if out.returncode:
        raise SystemExit(f"{tag} failed:\n{out.stderr[-2000:]}")
    faults = resource.getrusage(resource.RUSAGE_CHILDREN).ru_minflt - before
    summary = json.loads((Path(tmp) / "reports" / "metrics" / "train" / dataset / f"{tag}.json").read_text())
    return 1000 * summary["seconds"] / summary["steps"], faults / summary["steps"], summary["train/loss"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", default="bandai2_locomotion:lstm3lr:200,h36m:sagcn:40")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for run in args.runs.split(","):
            dataset, model, steps = run.split(":")
            stage(tmp, dataset, model, int(steps), "tuned", -1)                 # warm-up: page cache
            res: dict[str, list] = {s: [] for s in SETTINGS}
            for k in range(args.repeats):
                for s in SETTINGS:
                    res[s].append(stage(tmp, dataset, model, int(steps), s, k))
            losses = {r[2] for s in SETTINGS for r in res[s]}
            med = {}
            for s in SETTINGS:
                med[s] = statistics.median(r[0] for r in res[s])
                emit(f"allocator_{dataset}_{model}_{s}", med[s], "ms/step", None, steps=int(steps),
                     faults_per_step=round(statistics.median(r[1] for r in res[s])),
                     runs_ms=[round(r[0], 1) for r in res[s]])
            emit(f"allocator_{dataset}_{model}_speedup", med["glibc"] / med["tuned"], "x", None,
                 same_loss_bits=len(losses) == 1)


if __name__ == "__main__":
    main()

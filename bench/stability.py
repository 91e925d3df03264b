"""Do the committed table values hold on another kernel path? Reruns the pipeline's evaluation (and,
with ``--retrain``, its training first) with a forced other CPU code path, then compares every value of
every ``reports/eval/<ds>/results.csv`` with the committed one.

    python bench/stability.py                  # evaluate again on AVX2 kernels (MKL and oneDNN)
    python bench/stability.py --env ONEDNN_MAX_CPU_ISA=AVX2 --threads 1
    python bench/stability.py --retrain        # train every stage again too, two at a time (about an hour)
    python bench/stability.py --retrain --datasets cmu_aclstm   # one dataset's stages (about 15 min)
    python bench/stability.py --retrain --datasets h36m --runs h36m-sagcn h36m-sagcn-seed1 ...   # these stages only

The default other path is what an AVX2-only CPU takes: ``MKL_ENABLE_INSTRUCTIONS=AVX2`` (MKL runs the
GEMMs of every linear layer, LSTM and GRU), ``ONEDNN_MAX_CPU_ISA=AVX2`` (oneDNN runs only the
convolutions, i.e. SA-GCN's) and ``ATEN_CPU_CAPABILITY=avx2`` (PyTorch's own vectorised element-wise
and reduction kernels). oneDNN alone leaves every recurrent model's arithmetic bit-identical.

Bands (issue "Models that learn"): a deterministic value (``std`` empty: one value) must stay within
``--rel`` (5 %) of the committed one; a stochastic one (mean +- std over seeds) within ``--sigmas`` (2)
of its committed std. Prints one JSON line per dataset and a total: the share of values in their band,
and the worst offenders. Everything runs in a scratch copy (``--work``, default a temp dir): the
repository's models, reports and MLflow store are not touched. Reuses the repository's prepared data
(read only); with ``--retrain`` every ``train@`` stage of ``params.yaml`` is run again into the scratch
models folder, so the comparison covers training and evaluation together. The action classifier of
the generative suite is always retrained in the scratch copy (its cache is keyed by the thread count
and the data, and is not shared). ``--runs`` retrains only the named ``train@`` stages (keys of
``params.yaml: train_runs``); the datasets' other runs are linked from the repository's models, so the
comparison isolates those stages' training. ``--resume`` keeps the runs a killed ``--retrain`` left
finished in ``--work`` (a ``best.pt`` and their metrics file) instead of training them again.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

import pandas as pd
import yaml
from _util import ROOT, emit


#: the kernels an AVX2-only CPU takes (module docstring)
AVX2_ONLY = ["MKL_ENABLE_INSTRUCTIONS=AVX2", "ONEDNN_MAX_CPU_ISA=AVX2", "ATEN_CPU_CAPABILITY=avx2"]


def stage(script: str, overrides: list[str], env: dict, log: Path) -> float:
    t0 = time.perf_counter()
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as f:
        r = subprocess.run([sys.executable, str(ROOT / "pipelines" / script), *overrides], cwd=ROOT, env=env,
                           stdout=f, stderr=subprocess.STDOUT)
    if r.returncode:
        raise SystemExit(f"{script} {' '.join(overrides)} failed (exit {r.returncode}); see {log}")
    return time.perf_counter() - t0


def compare(ref: pd.DataFrame, new: pd.DataFrame, rel: float, sigmas: float) -> pd.DataFrame:
    key = ["table", "compare_to", "metric", "column", "method", "condition", "protocol"]
    m = ref.merge(new[key + ["value"]], on=key, how="left", suffixes=("", "_new"))
    m = m[pd.to_numeric(m["value"], errors="coerce").notna()].copy()
    v, w, sd = (pd.to_numeric(m[c], errors="coerce") for c in ("value", "value_new", "std"))
    stochastic = sd.notna() & (sd > 0)
    dev = (w - v).abs()
    m["stochastic"] = stochastic
    m["deviation"] = (dev / v.abs().where(v.abs() > 0, float("nan"))).where(~stochastic, dev / sd)
    m["ok"] = (~stochastic & (dev <= rel * v.abs())) | (stochastic & (dev <= sigmas * sd))
    m.loc[w.isna(), "ok"] = False
    return m


def main() -> None:
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    ap = argparse.ArgumentParser()
    ap.add_argument("--env", action="append", default=None, help="KEY=VALUE for the rerun (default "
                    f"{' '.join(AVX2_ONLY)})")
    ap.add_argument("--threads", type=int, default=None, help="torch threads of the rerun (train and eval)")
    ap.add_argument("--retrain", action="store_true", help="train every train@ stage again first")
    ap.add_argument("--jobs", type=int, default=2, help="training stages at a time with --retrain (one "
                    "thread each unless --threads; the longest committed stages start first)")
    ap.add_argument("--runs", nargs="+", default=None, help="with --retrain: only these train@ stages (keys of "
                    "params.yaml: train_runs); the datasets' other runs are linked from models/")
    ap.add_argument("--resume", action="store_true", help="with --retrain: keep runs already finished in --work")
    ap.add_argument("--datasets", nargs="+", choices=params["evaluate"], default=params["evaluate"],
                    help="only these datasets: their training stages and evaluation (default: all)")
    ap.add_argument("--rel", type=float, default=0.05)
    ap.add_argument("--sigmas", type=float, default=2.0)
    ap.add_argument("--work", default=None)
    args = ap.parse_args()
    t_start = time.perf_counter()
    datasets = list(args.datasets)
    extra = dict(e.split("=", 1) for e in (args.env or AVX2_ONLY))
    env = {**os.environ, "PROGRESS": "0", **extra}
    work = Path(args.work or tempfile.mkdtemp(prefix="stability-"))
    (work / "reports").mkdir(parents=True, exist_ok=True)
    log = work / "log.txt"
    common = ["tracking.enabled=false", f"paths.reports={work}/reports", f"paths.samples={work}/samples",
              f"hydra.run.dir={work}/hydra"]
    threads = [f"eval.threads={args.threads}"] if args.threads else []
    models = ROOT / "models"
    timings = {}
    if args.retrain:
        models = work / "models"
        threads_each = args.threads or (1 if args.jobs > 1 else None)
        t = [f"train.threads={threads_each}"] if threads_each else []

        def committed_seconds(r: dict) -> float:       # longest first packs the stages best
            f = ROOT / "reports" / "metrics" / "train" / r["dataset"] / f"{r['name']}.json"
            return float(json.loads(f.read_text()).get("seconds", 0)) if f.exists() else 0.0

        def train(item: tuple[str, dict]) -> tuple[str, float]:
            key, r = item
            seed = [f"seed={r['seed']}"] if "seed" in r else []
            return key, stage("train.py", [f"dataset={r['dataset']}", f"model={r['model']}",
                                           f"variant={r['variant']}", f"run_name={r['name']}",
                                           f"paths.models={models}", *seed, *t, *common], env,
                              work / "logs" / f"train_{key}.txt")

        runs = {k: r for k, r in params["train_runs"].items() if r["dataset"] in datasets}
        unknown = sorted(set(args.runs or []) - set(runs))
        if unknown:
            raise SystemExit(f"--runs {unknown}: not train@ stages of {datasets} in params.yaml (train_runs)")
        for key, r in runs.items():
            if args.runs is not None and key not in args.runs:        # not retrained: the committed model
                link = models / r["dataset"] / r["name"]
                link.parent.mkdir(parents=True, exist_ok=True)
                if not link.exists():
                    link.symlink_to(ROOT / "models" / r["dataset"] / r["name"], target_is_directory=True)
        runs = {k: r for k, r in runs.items() if args.runs is None or k in args.runs}

        def finished(r: dict) -> bool:
            return ((models / r["dataset"] / r["name"] / "best.pt").exists()
                    and (work / "reports" / "metrics" / "train" / r["dataset"] / f"{r['name']}.json").exists())

        todo = sorted(((k, r) for k, r in runs.items() if not (args.resume and finished(r))),
                      key=lambda kv: -committed_seconds(kv[1]))
        if len(todo) < len(runs):
            print(f"--resume: {len(runs) - len(todo)} of {len(runs)} runs already trained in {work}", file=sys.stderr)
        with ThreadPoolExecutor(max(1, args.jobs)) as pool:
            for fut in as_completed([pool.submit(train, item) for item in todo]):
                key, sec = fut.result()
                timings[key] = sec
                print(f"retrained {key} in {sec:.0f} s ({len(timings)} of {len(todo)})", file=sys.stderr, flush=True)
    elif not models.exists():
        raise SystemExit("no trained models here: run `make run` (or pass --retrain)")
    rows = []
    for ds in datasets:
        # the classifier cache (an evaluate output) goes to the scratch copy: the repository's stays untouched
        over = [f"dataset={ds}", f"paths.models={models}",
                f"++dataset.evaluate.generative.cache_dir={work}/classifiers/{ds}", *threads, *common]
        timings[f"evaluate@{ds}"] = stage("evaluate.py", over, env, log)
        ref = pd.read_csv(ROOT / "reports" / "eval" / ds / "results.csv", keep_default_na=False)
        new = pd.read_csv(work / "reports" / "eval" / ds / "results.csv", keep_default_na=False)
        m = compare(ref, new, args.rel, args.sigmas)
        m["dataset"] = ds
        rows.append(m)
        worst = m.sort_values("deviation", ascending=False).head(5)
        emit(f"stability_{ds}", float(m["ok"].mean()), "share in band", 0.97, values=int(len(m)),
             deterministic=int((~m["stochastic"]).sum()), stochastic=int(m["stochastic"].sum()),
             worst=[f"{r.method} | {r.metric} | {r.column} | {r.protocol}: {r.value} -> {r.value_new}"
                    for r in worst.itertuples()])
    allm = pd.concat(rows, ignore_index=True)
    allm.to_csv(work / "comparison.csv", index=False)
    emit("stability_total", float(allm["ok"].mean()), "share in band", 0.97, values=int(len(allm)),
         in_band=int(allm["ok"].sum()), env=extra, threads=args.threads, retrain=args.retrain,
         runs=args.runs, seconds=round(sum(timings.values()), 1), wall_seconds=round(time.perf_counter() - t_start, 1),
         comparison=str(work / "comparison.csv"))


if __name__ == "__main__":
    main()

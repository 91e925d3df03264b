"""`profile=paper` training on a lent GPU machine, cut to the device time it has.

The machine that runs this has PyTorch, NumPy, pandas and pyarrow but none of this project's other
packages, and what travels to it is limited in size. So it happens in three steps:

    # 1. here: resolved paper-profile configs, the prepared data they read, Hydra's pure-Python packages
    .venv/bin/python scripts/paper_gpu.py pack --out .gpu cmu_aclstm:glogen bandai2_locomotion:vae_lstm
    # 2. there (the repository's working tree plus .gpu), one run per model, side by side on one GPU:
    python3 scripts/paper_gpu.py train --pack .gpu --model glogen   --budget-s 330 --out $OUT &
    python3 scripts/paper_gpu.py train --pack .gpu --model vae_lstm --budget-s 1400 --out $OUT
    # 3. here: evaluate the returned runs (weights, config, curve, summary) on the test split
    .venv/bin/python scripts/paper_gpu.py evaluate --runs <dir with the returned tars> --out reports/extra/paper_gpu

`train` times a short probe first (its steps, one validation and the start-up) and cuts the model's paper
schedule to ``budget_s`` at that rate, a multiple of its validation interval. The probe's rate includes
the start-up, so the cut is conservative. A prepared pose array above ``--half-above-mb`` travels as
float16 (xz-compressed; bandai2_locomotion's 75 MB become 25 MB): at most 0.5 mm of rounding for poses
within 2 m. The results of the project's run are in ``reports/extra/paper_gpu/`` (README there).
"""

from __future__ import annotations

import argparse
import json
import lzma
import os
import shutil
import sys
import tarfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FILES = ("best.pt", "config.yaml", "curve.csv", "summary.json")   # what comes back of a run


def pack(args: argparse.Namespace) -> None:
    import numpy as np
    import yaml
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    out = Path(args.out)
    for pair in args.pairs:
        ds, model = pair.split(":")
        with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
            c = compose("config", overrides=[f"dataset={ds}", f"model={model}", "profile=paper", "train.device=cuda",
                                             "tracking.enabled=false"])
        (out / f"cfg_{model}.yaml").parent.mkdir(parents=True, exist_ok=True)
        (out / f"cfg_{model}.yaml").write_text(yaml.safe_dump(OmegaConf.to_container(c, resolve=True), sort_keys=False))
        rep = OmegaConf.select(c, "dataset.training.representation")
        src, dst = REPO / "data/processed" / ds / rep, out / "data/processed" / ds / rep
        shutil.copytree(REPO / "data/splits" / ds, out / "data/splits" / ds, dirs_exist_ok=True)
        dst.mkdir(parents=True, exist_ok=True)
        for f in src.iterdir():
            if f.name == "pose.npy" and f.stat().st_size > args.half_above_mb * 2**20:
                pose = np.load(f)
                (dst / "pose_f16.npy.xz").write_bytes(lzma.compress(pose.astype(np.float16).tobytes(), preset=6))
                (dst / "pose_f16.json").write_text(json.dumps({"shape": list(pose.shape)}))
            elif f.is_file():
                shutil.copy2(f, dst / f.name)
    site = Path(sys.modules["hydra"].__file__).parents[1]
    for pkg in ("hydra", "omegaconf", "antlr4"):   # pure Python: the run needs hydra.utils.get_class
        shutil.copytree(site / pkg, out / "site" / pkg, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
    print(f"packed {args.pairs} into {out}")


def unpack_poses(pack_dir: Path) -> None:
    import numpy as np

    for xz in pack_dir.glob("data/processed/*/*/pose_f16.npy.xz"):
        target = xz.with_name("pose.npy")
        if not target.exists():
            shape = json.loads(xz.with_name("pose_f16.json").read_text())["shape"]
            half = np.frombuffer(lzma.decompress(xz.read_bytes()), np.float16).reshape(shape)
            np.save(target, half.astype(np.float32))


def train(args: argparse.Namespace) -> None:
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")   # deterministic cuBLAS
    pack_dir = Path(args.pack).resolve()
    sys.path[:0] = [str(REPO / "src"), str(pack_dir / "site")]
    import torch
    import yaml

    from motionsynth.training.job import Job
    from motionsynth.training.run import run, train_config

    unpack_poses(pack_dir)
    work, out = Path(args.work), Path(args.out)

    def cfg_of(extra: dict) -> dict:
        cfg = yaml.safe_load((pack_dir / f"cfg_{args.model}.yaml").read_text())
        cfg["paths"].update(root=str(REPO), processed=str(pack_dir / "data/processed"),
                            splits=str(pack_dir / "data/splits"), models=str(work / "models"),
                            reports=str(work / "reports"))
        cfg["train"].update(extra)
        if not torch.cuda.is_available():   # a dry run on a CPU machine
            cfg["train"]["device"] = "cpu"
        return cfg

    probe_dir, run_dir = work / f"probe_{args.model}", work / f"run_{args.model}"
    shutil.rmtree(probe_dir, ignore_errors=True)
    shutil.rmtree(run_dir, ignore_errors=True)
    t0 = time.perf_counter()
    probe = run(cfg_of({"steps": args.probe, "eval_every": args.probe}), progress=False, job=Job(out_dir=probe_dir))
    per = (time.perf_counter() - t0) / args.probe
    paper = train_config(cfg_of({}))
    spp = probe["steps_per_pass"]
    full = int(paper.steps) if paper.steps is not None else int(paper.epochs) * spp
    every = int(paper.eval_every or (args.passes_per_eval * spp))
    steps = min(full, max(int(args.budget_s / per) // every, 1) * every)
    extra = {"steps": steps, "epochs": None, "eval_every": every, **json.loads(args.set)}
    print(f"{args.model}: probe {per * 1000:.1f} ms/step; running {extra['steps']} of the paper schedule's {full} "
          f"steps, validating every {extra['eval_every']}", flush=True)
    t1 = time.perf_counter()
    summary = run(cfg_of(extra), progress=False, job=Job(out_dir=run_dir))
    summary.update(paper_schedule_steps=full, probe_ms_per_step=per * 1000, wall_s=time.perf_counter() - t1,
                   device=torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
                   torch=torch.__version__, overrides=extra)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    state = torch.load(run_dir / "best.pt", map_location="cpu", weights_only=True)
    state.pop("optim", None)          # weights only: each returned file stays small
    torch.save(state, run_dir / "best.pt")
    out.mkdir(parents=True, exist_ok=True)
    with tarfile.open(out / f"{args.model}.tar", "w") as tf:
        for f in FILES:
            if (run_dir / f).exists():
                tf.add(run_dir / f, arcname=f"{args.model}/{f}")
    print(json.dumps({k: summary.get(k) for k in ("steps", "best_step", "converged", "seconds")}), flush=True)


def evaluate(args: argparse.Namespace) -> None:
    """The returned runs beside the pipeline's zero-velocity and mean-pose references, on the test split,
    with each dataset's own suites; rows of the GPU runs land in ``<out>/<dataset>_results.csv``."""
    import pandas as pd
    import yaml
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from motionsynth.evaluation import evaluate as run_suites

    out, work = Path(args.out), Path(args.work)
    for tar in sorted(Path(args.runs).glob("*.tar")):
        with tarfile.open(tar) as tf:
            tf.extractall(work / "returned", filter="data")
    for run_dir in sorted((work / "returned").iterdir()):
        cfg_run = yaml.safe_load((run_dir / "config.yaml").read_text())
        ds, model = cfg_run["dataset"]["name"], cfg_run["model"]["name"]
        models = work / "models" / ds
        models.mkdir(parents=True, exist_ok=True)
        shutil.copytree(run_dir, models / model, dirs_exist_ok=True)
        for ref in ("zero_velocity", "mean_pose"):
            if not (models / ref).exists():
                (models / ref).symlink_to((REPO / "models" / ds / ref).resolve())
        with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
            c = compose("config", overrides=[f"dataset={ds}", f"paths.root={REPO}", f"paths.models={work / 'models'}",
                                             f"paths.reports={work / 'reports'}", f"paths.samples={work / 'samples'}",
                                             "tracking.enabled=false"])
        ctx = run_suites(OmegaConf.to_container(c, resolve=True),
                         {model: model, "zero_velocity": "zero_velocity", "mean_pose": "mean_pose"})
        rows = pd.read_csv(work / "reports/eval" / ds / "results.csv")
        rows = rows[rows["run"].astype(str).str.startswith(model)]
        out.mkdir(parents=True, exist_ok=True)
        rows.to_csv(out / f"{ds}_results.csv", index=False)
        for f in ("curve.csv", "summary.json"):
            shutil.copyfile(run_dir / f, out / f"{ds}_{model}_{f}")
        print(f"{ds} {model}: {len(rows)} rows ({ctx.timings})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("pack")
    p.add_argument("pairs", nargs="+", help="<dataset>:<model>")
    p.add_argument("--out", default=".gpu")
    p.add_argument("--half-above-mb", type=float, default=40.0)
    t = sub.add_parser("train")
    t.add_argument("--pack", default=".gpu")
    t.add_argument("--model", required=True)
    t.add_argument("--budget-s", type=float, required=True)
    t.add_argument("--probe", type=int, default=50)
    t.add_argument("--passes-per-eval", type=int, default=10, help="validation interval where the schedule gives none")
    t.add_argument("--set", default="{}", help='train.* overrides as JSON, e.g. \'{"eval_every": 50}\'')
    t.add_argument("--work", default="/tmp/paper_gpu")
    t.add_argument("--out", default=os.environ.get("OUT", "paper_gpu_out"))
    e = sub.add_parser("evaluate")
    e.add_argument("--runs", required=True)
    e.add_argument("--work", default="/tmp/paper_gpu_eval")
    e.add_argument("--out", default="reports/extra/paper_gpu")
    args = ap.parse_args()
    {"pack": pack, "train": train, "evaluate": evaluate}[args.cmd](args)


if __name__ == "__main__":
    main()

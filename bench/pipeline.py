"""Wall time and peak memory of the data pipeline: `dvc repro -f` of ingest -> prepare -> split
for all five archives (plus data_report), on the current profile. Run from the repo root.

Usage: python bench/pipeline.py [--profile default]
Peak RSS is the largest resident set of any stage process (they run one after another).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time

from _util import ROOT, emit


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--with-report", action="store_true", help="also time the data_report stage")
    args = ap.parse_args()
    env = {**os.environ, "PROGRESS": "0", "DVC_NO_ANALYTICS": "1"}
    import resource

    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "dvc", "repro", "-f", "--single-item", *[
        f"{s}@{d}" for s in ("ingest", "prepare", "split") for d in _datasets()]]
        + (["data_report"] if args.with_report else []), cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        print(out.stdout[-3000:], out.stderr[-3000:], file=sys.stderr)
        raise SystemExit(out.returncode)
    peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    stages = len(re.findall(r"Running stage", out.stdout + out.stderr))
    emit("data_pipeline_wall", wall, "s", 90, stages=stages, includes="dvc overhead + MLflow logging")
    emit("data_pipeline_peak_rss", peak_kb / 1024 ** 2, "GiB", 4, note="largest single process")


def _datasets() -> list[str]:
    import yaml

    return list(yaml.safe_load((ROOT / "params.yaml").read_text())["datasets"])


if __name__ == "__main__":
    main()

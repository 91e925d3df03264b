"""Benchmark helpers: warm up, repeat, take the median, print one JSON line per figure."""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests"))


def timed(fn, repeats: int = 7, warmup: int = 2) -> tuple[float, list[float]]:
    """Run ``fn`` ``warmup`` times, then ``repeats`` timed times: (median seconds, all runs)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def median_time(fn, repeats: int = 7, warmup: int = 2) -> float:
    return timed(fn, repeats, warmup)[0]


def emit(bench: str, value: float, unit: str, target: float | None = None, **extra) -> None:
    rec = {"bench": bench, "value": round(value, 3), "unit": unit}
    if target is not None:
        rec["target"] = target
    rec.update(extra)
    print(json.dumps(rec), flush=True)

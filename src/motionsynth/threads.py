"""How many CPU threads a stage uses, and how idle threads wait.

Two processes on a 2-core machine that each run 2 compute threads do not just share the cores:
torch's OpenMP runtime (GNU libgomp) lets an idle worker thread *spin* for 300,000 iterations
before it sleeps, so each process burns the cycles the other needs. Measured with
``bench/concurrency.py`` (a whole GloGen training stage on h36m, 60 steps, 2 threads each, on the
2-core machine): alone 20.3 s; two copies at once 10.9x slower each, three 9.6x. Choices, by that
benchmark:

* **Short spinning** (:data:`OMP_SPIN_DEFAULT`): the pipelines' entry points set
  ``GOMP_SPINCOUNT=10000`` (unless the environment sets it) before torch starts its OpenMP runtime
  (``pipelines/_common.py``). Measured: alone 19.8 s (no loss), two copies 1.66x slower each, three
  2.67x. ``OMP_WAIT_POLICY=PASSIVE`` (no spinning at all) shared best (1.20x / 1.86x) but made a
  stage alone 18 % slower; 3,000 spins: 1.40x with 5 % solo loss; 30,000: 2.91x.
* **A thread count from the cores this process may use**: ``threads: auto`` (``train.threads``,
  ``eval.threads``) is the number of CPUs in the process's affinity mask (``taskset``, cgroup
  cpusets, SLURM's ``--cpus-per-task``) divided by the number of jobs a parallel launcher runs at
  once (``MOTIONSYNTH_PARALLEL_JOBS``, which the sweep callback sets from
  ``hydra.launcher.n_jobs``), at least 1. An integer is taken as it is.
"""

from __future__ import annotations

import os

#: the environment variable that tells a job how many jobs a launcher runs beside it
PARALLEL_JOBS_ENV = "MOTIONSYNTH_PARALLEL_JOBS"
#: libgomp's spin count before an idle thread sleeps, and the pipelines' default (module docstring)
OMP_SPIN_ENV, OMP_SPIN_DEFAULT = "GOMP_SPINCOUNT", "10000"


def available_cores() -> int:
    """CPUs this process may run on (its affinity mask; ``os.cpu_count()`` where there is none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def parallel_jobs() -> int:
    try:
        return max(1, int(os.environ.get(PARALLEL_JOBS_ENV, "1")))
    except ValueError:
        return 1


def resolve(value: int | str) -> int:
    """``"auto"`` -> ``available_cores() // parallel_jobs()`` (at least 1); a positive integer -> itself."""
    if value == "auto":
        return max(1, available_cores() // parallel_jobs())
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"threads must be 'auto' or an integer >= 1, got {value!r}")
    return value


def check(value, name: str) -> str | None:
    """A problem sentence for config validation, or None."""
    try:
        resolve(value)
    except ValueError:
        return f"{name} must be 'auto' or an integer >= 1, got {value!r}"
    return None

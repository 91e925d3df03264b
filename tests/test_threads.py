"""Thread counts from the cores a process may use, passive OpenMP waiting and malloc settings in the pipelines."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from conftest import REPO

from motionsynth import allocator, threads
from motionsynth.training.trainer import TrainConfig


def test_auto_is_the_affinity_mask_divided_by_the_parallel_jobs(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    monkeypatch.delenv(threads.PARALLEL_JOBS_ENV, raising=False)
    assert threads.available_cores() == 4 and threads.resolve("auto") == 4
    monkeypatch.setenv(threads.PARALLEL_JOBS_ENV, "2")
    assert threads.resolve("auto") == 2
    monkeypatch.setenv(threads.PARALLEL_JOBS_ENV, "8")
    assert threads.resolve("auto") == 1                 # never below one thread
    assert threads.resolve(3) == 3                      # an explicit count is kept


@pytest.mark.parametrize("bad", [0, -1, "two", 1.5, True])
def test_bad_thread_counts_are_config_errors(bad):
    with pytest.raises(ValueError, match="train.threads must be 'auto' or an integer >= 1"):
        TrainConfig(threads=bad).validate()


def test_pipelines_spin_briefly_unless_told_otherwise():
    code = ("import sys; sys.path.insert(0, 'pipelines'); import _common, os; "
            "print(os.environ['GOMP_SPINCOUNT'], 'torch' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k != "GOMP_SPINCOUNT"}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == [threads.OMP_SPIN_DEFAULT, "False"]   # set before torch is loaded
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env={**env, "GOMP_SPINCOUNT": "0"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.split()[0] == "0"


# A step-like loop: two 8 MB buffers taken and freed per step, as oneDNN's workspace and a gradient are.
_STEPS = ("import resource, sys; sys.path.insert(0, 'pipelines'); import _common\n"
          "import numpy as np\n"
          "def step():\n"
          "    a = np.ones(1 << 20); b = np.ones(1 << 20); del a, b\n"
          "step()\n"
          "f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
          "for _ in range(40): step()\n"
          "print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)")


def _faults(**env) -> int:
    """Minor page faults of 40 such steps in a process that imports the entry points' ``_common``."""
    base = {k: v for k, v in os.environ.items() if k not in (*allocator.GLIBC_ENV, allocator.OPT_OUT_ENV)}
    out = subprocess.run([sys.executable, "-c", _STEPS], cwd=REPO, env={**base, **env},
                         capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_the_pipelines_keep_a_steps_buffers_instead_of_faulting_them_back_in():
    tuned = _faults()                                                   # the entry points' settings
    glibc = _faults(**{allocator.OPT_OUT_ENV: "glibc"})                 # glibc's defaults, kept on request
    assert glibc > 40 * 500                  # with the defaults, megabytes of pages are faulted in again each step
    assert tuned < glibc / 20                # with the pipelines' settings they are reused
    # the user's glibc choice wins: pages are faulted in again each step, as with glibc's defaults. Not a
    # ratio to `glibc`: both counts move with the kernel's state (a full suite on a Zen 4 machine once gave
    # 59,871 for glibc's defaults and 20,840 here, against 39,945 and 41,280 in a quiet process)
    user = _faults(MALLOC_TRIM_THRESHOLD_="0")
    assert user > 40 * 250 and user > 20 * tuned

"""Thread counts from the cores a process may use, and passive OpenMP waiting in the pipelines."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from conftest import REPO

from motionsynth import threads
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

"""`python -m motionsynth.repro`, the parallel `dvc repro` of `make run`, on a small DVC project of its own:
independent stages overlap, dvc.lock ends as `dvc repro` would write it (a plain `dvc repro` then runs
nothing), a failed stage skips only its downstream stages, and an unchanged stage is not rerun."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

# a stage that records when it ran, sleeps, and writes its output
STAMP = ("python -c \"import json,sys,time; t=time.time(); time.sleep(float(sys.argv[2])); "
         "open(sys.argv[1],'w').write(json.dumps([t, time.time()]))\"")


def sh(args, cwd, env, check=True):
    r = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True)
    if check:
        assert r.returncode == 0, f"{args} failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


@pytest.fixture
def project(tmp_path):
    env = {**os.environ, "DVC_NO_ANALYTICS": "1", "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
           "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t",
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    (tmp_path / "dvc.yaml").write_text(textwrap.dedent(f"""\
        stages:
          slow_a:
            cmd: {STAMP} a.json 2
            outs: [a.json]
          after_a:
            cmd: python -c "import shutil; shutil.copy('a.json', 'b.json')"
            deps: [a.json]
            outs: [b.json]
          slow_c:
            cmd: {STAMP} c.json 2
            outs: [c.json]
          broken:
            cmd: python -c "raise SystemExit(3)"
            outs: [broken.json]
          after_broken:
            cmd: python -c "open('d.json', 'w').write('1')"
            deps: [broken.json]
            outs: [d.json]
        """))
    sh(["git", "init", "-q"], tmp_path, env)
    sh([sys.executable, "-m", "dvc", "init", "-q"], tmp_path, env)
    sh(["git", "add", "-A"], tmp_path, env)
    sh(["git", "commit", "-qm", "p"], tmp_path, env)
    return tmp_path, env


@pytest.fixture
def lock_writes(monkeypatch) -> list[list[str]]:
    """The stage names of every dvc.lock rewrite DVC makes in this process, in order."""
    from dvc.dvcfile import Lockfile

    lock_writes: list[list[str]] = []
    dump = Lockfile.dump_stages

    def counted(self, stages, **kwargs):
        lock_writes.append(sorted(s.name for s in stages))
        return dump(self, stages, **kwargs)

    monkeypatch.setattr(Lockfile, "dump_stages", counted)
    return lock_writes


def test_parallel_repro_overlaps_commits_like_dvc_and_skips_only_downstream_of_a_failure(project):
    root, env = project
    r = sh([sys.executable, "-m", "motionsynth.repro", "-j", "2"], root, env, check=False)
    out = r.stdout + r.stderr
    assert r.returncode == 1, out                      # one stage failed
    assert "stage 'broken' failed (exit status 3)" in out
    assert "skipping 'after_broken': an upstream stage failed" in out
    assert "5 stages: 3 ran, 0 unchanged, 1 failed, 1 skipped" in out
    a, c = (json.loads((root / f).read_text()) for f in ("a.json", "c.json"))
    assert a[0] < c[1] and c[0] < a[1], "the two independent 2-second stages did not overlap"
    assert (root / "b.json").read_text() == (root / "a.json").read_text()
    # dvc.lock holds what `dvc repro` writes: DVC itself finds the three stages up to date ...
    st = json.loads(sh([sys.executable, "-m", "dvc", "status", "--json"], root, env).stdout)
    assert set(st) == {"broken", "after_broken"}, st
    plain = sh([sys.executable, "-m", "dvc", "repro", "slow_a", "after_a", "slow_c"], root, env).stdout
    assert "Running stage" not in plain
    # ... and the outputs are in the cache (a deleted one comes back with `dvc checkout`)
    (root / "b.json").unlink()
    sh([sys.executable, "-m", "dvc", "checkout", "after_a"], root, env)
    assert (root / "b.json").exists()
    times = json.loads((root / "reports" / "stage_times.json").read_text())
    assert set(times) == {"slow_a", "after_a", "slow_c"} and times["slow_a"] >= 2
    # a second run reruns nothing that is up to date
    r2 = sh([sys.executable, "-m", "motionsynth.repro", "slow_a", "after_a", "slow_c"], root, env)
    assert "Running stage" not in r2.stdout and r2.stdout.count("didn't change, skipping") == 3


def test_bad_jobs_value_is_a_clear_error(project):
    root, env = project
    r = sh([sys.executable, "-m", "motionsynth.repro", "-j", "0"], root, env, check=False)
    assert r.returncode == 2 and "--jobs must be 'auto' or an integer >= 1, got '0'" in r.stderr


def test_a_freed_slot_is_refilled_before_the_finished_stage_is_committed(project):
    """DVC's save, commit and lock of a finished stage take seconds; a stage that does not wait on it
    starts first (with one slot, the second stage's start is logged before the first one's end)."""
    root, env = project
    out = sh([sys.executable, "-m", "motionsynth.repro", "-j", "1", "slow_a", "slow_c"], root, env).stdout
    lines = out.splitlines()
    starts = [i for i, s in enumerate(lines) if "Running stage" in s]
    ends = [i for i, s in enumerate(lines) if "finished in" in s]
    assert len(starts) == 2 and len(ends) == 2, out
    assert starts[1] < ends[0], out
    st = json.loads(sh([sys.executable, "-m", "dvc", "status", "--json", "slow_a", "slow_c"], root, env).stdout)
    assert st == {}, st


def test_a_missing_data_source_fails_in_one_line_and_skips_only_its_downstream(project):
    """A ``.dvc`` file whose data is not in the workspace (no ``dvc pull`` yet): the run names the
    file and the fix, the stages that read it are skipped, and the others run."""
    root, env = project
    (root / "raw.txt").write_text("x")
    sh([sys.executable, "-m", "dvc", "add", "-q", "raw.txt"], root, env)
    with open(root / "dvc.yaml", "a") as f:
        f.write("  reads_raw:\n    cmd: python -c \"open('e.json', 'w').write('1')\"\n"
                "    deps: [raw.txt]\n    outs: [e.json]\n")
    (root / "raw.txt").unlink()
    r = sh([sys.executable, "-m", "motionsynth.repro", "-j", "2", "raw.txt.dvc", "reads_raw", "slow_c"],
           root, env, check=False)
    out = r.stdout + r.stderr
    assert r.returncode == 1 and "Traceback" not in out, out
    assert "ERROR: data source 'raw.txt.dvc': missing data 'source': raw.txt (`dvc pull` fetches it" in out, out
    assert "skipping 'reads_raw': an upstream stage failed" in out
    assert (root / "c.json").exists() and not (root / "e.json").exists()
    # with the file back (dvc checkout from the cache), the source verifies and its stage runs
    sh([sys.executable, "-m", "dvc", "checkout", "raw.txt.dvc"], root, env)
    r = sh([sys.executable, "-m", "motionsynth.repro", "-j", "2", "reads_raw"], root, env)
    assert (root / "e.json").read_text() == "1", r.stdout


def test_lock_entries_are_written_in_batches_and_before_a_stage_that_may_read_them(project, lock_writes,
                                                                                   monkeypatch):
    """dvc.lock is rewritten once for the finished stages together, not once per stage; a stage whose
    upstream entries wait in the batch gets them written first (its command reads dvc.lock here)."""
    from motionsynth import repro

    root, env = project
    with open(root / "dvc.yaml", "a") as f:
        f.write("  reads_lock:\n    cmd: python -c \"import yaml; s = yaml.safe_load(open('dvc.lock'))['stages']; "
                "open('f.json', 'w').write(str(sorted(s)))\"\n    deps: [a.json]\n    outs: [f.json]\n")
    monkeypatch.chdir(root)
    monkeypatch.setenv("PATH", env["PATH"])
    assert repro.main(["-j", "1", "slow_a", "slow_c", "reads_lock"]) == 0
    assert sorted(sum(lock_writes, [])) == ["reads_lock", "slow_a", "slow_c"], lock_writes
    assert len(lock_writes) < 3, lock_writes         # batched: not one rewrite per stage
    assert "slow_a" in (root / "f.json").read_text()     # written before reads_lock started
    st = json.loads(sh([sys.executable, "-m", "dvc", "status", "--json"], root, env).stdout)
    assert set(st) == {"after_a", "broken", "after_broken"}, st


def test_a_run_killed_before_its_lock_write_is_restored_from_the_run_cache(project, monkeypatch):
    """The entries a killed run had not written yet: the next run finds those stages changed, and DVC's
    run cache gives back their outputs without running their commands again (as for make run's stages,
    which all have dependencies: DVC keeps no run cache for a stage without any)."""
    from motionsynth import repro

    root, env = project
    (root / "in.txt").write_text("x")
    with open(root / "dvc.yaml", "a") as f:
        f.write("  stamp_in:\n    cmd: python -c \"import time; open('g.json', 'w').write(open('in.txt').read() + "
                "str(time.time()))\"\n    deps: [in.txt]\n    outs: [g.json]\n")
    monkeypatch.chdir(root)
    monkeypatch.setenv("PATH", env["PATH"])
    monkeypatch.setattr(repro.Runner, "write_lock", lambda self: None)  # killed before any lock write
    assert repro.main(["-j", "2", "stamp_in"]) == 0
    first = (root / "g.json").read_text()
    st = json.loads(sh([sys.executable, "-m", "dvc", "status", "--json", "stamp_in"], root, env).stdout)
    assert set(st) == {"stamp_in"}, st               # no entry: DVC sees the stage as changed
    monkeypatch.undo()
    r = sh([sys.executable, "-m", "motionsynth.repro", "-j", "2", "stamp_in"], root, env)
    assert "Stage 'stamp_in' is cached: its outputs were checked out" in r.stdout, r.stdout
    assert (root / "g.json").read_text() == first    # the first run's output, not a new run's
    st = json.loads(sh([sys.executable, "-m", "dvc", "status", "--json", "stamp_in"], root, env).stdout)
    assert st == {}, st


def test_a_pending_lock_entry_is_written_while_other_stages_still_run(project, lock_writes, monkeypatch):
    """An entry waits at most LOCK_EVERY_S, even while no other stage finishes: the quick stage's entry is
    written on its own, before the 2-second stage beside it ends."""
    from motionsynth import repro

    root, env = project
    with open(root / "dvc.yaml", "a") as f:
        f.write("  quick:\n    cmd: python -c \"open('q.json', 'w').write('1')\"\n    outs: [q.json]\n")
    monkeypatch.setattr(repro, "LOCK_EVERY_S", 0.3)
    monkeypatch.chdir(root)
    monkeypatch.setenv("PATH", env["PATH"])
    assert repro.main(["-j", "2", "quick", "slow_c"]) == 0
    assert lock_writes == [["quick"], ["slow_c"]], lock_writes

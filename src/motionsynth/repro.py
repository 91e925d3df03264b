"""``dvc repro`` with independent stages run side by side: what ``make run`` calls.

    python -m motionsynth.repro [-j N] [--force] [--dry] [targets ...]

DVC runs one stage at a time, and its stages here are mostly single-threaded Python or small recurrent
models that a second core barely speeds up. Measured on the 2-core machine (``bench/concurrency.py``,
GloGen on ``h36m``, 60 steps): one stage on 2 threads 25.2 s, on 1 thread 28.5 s, and two 1-thread
stages at once 27.7 s each, i.e. 1.8x the throughput of one 2-thread stage at a time.

This runner takes DVC's own plan (the stages of the targets and everything upstream, as ``dvc repro``
plans them) and keeps up to ``-j`` stage commands running. Each stage goes through DVC's steps, in
this process: skipped when ``Stage.changed`` says so (after its upstream stages ran), outputs removed
(persistent ones kept), the run cache tried, the command run, then ``save``, ``commit`` and the
``dvc.lock`` entry that ``dvc repro`` writes. A plain ``dvc repro`` afterwards finds every stage up to
date. The ``dvc.lock`` entries are written in batches (:meth:`Runner.write_lock`): rewriting the whole
file costs about 2 s of CPU per stage at 91 stages, time taken from the stages that share the cores.
A batch is written before a stage starts whose upstream stages wait in it (a stage command may read
``dvc.lock``), once the oldest pending entry has waited :data:`LOCK_EVERY_S` seconds, and when the run
ends, fails or is interrupted. A run killed outright loses at most that many seconds of entries; the
next run restores those stages from DVC's run cache (or runs them again where a stage has uncached
outputs or no dependencies).
A failed stage is reported and its downstream stages are skipped; the others go on (``dvc repro
--keep-going``); the exit status is 1 then.

Results do not depend on ``-j``: the default profile pins one thread per stage (``train.threads``,
``eval.threads``), so ``dvc repro`` (one at a time) and this runner give the same bits. Children get
``MOTIONSYNTH_PARALLEL_JOBS`` (for ``threads: auto``) and ``PROGRESS=0``; their output is prefixed with
the stage name. Stages start longest critical path first, by the wall times of the last run in this
clone (:data:`TIMES_FILE`, committed with the results; the README's per-stage times come from it).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from motionsynth import threads

#: per-stage wall seconds of the last run (relative to the repository root); read to order the stages
TIMES_FILE = Path("reports/stage_times.json")  # outside every stage's deps (reports/metrics is one)
POLL_S = 0.2  # how often the scheduler looks for a finished stage
LOCK_EVERY_S = 300.0  # the longest a committed stage's dvc.lock entry waits to be written


def log(msg: str) -> None:
    print(f"[repro {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def pump(stream, name: str) -> None:
    for line in stream:
        sys.stdout.write(f"[{name}] {line}")
        sys.stdout.flush()


def critical_paths(graph, steps, durations: dict[str, float]) -> dict:
    """Each stage's own expected seconds plus the longest chain of stages downstream of it."""
    cp: dict = {}
    for st in reversed(steps):  # ``steps`` is DVC's post-order: upstream first, so reversed is downstream first
        below = [cp[d] for d in graph.predecessors(st) if d in cp]
        cp[st] = durations.get(st.addressing, 0.0) + max(below, default=0.0)
    return cp


class Runner:
    def __init__(self, repo, steps, graph, jobs: int, force: bool, dry: bool):
        self.repo, self.steps, self.graph, self.jobs, self.force, self.dry = repo, steps, graph, jobs, force, dry
        self.in_plan = set(steps)
        self.done: set = set()
        self.failed: set = set()
        self.skipped: set = set()
        self.running: dict = {}  # stage -> (process, start time, pump thread)
        self.ending: set = set()  # commands done, DVC bookkeeping not yet
        self.ran: dict[str, float] = {}
        self.unlocked: list = []  # committed stages whose dvc.lock entries are not written yet
        self.unlocked_since = 0.0  # when the oldest of them was committed
        root = Path(repo.root_dir)
        self.times_path = root / TIMES_FILE
        self.times = json.loads(self.times_path.read_text()) if self.times_path.exists() else {}
        self.priority = critical_paths(graph, steps, self.times)
        self.env = {**os.environ, threads.PARALLEL_JOBS_ENV: str(jobs), "PROGRESS": os.environ.get("PROGRESS", "0")}

    def upstream(self, st) -> list:
        return [u for u in self.graph.successors(st) if u in self.in_plan]

    def ancestors(self, st) -> set:
        """Every stage upstream of ``st``, direct or not (in the plan or not)."""
        seen, todo = set(), list(self.graph.successors(st))
        while todo:
            u = todo.pop()
            if u not in seen:
                seen.add(u)
                todo.extend(self.graph.successors(u))
        return seen

    def ready(self) -> list:
        out = []
        for st in self.steps:
            if st in self.done or st in self.failed or st in self.skipped or st in self.running or st in self.ending:
                continue
            ups = self.upstream(st)
            if any(u in self.failed or u in self.skipped for u in ups):
                self.skipped.add(st)
                log(f"skipping '{st.addressing}': an upstream stage failed")
            elif all(u in self.done for u in ups):
                out.append(st)
        return sorted(out, key=lambda s: -self.priority[s])

    def start(self, st) -> None:
        from dvc.stage.cache import RunCacheNotFoundError

        if not self.force and not st.changed(upstream=self.upstream(st)):
            log(f"Stage '{st.addressing}' didn't change, skipping")
            self.done.add(st)
            return
        cmd = " && ".join(st.cmd) if isinstance(st.cmd, list) else st.cmd
        log(f"Running stage '{st.addressing}' ({len(self.running) + 1} running): {cmd or 'verify the data source'}")
        if self.dry:
            self.done.add(st)
            return
        if not cmd:  # a data source (a .dvc file): nothing to run; DVC checks its file and re-hashes it
            self.verify_source(st)
            return
        if self.unlocked and self.ancestors(st) & set(self.unlocked):
            self.write_lock()  # its command may read its upstream stages' entries (training's dataset hash)
        st.remove_outs(ignore_remove=False, force=False)  # persistent outs stay (a killed run resumes)
        if not self.force:
            try:
                self.repo.stage_cache.restore(st)
                log(f"Stage '{st.addressing}' is cached: its outputs were checked out")
                self.finish(st, time.perf_counter())
                return
            except RunCacheNotFoundError:
                st.save_deps()
        proc = subprocess.Popen(cmd, shell=True, cwd=self.repo.root_dir, env=self.env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
        pt = threading.Thread(target=pump, args=(proc.stdout, st.addressing), daemon=True)
        pt.start()
        self.running[st] = (proc, time.perf_counter(), pt)

    def verify_source(self, st) -> None:
        """What ``dvc repro`` does with a changed data source: its file must be there (else the stage
        fails with one line, and its downstream stages are skipped); a changed file is hashed anew."""
        try:
            st.run()
            st.dump()
        except Exception as e:  # dvc's MissingDataSource and the like: one line, the run goes on
            self.fail(st, f"data source '{st.addressing}': {e} (`dvc pull` fetches it; `make run` does)")
            return
        self.done.add(st)

    def fail(self, st, why: str) -> None:
        """A stage that failed: one line; the stages downstream of it are skipped, the others go on."""
        self.failed.add(st)
        log(f"ERROR: {why}; its downstream stages will be skipped")

    def finish(self, st, t0: float) -> None:
        """What ``dvc repro`` does after a stage's command: save the outputs, commit them, write dvc.lock."""
        no_cache_outs = any(not o.use_cache for o in st.outs if not (o.is_metric or o.is_plot))
        st.save(run_cache=not no_cache_outs)
        st.commit()
        if not self.unlocked:
            self.unlocked_since = time.perf_counter()
        self.unlocked.append(st)
        self.ran[st.addressing] = time.perf_counter() - t0
        self.done.add(st)

    def write_lock(self) -> None:
        """Write the pending ``dvc.lock`` entries: one rewrite of each lock file for all of them."""
        by_file: dict = {}
        for st in self.unlocked:
            by_file.setdefault(st.dvcfile.path, (st.dvcfile, []))[1].append(st)
        for dvcfile, stages in by_file.values():
            dvcfile.dump_stages(stages, update_pipeline=False)
        self.unlocked.clear()

    def reap(self) -> None:
        """Collect the finished commands; refill the freed slots with stages that do not wait on them
        *before* the DVC bookkeeping of the finished ones (save, commit, lock: a few seconds each), so a
        slot does not idle through it; then the bookkeeping, which may make downstream stages ready."""
        ended = []
        for st, (proc, t0, pt) in list(self.running.items()):
            if proc.poll() is None:
                continue
            pt.join()
            del self.running[st]
            if proc.returncode == 0:
                ended.append((st, t0))
                self.ending.add(st)
            else:
                self.fail(st, f"stage '{st.addressing}' failed (exit status {proc.returncode})")
        if not ended:
            return
        self.fill()
        for st, t0 in ended:
            self.ending.discard(st)
            self.finish(st, t0)
            log(f"Stage '{st.addressing}' finished in {self.ran[st.addressing]:.0f} s")

    def fill(self) -> None:
        """Start ready stages until ``jobs`` run (a skipped or cached stage can make others ready)."""
        progressed = True
        while progressed and len(self.running) < self.jobs:
            progressed = False
            for st in self.ready():
                self.start(st)
                progressed = True
                break

    def stop(self) -> None:
        for proc, _, _ in self.running.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
        for proc, _, _ in self.running.values():
            proc.wait()

    def run(self) -> int:
        t_start = time.perf_counter()
        try:
            while True:
                self.fill()
                if not self.running:
                    break
                time.sleep(POLL_S)
                self.reap()
                if self.unlocked and time.perf_counter() - self.unlocked_since >= LOCK_EVERY_S:
                    self.write_lock()  # no entry waits longer, even while no stage finishes
        except BaseException:
            log("interrupted: stopping the running stages (finished stages are committed)")
            self.stop()
            raise
        finally:
            self.write_lock()
            if self.ran and not self.dry:
                self.times.update({k: round(v, 1) for k, v in self.ran.items()})
                self.times_path.parent.mkdir(parents=True, exist_ok=True)
                self.times_path.write_text(json.dumps(dict(sorted(self.times.items())), indent=1) + "\n")
        wall = time.perf_counter() - t_start
        unchanged = len(self.done) - len(self.ran)
        log(f"{len(self.steps)} stages: {len(self.ran)} ran, {unchanged} unchanged, {len(self.failed)} failed, "
            f"{len(self.skipped)} skipped; wall {wall / 60:.1f} min with {self.jobs} at a time")
        if self.failed:
            log("failed: " + ", ".join(sorted(s.addressing for s in self.failed)))
        return 1 if self.failed or self.skipped else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m motionsynth.repro", description=__doc__.split("\n\n")[0])
    ap.add_argument("targets", nargs="*", help="stages or dvc.yaml files (default: the whole dvc.yaml)")
    ap.add_argument("-j", "--jobs", default="auto",
                    help="stages at once (default auto: the CPUs this process may use)")
    ap.add_argument("-f", "--force", action="store_true", help="run every planned stage even if unchanged")
    ap.add_argument("--dry", action="store_true", help="print what would run")
    args = ap.parse_args(argv)
    try:
        jobs = threads.available_cores() if args.jobs == "auto" else int(args.jobs)
    except ValueError:
        jobs = 0
    if jobs < 1:
        ap.error(f"--jobs must be 'auto' or an integer >= 1, got {args.jobs!r}")

    from dvc.repo import Repo, lock_repo
    from dvc.repo.reproduce import collect_stages, get_active_graph, plan_repro

    repo = Repo(".")
    # the repository lock and git context of `dvc repro` (held throughout: the stage commands do not call dvc)
    with lock_repo(repo), repo.scm_context():
        stages = collect_stages(repo, args.targets or ["dvc.yaml"])
        graph = get_active_graph(repo.index.graph)
        steps = plan_repro(graph, stages)
        log(f"{len(steps)} stages planned, {jobs} at a time")
        return Runner(repo, steps, graph, jobs, args.force, args.dry).run()


if __name__ == "__main__":
    sys.exit(main())

"""The MLflow UI for users, and a loopback MLflow tracking server for tests and teams.

    motionsynth ui [--port N] [--host 127.0.0.1] [--backend-store-uri URI]     (or: make ui)

starts ``mlflow server`` on the project's store (``sqlite:///<repo>/mlflow.db``), waits until it
answers, prints ``MLflow UI: http://127.0.0.1:PORT`` and blocks; Ctrl-C or SIGTERM stops the server
and every process it started.

:func:`serve` is the reusable part (the CLI and tests/test_ui.py use it): the server runs as
``python -m mlflow server`` with the light settings (one worker, no job-execution consumers,
about 500 MB), ``--serve-artifacts`` (artifacts show in the UI and clients of an http store
upload through it), in its own session / process group, which is killed as a whole on exit.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Iterator, Sequence

from . import tracking

LIGHT_ENV = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
_REMOTE_SCHEMES = ("http://", "https://", "databricks")


class ServerURL(str):
    """The server's base URL (``http://HOST:PORT``); ``.process`` is the ``mlflow server`` process,
    whose pid is also its process-group and session id, ``.log`` its output file."""

    process: subprocess.Popen
    log: Path

    @property
    def pid(self) -> int:
        return self.process.pid


def project_store(root: str | Path) -> str:
    """The store ``motionsynth ui`` shows by default: ``$MLFLOW_TRACKING_URI`` when it names a local
    store (a database or ``file:`` URI), else the project's ``mlflow.db`` (:func:`tracking.local_store_uri`)."""
    uri = tracking.tracking_uri(root)
    return tracking.local_store_uri(root) if uri.startswith(_REMOTE_SCHEMES) else uri


def artifacts_destination(root: str | Path, backend_store_uri: str) -> Path:
    """Where the server keeps artifacts uploaded through it (experiments created over http):
    beside a SQLite database, as for local experiments (:func:`tracking.sqlite_artifacts`),
    else ``<root>/mlartifacts``."""
    return tracking.sqlite_artifacts(backend_store_uri) or Path(root).resolve() / "mlartifacts"


def is_loopback(host: str) -> bool:
    """Does ``host`` (an address or a name) bind to this machine only? A name counts when every
    address it resolves to is a loopback one; an unresolvable name does not."""
    import ipaddress

    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        pass
    try:
        addrs = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except OSError:
        return False
    return bool(addrs) and all(ipaddress.ip_address(a.split("%")[0]).is_loopback for a in addrs)


def exposure_warning(host: str) -> str | None:
    """The warning ``motionsynth ui --host HOST`` prints when HOST is reachable from other machines."""
    if is_loopback(host):
        return None
    return (f"motionsynth ui: WARNING: --host {host} serves the MLflow UI and REST API to other machines "
            "WITHOUT AUTHENTICATION: anyone who reaches the port can read, change and delete every run. "
            "For a team, put authentication in front of it (MLflow's basic-auth app or a reverse proxy; "
            "README: 'A team tracking server'), or keep the default 127.0.0.1 and use an SSH tunnel.")


def free_port(host: str = "127.0.0.1") -> int:
    """A port nobody listens on now (the kernel's pick for a socket bound to port 0)."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def server_command(root: str | Path, port: int, host: str = "127.0.0.1",
                   backend_store_uri: str | None = None) -> list[str]:
    uri = backend_store_uri or project_store(root)
    return [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri,
            "--host", host, "--port", str(port), "--workers", "1", "--serve-artifacts",
            "--artifacts-destination", str(artifacts_destination(root, uri))]


def _http_ok(url: str, timeout: float = 2.0) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return 200 <= r.status < 300
    except (urllib.error.URLError, OSError, ValueError):
        return False


def group_members(pgid: int) -> list[int]:
    """Live (non-zombie) processes of process group ``pgid``."""
    proc = Path("/proc")
    if not proc.is_dir():  # not Linux: the kernel's answer, zombies included
        try:
            os.killpg(pgid, 0)
            return [pgid]
        except (ProcessLookupError, PermissionError):
            return []
    out = []
    for d in proc.iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2:].split()  # state, ppid, pgrp, session, ...
        if fields[0] != "Z" and int(fields[2]) == pgid:
            out.append(int(d.name))
    return out


def stop_group(proc: subprocess.Popen, grace: float = 10.0) -> None:
    """SIGTERM the process group led by ``proc``, SIGKILL what is left after ``grace`` seconds,
    and wait until no process of the group is alive."""
    pgid = proc.pid
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 10.0)):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, sig)
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            if proc.poll() is not None and not group_members(pgid):
                return
            time.sleep(0.1)
    proc.wait(timeout=5)
    left = group_members(pgid)
    if left:
        raise RuntimeError(f"mlflow server processes {left} survived SIGKILL")


def _tail(path: Path, n: int = 3000) -> str:
    try:
        return path.read_text(errors="replace")[-n:]
    except OSError:
        return ""


@contextlib.contextmanager
def serve(root: str | Path, port: int | None = None, host: str = "127.0.0.1",
          backend_store_uri: str | None = None, timeout: float = 120) -> Iterator[ServerURL]:
    """Run ``mlflow server`` for project ``root`` until the block ends; yields its URL once it answers.

    ``port=None`` picks a free port (retried if another process takes it first). The store is
    ``backend_store_uri``, else :func:`project_store`. The server's output goes to a temporary log
    file (``url.log``), deleted on exit unless the server failed to start (the error quotes it).
    On exit, the server's whole process group (uvicorn worker included) is stopped, and nothing of
    it is left running.
    """
    root = Path(root).resolve()
    root.mkdir(parents=True, exist_ok=True)
    if port is not None and not port_free(host, port):  # else another server would answer for ours
        raise RuntimeError(f"port {port} on {host} is in use (leave out --port to get a free one)")
    env = {**os.environ, **LIGHT_ENV}
    attempts = 3 if port is None else 1
    for attempt in range(attempts):
        p = port or free_port(host)
        fd, log_name = tempfile.mkstemp(prefix="mlflow-server-", suffix=".log")
        log = Path(log_name)
        with os.fdopen(fd, "wb") as out:
            proc = subprocess.Popen(server_command(root, p, host, backend_store_uri), cwd=root, env=env,
                                    stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True)
        failed = False
        try:
            url = ServerURL(f"http://{'[' + host + ']' if ':' in host else host}:{p}")
            url.process, url.log = proc, log
            deadline = time.monotonic() + timeout
            while proc.poll() is None and time.monotonic() < deadline:
                if _http_ok(f"{url}/health") or _http_ok(f"{url}/api/2.0/mlflow/experiments/search?max_results=1"):
                    break
                time.sleep(0.25)
            else:
                died = proc.poll() is not None
                msg = (f"mlflow server on {url} {'exited with code ' + str(proc.returncode) if died else f'did not answer within {timeout:g} s'}"
                       f"\ncommand: {' '.join(proc.args)}\nlog ({log}):\n{_tail(log)}")
                if died and attempt + 1 < attempts and "address already in use" in _tail(log).lower():
                    continue  # another process took the free port meanwhile: pick another
                failed = True  # the message names the log: keep it
                raise RuntimeError(msg)
            yield url
            return
        finally:
            stop_group(proc)
            if not failed:
                with contextlib.suppress(OSError):
                    log.unlink()


def main(argv: Sequence[str] | None = None) -> int:
    """``motionsynth ui``: serve the MLflow UI until Ctrl-C / SIGTERM."""
    ap = argparse.ArgumentParser(
        prog="motionsynth ui",
        description="Browse the project's MLflow runs: starts the MLflow server (UI + REST API) on "
                    "this machine and prints its address; Ctrl-C stops it.")
    ap.add_argument("--port", type=int, default=None, help="port (default: a free one)")
    ap.add_argument("--host", default="127.0.0.1",
                    help="interface to bind (default 127.0.0.1: this machine only; any other serves the "
                         "runs to the network with no authentication: see the README's team-server section)")
    ap.add_argument("--backend-store-uri", default=None,
                    help="the store to show (default: sqlite:///<project>/mlflow.db, or a local "
                         "$MLFLOW_TRACKING_URI)")
    ap.add_argument("--root", default=None,
                    help="the project folder (default: $MOTIONSYNTH_ROOT, else this checkout)")
    ap.add_argument("--timeout", type=float, default=120, help="seconds to wait for the server to answer")
    args = ap.parse_args(list(argv) if argv is not None else None)
    root = Path(args.root or os.environ.get("MOTIONSYNTH_ROOT") or Path(__file__).resolve().parents[2])
    warning = exposure_warning(args.host)
    if warning:
        print(warning, file=sys.stderr, flush=True)

    def on_signal(signum, frame):  # leave through the context manager, which stops the server
        raise KeyboardInterrupt

    # Ctrl-C (even where a shell started us with SIGINT ignored), SIGTERM, and a closed terminal
    # (SIGHUP): the server runs in its own session, so only we can stop it
    stops = [s for s in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, s)]
    old = {s: signal.signal(getattr(signal, s), on_signal) for s in stops}
    try:
        with serve(root, args.port, args.host, args.backend_store_uri, args.timeout) as url:
            store = args.backend_store_uri or project_store(root)
            print(f"MLflow UI: {url}", flush=True)
            print(f"  store: {store}\n  (Ctrl-C stops it)", flush=True)
            while url.process.poll() is None:
                time.sleep(0.5)
            print(f"motionsynth ui: the MLflow server exited with code {url.process.returncode}; "
                  f"its log:\n{_tail(url.log)}", file=sys.stderr)
            return 1
    except KeyboardInterrupt:
        print("motionsynth ui: stopped", file=sys.stderr)
        return 0
    except RuntimeError as e:
        print(f"motionsynth ui: {e}", file=sys.stderr)
        return 1
    finally:
        for s, handler in old.items():
            signal.signal(getattr(signal, s), handler)


def runs_search(url: str, experiment_ids: list[str], max_results: int = 1000) -> list[dict]:
    """All runs of ``experiment_ids`` through the REST API (a small helper for scripts and tests)."""
    return _post(f"{url}/api/2.0/mlflow/runs/search",
                 {"experiment_ids": experiment_ids, "max_results": max_results}).get("runs", [])


def _post(url: str, body: dict) -> dict:
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


if __name__ == "__main__":
    sys.exit(main())

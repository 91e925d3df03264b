"""A stage stopped by bad input or missing data says so in ONE line and exits non-zero (no traceback);
``motionsynth ui`` on a network address warns that the MLflow UI has no authentication."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest
from conftest import REPO


def stage(root, script, *args):
    r = subprocess.run([sys.executable, str(REPO / "pipelines" / script), "tracking.enabled=false",
                        f"hydra.run.dir={root}/logs", *args], cwd=REPO, capture_output=True, text=True,
                       env={**os.environ, "MOTIONSYNTH_ROOT": str(root), "PROGRESS": "0"})
    return r.returncode, r.stderr


def one_line(err: str) -> str:
    assert err.endswith("\n") and err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


def test_not_a_zip_archive(tmp_path):
    (tmp_path / "data" / "raw").mkdir(parents=True)
    (tmp_path / "data" / "raw" / "bandai1.zip").write_bytes(b"this is not a zip archive")
    rc, err = stage(tmp_path, "ingest.py", "dataset=bandai1")
    assert rc == 2
    assert one_line(err) == f"ingest: {tmp_path}/data/raw/bandai1.zip: cannot open archive: File is not a zip file"
    assert not (tmp_path / "data" / "interim" / "bandai1").exists()


@pytest.mark.parametrize("script,args,missing,command", [
    ("train.py", ["model=vae_lstm", "dataset=bandai2_locomotion"],
     "data/processed/bandai2_locomotion/pos3d/representation.json", "dvc repro split@bandai2_locomotion"),
    ("prepare.py", ["dataset=h36m"], "data/interim/h36m: no store there", "dvc repro ingest@h36m"),
    ("split.py", ["dataset=cmu_aclstm"], "data/processed/cmu_aclstm: no prepared representation",
     "dvc repro prepare@cmu_aclstm"),
])
def test_missing_data_names_what_and_the_command_that_makes_it(tmp_path, script, args, missing, command):
    rc, err = stage(tmp_path, script, *args)
    line = one_line(err)
    assert rc == 2 and line.startswith(script.removesuffix(".py") + ": ")
    assert f"{tmp_path}/{missing}" in line and f"`{command}`" in line, line


def test_ui_on_a_network_address_warns_that_it_has_no_authentication(capsys):
    from motionsynth import ui

    assert all(ui.exposure_warning(h) is None for h in ("127.0.0.1", "localhost", "::1", "127.0.0.2"))
    with socket.socket() as busy:              # its port is taken: the CLI warns, then stops before any server
        busy.bind(("0.0.0.0", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert ui.main(["--host", "0.0.0.0", "--port", str(port)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("motionsynth ui: WARNING: --host 0.0.0.0 serves the MLflow UI")
    assert "WITHOUT AUTHENTICATION" in err[0] and "basic-auth" in err[0], err
    assert "in use" in err[1]

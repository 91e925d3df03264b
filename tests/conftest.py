"""Shared fixtures: real archives located through their committed .dvc pointers."""

from __future__ import annotations

import io
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
STORE = REPO.parent / "shared" / "dvc-store" / "files" / "md5"
sys.path.insert(0, str(REPO / "src"))


def archive_path(name: str) -> Path:
    """The real archive ``name`` (e.g. ``bandai1``): data/raw/ if pulled, else the team's DVC store."""
    local = REPO / "data" / "raw" / f"{name}.zip"
    if local.exists():
        return local
    md5 = yaml.safe_load((REPO / "data" / "raw" / f"{name}.zip.dvc").read_text())["outs"][0]["md5"]
    path = STORE / md5[:2] / md5[2:]
    if not path.exists():
        raise FileNotFoundError(f"archive {name} is neither in data/raw nor in {STORE} (run `dvc pull`)")
    return path


def dataset_cfg(name: str) -> dict:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "dataset" / f"{name}.yaml"), resolve=True)


def make_zip(path: Path, members: dict[str, bytes | str]) -> Path:
    """Write a zip archive with the given members (names are written verbatim, hostile ones included)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(zipfile.ZipInfo(name), data.encode() if isinstance(data, str) else data)
    path.write_bytes(buf.getvalue())
    return path


@pytest.fixture
def repo() -> Path:
    return REPO

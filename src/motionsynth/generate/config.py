"""Options of ``motionsynth generate``: ``conf/generate.yaml`` composed with ``key=value``
overrides, the error type every input problem raises, and the small checked parsers."""

from __future__ import annotations

import difflib
import math
import os
import re
from pathlib import Path
from typing import Any, Mapping, Sequence as Seq

FAMILIES = ("vae_lstm", "glocal")
FORMATS = ("bvh", "gif", "npz", "mp4")
TARGETS = {"vae_lstm": "motionsynth.models.vae_lstm.VAELSTM", "glogen": "motionsynth.models.glogen.GloGen",
           "locgen": "motionsynth.models.locgen.LocGen"}
CONF_NAME = "generate"
# values that are free text for an animator: quoted before Hydra parses them (commas, colons, spaces)
FREE_TEXT = ("path", "schedule", "out_dir", "name", "formats", "root", "models_dir", "processed_dir",
             "splits_dir", "params_file", "dataset")
SEGMENT_KEYS = {"seconds", "forward", "sideways", "turn", "radius_m", "turn_deg"}


class GenerateError(ValueError):
    """A problem with the command's inputs, worded for someone who does not read code."""


# ============================================================================ config

def repo_root() -> Path:
    """The checkout this module lives in (``src/motionsynth/generate/config.py`` -> the repository)."""
    return Path(__file__).resolve().parents[3]


def _conf_dir() -> Path:
    candidates = [repo_root() / "conf"]
    if os.environ.get("MOTIONSYNTH_ROOT"):
        candidates.insert(0, Path(os.environ["MOTIONSYNTH_ROOT"]) / "conf")
    candidates.append(Path.cwd() / "conf")
    for c in candidates:
        if (c / f"{CONF_NAME}.yaml").exists():
            return c
    raise GenerateError(f"cannot find conf/{CONF_NAME}.yaml (looked in {', '.join(str(c) for c in candidates)}); "
                        f"run the command from the motionsynth project folder or set MOTIONSYNTH_ROOT")


def quote_overrides(overrides: Seq[str]) -> list[str]:
    """Make ``key=free text`` safe for Hydra's override grammar: ``schedule=walk:4s,run:3s`` would
    be a sweep and ``path=my path.csv`` a syntax error, so such values are single-quoted."""
    out = []
    for ov in overrides:
        m = re.fullmatch(r"([A-Za-z_][\w.]*)=(.*)", ov, flags=re.S)
        if m and m.group(1) in FREE_TEXT:
            key, val = m.groups()
            if not (len(val) >= 2 and val[0] == val[-1] and val[0] in "'\"") and not val.startswith("["):
                if val in ("null", ""):
                    out.append(f"{key}=null" if val == "null" else f"{key}=''")
                    continue
                val = "'" + val.replace("\\", "\\\\").replace("'", "\\'") + "'"
            ov = f"{key}={val}"
        out.append(ov)
    return out


def compose_config(overrides: Seq[str] = ()) -> dict[str, Any]:
    """``conf/generate.yaml`` with ``overrides`` (``key=value`` strings), resolved to a plain dict;
    ``root`` defaults to ``$MOTIONSYNTH_ROOT``, else this checkout."""
    from hydra import compose, initialize
    from hydra.core.config_store import ConfigStore
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    conf = _conf_dir()
    bad = [o for o in overrides if "=" not in o]
    if bad:
        raise GenerateError(f"options are written key=value, got {bad[0]!r} (see motionsynth generate --help)")
    # The file is registered on its own rather than composed from conf/: conf/ holds the training
    # pipeline's config groups (model/, dataset/, ...), which would turn model= and dataset= into
    # group choices.
    ConfigStore.instance().store(name=f"motionsynth_{CONF_NAME}", node=OmegaConf.load(conf / f"{CONF_NAME}.yaml"))
    try:
        with initialize(version_base="1.3", config_path=None):
            cfg = compose(f"motionsynth_{CONF_NAME}", overrides=quote_overrides(overrides))
    except HydraException as e:
        msg = str(e)
        m = re.search(r"Could not override '([^']+)'", msg) or re.search(r"Key '([^']+)' is not in struct", msg)
        if m:
            known = _option_names(OmegaConf.to_container(OmegaConf.load(conf / f"{CONF_NAME}.yaml")))
            near = difflib.get_close_matches(m.group(1), known, n=1)
            raise GenerateError(f"unknown option {m.group(1)!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                                + f"; options: {', '.join(known)} (motionsynth generate --help)") from None
        raise GenerateError(f"cannot read the options {list(overrides)}: {msg.splitlines()[0]}") from None
    if cfg.get("root") in (None, ""):
        cfg.root = os.environ.get("MOTIONSYNTH_ROOT") or str(conf.parent)
    cfg.root = str(Path(str(cfg.root)).expanduser().resolve())
    try:
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    except OmegaConfBaseException as e:
        raise GenerateError(f"cannot resolve the options: {e}") from None


def _option_names(cfg: Mapping) -> list[str]:
    names = []
    for k, v in cfg.items():
        if isinstance(v, Mapping):
            if k == "presets":
                names.append("presets.<name>...")
                continue
            names += [f"{k}.{kk}" for kk in v.keys()]
        else:
            names.append(str(k))
    return names


# ============================================================================ small parsers

def _number(value: Any, what: str, unit: str = "") -> float:
    if isinstance(value, bool):
        raise GenerateError(f"{what} must be a number{unit}, got {value!r}")
    if isinstance(value, str):
        v = value.strip()
        if unit == " of seconds" and v.lower().endswith("s"):
            v = v[:-1].strip()
        try:
            value = float(v)
        except ValueError:
            raise GenerateError(f"{what} must be a number{unit}, got {value!r}") from None
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise GenerateError(f"{what} must be a number{unit}, got {value!r}") from None
    if not math.isfinite(value):
        raise GenerateError(f"{what} must be a finite number{unit}, got {value!r}")
    return value


def _int(value: Any, what: str, minimum: int) -> int:
    v = _number(value, what)
    if v != int(v) or v < minimum:
        raise GenerateError(f"{what} must be a whole number >= {minimum}, got {value!r}")
    return int(v)


def _canon(name: str) -> str:
    return re.sub(r"[\s_]+", "-", str(name).strip().lower())


def _suggest(name: str, known: Seq[str]) -> str:
    near = difflib.get_close_matches(_canon(name), [_canon(k) for k in known], n=1, cutoff=0.5)
    if not near:
        return ""
    return f" (did you mean {next(k for k in known if _canon(k) == near[0])!r}?)"

"""``motionsynth generate``: trained models -> BVH / GIF / NPZ files an animator can open.

Two model families (``conf/generate.yaml``, every key settable as ``key=value``):

* ``model=vae_lstm`` (VAE-LSTM on ``bandai2_locomotion``): a character walks along a *control
  path*: per frame ``(forward m/s, sideways m/s, turn rad/s)`` in the body's own frame (+ sideways
  and + turn = to the left), at the dataset's frame rate (60 fps). The path is a named preset
  (``presets:`` in the config: piecewise-constant segments, smoothed) or a CSV file with
  columns ``forward, sideways, turn`` (one row per frame) and optionally ``time`` (seconds; the
  rows are then resampled linearly onto the frame grid). Preset speeds may be *named*
  (``forward: walk``): the median forward speed of that class's frames in the training split
  (1.14 m/s for ``walk`` in the full data). The latent code is sampled from the prior (0
  initial frames, Algorithm 1), one per character (``num_samples``). The root trajectory is the
  integral of the path (:func:`~motionsynth.data.controls.integrate_controls`, starting at the
  origin facing +Z, or ``start_heading_deg``); each generated root-relative pose is rotated to
  the heading and moved to the root: global positions.
* ``model=glocal`` (GloGen + LocGen on ``bandai1``): a *class schedule*
  ``"walk:4s,run:3s,walk-left:3s"``. GloGen rolls out sparse poses (one per ``k`` = 5 frames of
  the data), LocGen fills ``M`` in-betweens per gap. Pace: ``M + 1`` output frames per sparse
  step, the whole number nearest to ``k / pace`` in ratio (:func:`frames_per_step`; k = 5:
  pace 0.5 -> 10, 1 -> 5, 1.5 and 2 -> 3, 2.5 and 3 -> 2), so the same sparse poses (the
  schedule "in poses") play faster (fewer frames) or slower; the effective pace
  ``k / (M + 1)`` is printed and stored. GlocalNet has no trajectory model: the poses
  are root-relative, so the character **stays in place** (root over the origin, facing +Z),
  like a treadmill; no trajectory is invented.

Choices where the brief is open (and why)
-----------------------------------------
* **Schedule durations are at pace 1** ("natural" time: ``d`` seconds = ``round(d * fps / k)``
  sparse steps, durations rounded to the sparse grid of ``k / fps`` = 1/6 s). The output lasts
  ``steps * (M + 1)`` frames, i.e. about ``total / pace`` seconds; a switch at natural time
  ``s`` lands at output frame ``round(s * fps / k) * (M + 1)``. The last entry may omit its
  duration (``walk:4s,run``): it then fills the output up to ``seconds``.
* **Exact switch times**: ``GloGen.generate`` with per-step labels switches class only at its
  chunk starts (every ``t_in`` sparse poses). To switch exactly at the asked pose, each
  schedule entry is one ``GloGen.generate`` call with that entry's class, seeded with the last
  ``t_in`` poses generated so far; inside an entry this is the same roll-out as per-step
  labels, and a switch on a chunk boundary gives identical output.
* **Seed** (GloGen needs ``t_in`` initial sparse poses): ``glocal.seed_motion=data`` takes the
  first ``t_in`` sparse poses of the first window (file order: first sequence, frame 0) of a
  test-split sequence of the first class (then val, then train, when the test split has
  none) - deterministic; ``zeros`` starts from the train-split mean pose. The seed poses are
  part of the output, so the first entry must last at least ``t_in * k / fps`` (0.83 s).
* **Transitions**: GloGen rolls out chunks of ``t_in`` sparse poses, and the first pose of a chunk
  can jump - at class switches and inside a class alike. Measured as the step into a pose over
  the median of the 10 steps around it (:func:`seam_jumps`; 1 = smooth; over all poses of a
  bandai1 output: median 0.96, 90th percentile 1.9), default-profile models, no blending:
  bandai1 ``walk:4s,run:3s,walk-left:3s`` switches 1.8 / 1.4, chunk seams 1.75 on average;
  ``walk:3s,bow:3s,run:3s,kick:3s`` switches 1.9 / 1.4 / 1.5, seams 1.3; cmu_aclstm (same
  architecture) switches 3.3 / 3.1, seams 3.9: a visible pop every ``t_in * k / fps`` = 0.83 s.
  So by default (``glocal.blend_at=seams``; ``switches`` and ``none`` are the other choices) at
  every chunk start ``q`` the velocity change ``x[q] - 2 x[q-1] + x[q-2]`` is removed and faded
  back in over ``glocal.blend_poses`` (5) sparse poses with a raised-cosine weight: the pose at
  the seam continues the previous velocity, later poses converge to GloGen's
  (:func:`blend_seams`). After it: bandai1 seams 0.85 / 0.86, switches 1.8 / 1.05 and
  1.1 / 1.3 / 0.9 (walk -> run stays a little above 1: running takes longer steps);
  cmu_aclstm seams 1.0, switches 1.2 / 0.9. LocGen then fills in-betweens between the blended
  poses. The ratios before/after are printed and stored in the NPZ (``switch_jump_raw``,
  ``switch_jump``, ``chunk_jump_raw``, ``chunk_jump``; ``sparse_raw`` / ``sparse`` hold the
  keyframes before/after, normalised).
* **Lengths**: a VAE-LSTM output of ``T`` frames is generated with ``T`` rounded up to the
  pooling factor (4) and cut back; the controls are padded with their last row. Output must
  last at least ``min_seconds`` (10 s).
* **Several characters** (``num_samples > 1``, VAE-LSTM only; GlocalNet is deterministic):
  one file set per character, ``<name>_<i>.*``, all on the same path.
* **BVH**: on the prepared representation's skeleton (``skeleton.json``, 21 joints), in the
  source files' units (centimetres, :func:`~motionsynth.viz.bvh_export.dataset_scale`); bone
  lengths are the skeleton's, directions the generated ones (no bone-length check by default:
  generated bones stretch a little).
* **GIF** with matplotlib (blitting) + Pillow, ``gif.fps`` frames per second (every n-th frame):
  ~1.5 s for 10 s at 15 fps; **MP4** (H.264) through the ffmpeg binary bundled with
  ``imageio-ffmpeg`` (raw frames piped in; ``$IMAGEIO_FFMPEG_EXE`` overrides it; without either, an
  error before any work). Both are drawn by :mod:`motionsynth.viz.animation`, which the
  ``animate`` stage's side-by-side comparisons share.

Errors: every problem an animator can cause (unknown option, class, preset, malformed schedule
or CSV, bad length or pace, missing model or data) raises :class:`GenerateError` from
:func:`compose_config` or :func:`plan`, before a model is loaded or a file written.
``motionsynth.cli.main`` prints the message and exits with code 2.
"""

from __future__ import annotations

import csv
import difflib
import json
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence as Seq

import numpy as np

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
    """The checkout this module lives in (``src/motionsynth/generate.py`` -> the repository)."""
    return Path(__file__).resolve().parents[2]


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


@dataclass
class Entry:
    """One schedule entry: class name and index, duration at pace 1 (None: fills the rest)."""

    name: str
    label: int
    seconds: float | None


def parse_schedule(text: str, classes: Mapping[str, int]) -> list[Entry]:
    """``"walk:4s,run:3s,walk-left:3s"`` -> entries. Separators: ``,``, ``;`` or spaces; durations in
    seconds with an optional ``s``; names case-insensitive (``_`` or a space = ``-``); the last
    entry may omit its duration. ``classes`` maps class names to label indices."""
    if not isinstance(text, str) or not text.strip():
        raise GenerateError('the schedule is empty: write it as "class:seconds,class:seconds,...", '
                            'e.g. schedule="walk:4s,run:3s,walk-left:3s"')
    known = {_canon(k): (k, v) for k, v in classes.items()}
    tidy = re.sub(r"\s*:\s*", ":", text.strip())
    tidy = re.sub(r"(\d)\s+(s|sec|secs|seconds)\b", r"\1\2", tidy, flags=re.I)
    parts = [p.strip() for p in re.split(r"\s*[,;]\s*|\s+", tidy)]
    entries = []
    for i, part in enumerate(parts):
        where = f"schedule entry {i + 1} ({part!r})"
        if not part:
            raise GenerateError(f"schedule {text!r}: entry {i + 1} is empty (two commas in a row, or a trailing comma?)")
        if ":" in part:
            name, dur = (s.strip() for s in part.split(":", 1))
            m = re.fullmatch(r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|sec|secs|seconds)?", dur, flags=re.I)
            if not m:
                raise GenerateError(f"{where}: the duration {dur!r} is not a number of seconds "
                                    f"(write e.g. {name or 'walk'}:4s)")
            seconds = float(m.group(1))
            if seconds <= 0:
                raise GenerateError(f"{where}: the duration must be positive")
        else:
            name, seconds = part, None
            if i != len(parts) - 1:
                raise GenerateError(f"{where} has no duration: only the last entry may omit it "
                                    f"(write e.g. {part}:3s)")
        if not name:
            raise GenerateError(f"{where}: the class name is missing (write e.g. walk:4s)")
        if _canon(name) not in known:
            raise GenerateError(f"unknown class {name!r} in the schedule{_suggest(name, list(classes))}; "
                                f"known classes: {', '.join(classes)}")
        canon, label = known[_canon(name)]
        entries.append(Entry(canon, label, seconds))
    return entries


def read_controls_csv(path: str | Path, fps: float) -> np.ndarray:
    """A control path CSV -> ``[T, 3]`` float64 (forward m/s, sideways m/s, turn rad/s) per frame.

    Columns ``forward, sideways, turn`` (any order, case-insensitive, extra columns ignored);
    one row per frame at ``fps``, or with a ``time`` column (seconds, increasing): resampled
    linearly onto ``time[0] + i / fps``. Errors name the file, the row (counting the header as
    row 1, as a spreadsheet does) and the column."""
    import pandas as pd

    path = Path(path)
    if not path.is_file():
        raise GenerateError(f"path={str(path)!r}: no such file (a path is a preset name or a CSV file with "
                            f"columns forward, sideways, turn)")
    try:
        # the delimiter is sniffed (, ; or tab: spreadsheets in some locales write ;); blank lines are kept
        # so that reported row numbers are the file's
        df = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True, sep=None,
                         engine="python", skip_blank_lines=False, encoding="utf-8-sig")
    except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError, csv.Error) as e:
        raise GenerateError(f"{path}: not a readable CSV file ({str(e).splitlines()[0]})") from None
    df = df.fillna("")
    df.columns = [str(c).strip().lower() for c in df.columns]
    filled = np.flatnonzero((df.astype(str).apply(lambda c: c.str.strip()) != "").any(axis=1).to_numpy())
    df = df.iloc[:filled[-1] + 1 if len(filled) else 0]             # trailing blank lines are no rows
    need = ["forward", "sideways", "turn"]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise GenerateError(f"{path}: missing column(s) {', '.join(missing)}; the file has "
                            f"{', '.join(map(repr, df.columns)) or 'no columns'}. A control path needs columns "
                            f"forward (m/s), sideways (m/s, + = left) and turn (rad/s, + = left), optionally time (s)")
    if len(df) == 0:
        raise GenerateError(f"{path}: no data rows under the header")
    cols = need + (["time"] if "time" in df.columns else [])
    values = {}
    for c in cols:
        s = df[c].astype(str).str.strip()
        v = pd.to_numeric(s, errors="coerce").to_numpy(dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(v))
        if len(bad):
            r = int(bad[0])
            raw = s.iloc[r]
            what = "is empty" if raw == "" else (f"is {raw!r}, not a finite number")
            raise GenerateError(f"{path}: row {r + 2} (counting the header as row 1), column {c!r} {what}"
                                + (f"; {len(bad)} bad value(s) in that column" if len(bad) > 1 else ""))
        values[c] = v
    ctrl = np.stack([values[c] for c in need], axis=1)
    if "time" not in values:
        return ctrl
    t = values["time"]
    step = np.diff(t)
    if len(t) < 2:
        raise GenerateError(f"{path}: a time column needs at least 2 rows")
    if (step <= 0).any():
        r = int(np.flatnonzero(step <= 0)[0]) + 1
        raise GenerateError(f"{path}: row {r + 2}, column 'time': {t[r]:g} s does not come after the previous "
                            f"row's {t[r - 1]:g} s (times must increase)")
    frames = int(math.floor((t[-1] - t[0]) * fps + 1e-9)) + 1
    grid = t[0] + np.arange(frames) / fps
    return np.stack([np.interp(grid, t, ctrl[:, i]) for i in range(3)], axis=1)


# ============================================================================ data look-ups

@dataclass
class RunInfo:
    """A trained run: its folder, resolved training config and checkpoint."""

    name: str
    dir: Path
    cfg: dict
    ckpt: Path


def _train_stage(params_file: Path, dataset: str, run: str, model: str) -> str:
    try:
        import yaml

        runs = yaml.safe_load(params_file.read_text()).get("train_runs") or {}
        for key, r in runs.items():
            if r.get("dataset") == dataset and r.get("name") == run:
                return f"`dvc repro train@{key}`"
    except (OSError, ValueError, AttributeError):
        pass
    return (f"`python pipelines/train.py dataset={dataset} model={model} run_name={run}` (no train stage in "
            f"params.yaml names it)")


def _find_run(cfg: dict, dataset: str, run: str, kind: str) -> RunInfo:
    import yaml

    d = Path(cfg["models_dir"]) / dataset / run
    ckpt, conf = d / "best.pt", d / "config.yaml"
    if not ckpt.exists() or not conf.exists():
        stage = _train_stage(Path(cfg["params_file"]), dataset, run, kind)
        state = "is still training or stopped early" if (d / "last.pt").exists() else "has not been trained"
        raise GenerateError(f"no trained {kind} model at {ckpt} (it {state}); {stage} produces it. "
                            f"Models are looked up in models_dir={cfg['models_dir']}")
    rcfg = yaml.safe_load(conf.read_text())
    target = (rcfg.get("model") or {}).get("_target_")
    if target != TARGETS[kind]:
        raise GenerateError(f"{d} holds a {str(target).rsplit('.', 1)[-1]} model, not a {TARGETS[kind].rsplit('.', 1)[-1]}")
    return RunInfo(run, d, rcfg, ckpt)


def _run_cfg_with_paths(info: RunInfo, cfg: dict) -> dict:
    """The run's training config pointed at this command's data folders (the stored paths may
    be another machine's)."""
    rc = json.loads(json.dumps(info.cfg))
    rc["paths"] = {**(rc.get("paths") or {}), "processed": cfg["processed_dir"], "splits": cfg["splits_dir"],
                   "root": cfg["root"], "models": cfg["models_dir"]}
    return rc


def _hparams(rc: dict) -> dict:
    """The model's constructor arguments as :func:`motionsynth.training.run.build` merges them."""
    from .training.run import hparams

    return hparams(rc)


@dataclass
class DataInfo:
    rep_dir: Path
    split_dir: Path
    protocol: str
    fps: float
    meta: Any            # pandas DataFrame: the representation's sequences
    split: Any           # pandas Series sequence_id -> split
    skeleton: Any        # motionsynth.data.types.Skeleton


def _data(cfg: dict, info: RunInfo) -> DataInfo:
    import pandas as pd

    from .data.types import Skeleton

    ds = info.cfg["dataset"]
    rep, proto = ds["training"]["representation"], ds["training"]["protocol"]
    rep_dir = Path(cfg["processed_dir"]) / ds["name"] / rep
    split_dir = Path(cfg["splits_dir"]) / ds["name"] / rep
    need = [rep_dir / "representation.json", rep_dir / "meta.parquet", rep_dir / "skeleton.json",
            split_dir / f"{proto}.csv", split_dir / f"{proto}_stats.npz"]
    missing = [p for p in need if not p.exists()]
    if missing:
        raise GenerateError(f"the prepared data of {ds['name']} is missing ({missing[0]}); `dvc repro split@{ds['name']}` "
                            f"produces it (generation needs its skeleton, class names and normalisation statistics)")
    repr_ = json.loads((rep_dir / "representation.json").read_text())
    if repr_.get("space") != "3d":
        raise GenerateError(f"{info.dir} was trained on the {repr_.get('space')} representation {rep!r}; "
                            f"generate writes 3-D motion only")
    meta = pd.read_parquet(rep_dir / "meta.parquet")
    split = pd.read_csv(split_dir / f"{proto}.csv").set_index("sequence_id")["split"]
    return DataInfo(rep_dir, split_dir, proto, float(repr_["fps"]), meta, split, Skeleton.load(rep_dir / "skeleton.json"))


def _train_controls(data: DataInfo, label: int | None = None) -> np.ndarray:
    """Control signals ``[N, 3]`` of the training split's frames (of one class)."""
    c = np.load(data.rep_dir / "controls.npy", mmap_mode="r")
    m = data.meta
    keep = m["sequence_id"].map(data.split).to_numpy() == "train"
    if label is not None:
        keep &= m["label"].to_numpy() == label
    rows = [np.arange(o, o + f) for o, f in zip(m["offset"].to_numpy()[keep], m["frames"].to_numpy()[keep])]
    if not rows:
        return np.zeros((0, 3))
    return np.asarray(c[np.concatenate(rows)], dtype=np.float64)


def class_names(data: DataInfo) -> dict[str, int]:
    """Class name -> label of the classes with training sequences, in label order."""
    m = data.meta
    if "label_name" not in m.columns or "label" not in m.columns:
        return {}
    train = m[m["sequence_id"].map(data.split).to_numpy() == "train"]
    pairs = train[["label", "label_name"]].drop_duplicates().sort_values("label")
    return {str(n): int(lab) for lab, n in zip(pairs["label"], pairs["label_name"]) if str(n) and int(lab) >= 0}


# ============================================================================ control-path presets

def _speed(value: Any, speeds: Mapping[str, float], where: str) -> float:
    if isinstance(value, str) and not re.fullmatch(r"\s*-?[0-9.eE+-]+\s*", value):
        if value not in speeds:
            raise GenerateError(f"{where}: unknown named speed {value!r}; named speeds: {', '.join(speeds) or 'none'} "
                                f"(vae_lstm.typical_speeds), or give m/s")
        return speeds[value]
    return _number(value, where, " (m/s)")


def preset_controls(name: str, preset: Mapping, frames: int, fps: float, speeds: Mapping[str, float],
                    smooth_s: float) -> tuple[np.ndarray, float]:
    """A preset's control path ``[frames, 3]`` and its start heading (radians). See the
    ``presets:`` section of ``conf/generate.yaml`` for the segment keys."""
    from .data.controls import gaussian_smooth

    where = f"preset {name!r} (conf/generate.yaml presets.{name})"
    if not isinstance(preset, Mapping) or not isinstance(preset.get("segments"), list) or not preset["segments"]:
        raise GenerateError(f"{where}: needs a non-empty list of segments")
    unknown = set(preset) - {"segments", "repeat", "start_heading_deg"}
    if unknown:
        raise GenerateError(f"{where}: unknown keys {sorted(unknown)}; known: segments, repeat, start_heading_deg")
    segs, repeat = preset["segments"], bool(preset.get("repeat", False))
    rows = []
    for i, seg in enumerate(segs):
        w = f"{where} segment {i + 1}"
        if not isinstance(seg, Mapping):
            raise GenerateError(f"{w}: must be a mapping like {{seconds: 2, forward: walk}}")
        bad = set(seg) - SEGMENT_KEYS
        if bad:
            raise GenerateError(f"{w}: unknown keys {sorted(bad)}; known: {', '.join(sorted(SEGMENT_KEYS))}")
        n = None
        if seg.get("seconds") is not None:
            s = _number(seg["seconds"], f"{w} seconds", " of seconds")
            if s <= 0:
                raise GenerateError(f"{w}: seconds must be positive")
            n = max(1, round(s * fps))
        elif repeat or i != len(segs) - 1:
            raise GenerateError(f"{w}: needs seconds (only the last segment of a non-repeating preset may fill the rest)")
        fwd = _speed(seg.get("forward", 0.0), speeds, f"{w} forward")
        side = _speed(seg.get("sideways", 0.0), speeds, f"{w} sideways")
        turns = [k for k in ("turn", "radius_m", "turn_deg") if seg.get(k) is not None]
        if len(turns) > 1:
            raise GenerateError(f"{w}: give only one of turn, radius_m, turn_deg")
        turn = 0.0
        if turns == ["turn"]:
            turn = _number(seg["turn"], f"{w} turn", " (rad/s)")
        elif turns == ["radius_m"]:
            r = _number(seg["radius_m"], f"{w} radius_m", " (metres)")
            if r == 0:
                raise GenerateError(f"{w}: radius_m must not be 0")
            turn = fwd / r
        elif turns == ["turn_deg"]:
            if n is None:
                raise GenerateError(f"{w}: turn_deg needs the segment's seconds")
            turn = math.radians(_number(seg["turn_deg"], f"{w} turn_deg", " (degrees)")) / (n / fps)
        rows.append((n, (fwd, side, turn)))
    out = np.zeros((frames, 3))
    t, i = 0, 0
    while t < frames:
        if not repeat and i >= len(rows):
            out[t:] = rows[-1][1]
            break
        n, val = rows[i % len(rows)]
        n = frames - t if n is None else n
        out[t:t + n] = val
        t, i = t + n, i + 1
    heading = math.radians(_number(preset.get("start_heading_deg", 0.0), f"{where} start_heading_deg", " (degrees)"))
    return gaussian_smooth(out, smooth_s * fps), heading


# ============================================================================ plan

@dataclass
class Plan:
    """Everything :func:`run` needs, checked: no model loaded, no file written yet."""

    cfg: dict
    family: str
    dataset: str
    fps: float
    frames: int
    formats: list[str]
    out_dir: Path
    stem: str
    data: DataInfo
    runs: dict[str, RunInfo]
    num_samples: int = 1
    warnings: list[str] = field(default_factory=list)
    # vae_lstm
    path_name: str | None = None
    controls: np.ndarray | None = None        # [T, 3] physical units
    start_heading: float = 0.0
    # glocal
    entries: list[Entry] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)   # sparse steps per entry
    classes: dict[str, int] = field(default_factory=dict)
    k: int = 1
    M: int = 0
    t_in: int = 1
    pace: float = 1.0
    seed_window: tuple[str, int, str] | None = None  # (split, window index, sequence id)

    @property
    def seconds(self) -> float:
        return self.frames / self.fps

    def describe(self) -> str:
        if self.family == "vae_lstm":
            what = f"VAE-LSTM ({self.runs['vae_lstm'].dir}) along path {self.path_name!r}"
            if self.num_samples > 1:
                what += f", {self.num_samples} characters"
        else:
            what = (f"GloGen + LocGen ({self.runs['glogen'].dir}, {self.runs['locgen'].dir}) playing "
                    f"{schedule_text(self.entries, self.steps, self.k, self.fps)} at pace {self.pace:g} "
                    f"(M = {self.M} in-betweens per {self.k}-frame step: effective pace {self.k / (self.M + 1):.3g})")
        return f"{self.seconds:.2f} s ({self.frames} frames at {self.fps:g} fps) with {what}"


def schedule_text(entries: list[Entry], steps: list[int], k: int, fps: float) -> str:
    return ",".join(f"{e.name}:{s * k / fps:g}s" for e, s in zip(entries, steps))


def frames_per_step(k: int, pace: float) -> int:
    """``M + 1``: the whole number of output frames per sparse step whose pace ``k / (M + 1)`` is
    nearest (as a ratio) to ``pace``; e.g. k = 5: pace 1 -> 5, 1.5 -> 3 (1.67), 2 -> 3 (1.67),
    2.5 -> 2, 0.5 -> 10."""
    x = k / pace
    lo, hi = max(1, math.floor(x)), max(1, math.ceil(x))
    return lo if abs(math.log(k / lo / pace)) <= abs(math.log(k / hi / pace)) else hi


def _seconds_opt(cfg: dict) -> float | None:
    if cfg.get("seconds") in (None, ""):
        return None
    s = _number(cfg["seconds"], "seconds", " of seconds")
    if s <= 0:
        raise GenerateError(f"seconds must be positive, got {cfg['seconds']!r}")
    return s


def _check_length(frames: int, fps: float, cfg: dict, hint: str) -> None:
    need = float(cfg.get("min_seconds", 0.0))
    if frames / fps + 1e-9 < need:
        raise GenerateError(f"the output would last {frames / fps:.2f} s ({frames} frames at {fps:g} fps), "
                            f"shorter than the minimum of {need:g} s; {hint}")


def plan(cfg: dict) -> Plan:
    """Check every input and resolve it (cheap reads only: configs, tables, statistics)."""
    family = cfg.get("model")
    if family not in FAMILIES:
        raise GenerateError(f"model={family!r} is not a model family here{_suggest(str(family), FAMILIES)}; "
                            f"choose model=vae_lstm (walk along a path) or model=glocal (a schedule of activities)")
    fam = cfg[family]
    formats = cfg.get("formats")
    if isinstance(formats, str):
        formats = [f for f in re.split(r"[,\s]+", formats.strip()) if f]
    if not isinstance(formats, list) or not formats:
        raise GenerateError(f"formats must list some of {', '.join(FORMATS)}, e.g. formats=[bvh,gif], got {formats!r}")
    formats = [str(f).strip().lower().lstrip(".") for f in formats]
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise GenerateError(f"unknown output format(s) {bad}; choose from {', '.join(FORMATS)}")
    if "mp4" in formats:
        if ffmpeg_path() is None:
            raise GenerateError("mp4 output needs ffmpeg, which is not available here (the Python package "
                                "imageio-ffmpeg bundles it: pip install imageio-ffmpeg; or set IMAGEIO_FFMPEG_EXE "
                                "to an ffmpeg binary); drop mp4 from formats (GIF works without it)")
    formats = list(dict.fromkeys(formats))
    seed = cfg.get("seed")
    _int(seed, "seed", 0)
    _int(cfg.get("threads"), "threads", 1)
    ns = _int(cfg.get("num_samples"), "num_samples", 1)
    out_dir = Path(str(cfg.get("out_dir") or ".")).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise GenerateError(f"out_dir={str(out_dir)!r} is a file, not a folder")
    parent = next((p for p in [out_dir, *out_dir.absolute().parents] if p.exists()), None)
    if parent is None or not os.access(parent, os.W_OK):
        raise GenerateError(f"out_dir={str(out_dir)!r}: cannot write there ({parent} is not writable)")
    if cfg.get("name") not in (None, "") and not re.fullmatch(r"[\w.+-]+", str(cfg["name"])):
        raise GenerateError(f"name={cfg['name']!r}: use letters, digits, '-', '_', '.' or '+' only (it names the files)")
    dataset = cfg.get("dataset") or fam["default_dataset"]
    seconds = _seconds_opt(cfg)
    _number(cfg.get("min_seconds"), "min_seconds", " of seconds")
    if family == "glocal":
        _int(fam.get("blend_poses") or 0, "glocal.blend_poses", 0)
        if fam.get("blend_at", "seams") not in ("seams", "switches", "none"):
            raise GenerateError(f"glocal.blend_at must be seams, switches or none, got {fam.get('blend_at')!r}")

    if family == "vae_lstm":
        if cfg.get("schedule") not in (None, "") or _number(cfg.get("pace"), "pace") != 1.0:
            raise GenerateError(f"{'schedule' if cfg.get('schedule') not in (None, '') else 'pace'}= applies to "
                                f"model=glocal; model=vae_lstm follows a path= (a preset or a CSV file)")
        runs = {"vae_lstm": _find_run(cfg, dataset, fam["run"], "vae_lstm")}
        data = _data(cfg, runs["vae_lstm"])
        p = _plan_vae(cfg, fam, data, seconds)
    else:
        if cfg.get("path") not in (None, ""):
            raise GenerateError("path= applies to model=vae_lstm; model=glocal plays a schedule= of activities, "
                                'e.g. schedule="walk:4s,run:3s,walk-left:3s"')
        if ns != 1:
            raise GenerateError("GloGen + LocGen are deterministic: every character would be identical; "
                                "use num_samples=1 (or model=vae_lstm for a crowd)")
        runs = {"glogen": _find_run(cfg, dataset, fam["glogen_run"], "glogen"),
                "locgen": _find_run(cfg, dataset, fam["locgen_run"], "locgen")}
        data = _data(cfg, runs["glogen"])
        p = _plan_glocal(cfg, fam, data, runs, seconds)
    p.update(cfg=cfg, family=family, dataset=dataset, formats=formats, out_dir=out_dir, data=data, runs=runs,
             num_samples=ns)
    pl = Plan(**p)
    pl.stem = str(cfg["name"]) if cfg.get("name") not in (None, "") else _default_stem(pl)
    return pl


def _default_stem(p: Plan) -> str:
    if p.family == "vae_lstm":
        s = f"vae_lstm_{Path(p.path_name).stem if p.path_name else 'path'}_{round(p.seconds, 1):g}s"
    else:
        names = "-".join(dict.fromkeys(_canon(e.name) for e in p.entries))
        s = f"glocal_{names[:60]}_pace{p.pace:g}"
    return re.sub(r"[^\w.+-]+", "_", s)


def _plan_vae(cfg: dict, fam: dict, data: DataInfo, seconds: float | None) -> dict:
    fps = data.fps
    path = cfg.get("path")
    path = fam["default_path"] if path in (None, "") else str(path)
    presets = cfg.get("presets") or {}
    warnings: list[str] = []
    is_file = path.lower().endswith((".csv", ".txt")) or os.sep in path or "/" in path or Path(path).is_file()
    if is_file:
        ctrl = read_controls_csv(path, fps)
        if seconds is not None:
            frames = round(seconds * fps)
            if frames > len(ctrl):
                raise GenerateError(f"{path} covers {len(ctrl) / fps:.2f} s ({len(ctrl)} frames at {fps:g} fps) "
                                    f"but seconds={seconds:g} asks for more; drop seconds= to use the whole file")
            ctrl = ctrl[:frames]
        frames = len(ctrl)
        _check_length(frames, fps, cfg, f"the CSV {path} needs at least {math.ceil(cfg['min_seconds'] * fps)} rows "
                                        f"(one per frame at {fps:g} fps) or a time column spanning that long")
        heading = 0.0
    else:
        if path not in presets:
            raise GenerateError(f"unknown path preset {path!r}{_suggest(path, list(presets))}; presets: "
                                f"{', '.join(presets)} - or give a CSV file (columns forward, sideways, turn)")
        frames = round((seconds if seconds is not None else _number(fam["default_seconds"], "vae_lstm.default_seconds"))
                       * fps)
        _check_length(frames, fps, cfg, "set seconds= to a longer length")
        classes = class_names(data)
        speeds = {}
        used = {str(s.get(k)) for s in presets[path].get("segments", []) if isinstance(s, Mapping)
                for k in ("forward", "sideways")}
        for sname, cls in (fam.get("typical_speeds") or {}).items():
            if sname not in used:
                speeds[sname] = float("nan")   # known name, not needed by this preset
                continue
            if cls not in classes:
                raise GenerateError(f"vae_lstm.typical_speeds.{sname}: class {cls!r} is not in {data.rep_dir} "
                                    f"(classes: {', '.join(classes)})")
            c = _train_controls(data, classes[cls])
            if not len(c):
                raise GenerateError(f"vae_lstm.typical_speeds.{sname}: no training frames of class {cls!r}")
            speeds[sname] = float(np.median(c[:, 0]))
        ctrl, heading = preset_controls(path, presets[path], frames, fps, speeds,
                                        _number(fam["smooth_s"], "vae_lstm.smooth_s"))
    lo_p, hi_p = fam.get("range_percentiles") or (0.0, 100.0)
    train = _train_controls(data)
    if len(train):
        lo, hi = np.percentile(train, [lo_p, hi_p], axis=0)
        for i, (nm, unit) in enumerate((("forward", "m/s"), ("sideways", "m/s"), ("turn", "rad/s"))):
            if ctrl[:, i].min() < lo[i] - 1e-9 or ctrl[:, i].max() > hi[i] + 1e-9:
                warnings.append(f"{nm} goes from {ctrl[:, i].min():.2f} to {ctrl[:, i].max():.2f} {unit}; the training "
                                f"data's {lo_p:g}-{hi_p:g} % range is {lo[i]:.2f} to {hi[i]:.2f} {unit}: "
                                f"expect artefacts there")
    return dict(fps=fps, frames=frames, path_name=path, controls=ctrl, start_heading=heading, warnings=warnings,
                stem="")


def _plan_glocal(cfg: dict, fam: dict, data: DataInfo, runs: dict[str, RunInfo], seconds: float | None) -> dict:
    import pandas as pd

    fps = data.fps
    g, loc = runs["glogen"], runs["locgen"]
    if (g.cfg["dataset"]["training"]["representation"] != loc.cfg["dataset"]["training"]["representation"]
            or g.cfg["dataset"]["training"]["protocol"] != loc.cfg["dataset"]["training"]["protocol"]):
        raise GenerateError(f"{g.dir} and {loc.dir} were trained on different data representations")
    clips = g.cfg["dataset"]["prepare"]["representations"][g.cfg["dataset"]["training"]["representation"]]["clips"]
    k = int(clips["glocal"]["every"])
    t_in = int(_hparams(g.cfg).get("t_in", 5))
    classes = class_names(data)
    if not classes:
        raise GenerateError(f"{g.cfg['dataset']['name']} has no class labels: a schedule needs named classes")
    text = cfg.get("schedule")
    text = fam["default_schedule"] if text in (None, "") else str(text)
    entries = parse_schedule(text, classes)
    pace = _number(cfg.get("pace"), "pace")
    lo, hi = (float(x) for x in fam["pace_range"])
    if not lo <= pace <= hi:
        raise GenerateError(f"pace={pace:g} is outside {lo:g}..{hi:g} (1 = the data's pace, 2 = twice as fast)")
    M = frames_per_step(k, pace) - 1
    step_s = k / fps
    steps = []
    for e in entries:
        if e.seconds is None:
            steps.append(None)
            continue
        n = round(e.seconds / step_s)
        if n < 1:
            raise GenerateError(f"schedule entry {e.name}:{e.seconds:g}s is shorter than one pose step ({step_s:.3g} s)")
        steps.append(n)
    fixed = sum(s for s in steps if s is not None)
    if steps[-1] is None:
        if seconds is None:
            raise GenerateError(f"the last schedule entry {entries[-1].name!r} has no duration: give it one "
                                f"({entries[-1].name}:3s) or set seconds= to the length of the whole output")
        frames = round(seconds * fps)
        total = math.ceil(frames / (M + 1))
        if total - fixed < 1:
            raise GenerateError(f"the schedule's other entries already last {fixed * (M + 1) / fps:.2f} s at pace "
                                f"{pace:g}; seconds={seconds:g} leaves nothing for {entries[-1].name!r}")
        steps[-1] = total - fixed
    else:
        if seconds is not None:
            raise GenerateError(f"seconds= only applies when the schedule's last entry has no duration (e.g. "
                                f"{','.join(f'{e.name}:{e.seconds:g}s' for e in entries[:-1]) + ',' if len(entries) > 1 else ''}"
                                f"{entries[-1].name}); this schedule sets every duration: it lasts "
                                f"{fixed * step_s:g} s at pace 1"
                                + (f", {fixed * (M + 1) / fps:.2f} s at pace {pace:g}" if M + 1 != k else ""))
        frames = fixed * (M + 1)
    _check_length(frames, fps, cfg, f"the schedule lasts {sum(steps) * step_s:.2f} s at pace 1; at pace {pace:g} "
                                    f"it plays in {frames / fps:.2f} s: lengthen the schedule or lower the pace")
    if steps[0] < t_in:
        raise GenerateError(f"the first schedule entry {entries[0].name!r} must last at least {t_in * step_s:.3g} s "
                            f"at pace 1 ({t_in} poses of real {entries[0].name!r} motion start the sequence)")
    seed_motion = fam.get("seed_motion", "data")
    if seed_motion not in ("data", "zeros"):
        raise GenerateError(f"glocal.seed_motion must be data or zeros, got {seed_motion!r}")
    seed_window = None
    warnings: list[str] = []
    if seed_motion == "data":
        wpath = data.rep_dir / "windows_glocal.parquet"
        if not wpath.exists():
            raise GenerateError(f"{data.rep_dir} has no glocal windows (seed motion); `dvc repro prepare@{g.cfg['dataset']['name']}`")
        w = pd.read_parquet(wpath)
        seq_split = w["sequence_id"].map(data.split).to_numpy()
        seq_label = data.meta["label"].to_numpy()[w["seq"].to_numpy()]
        for i, sp in enumerate(fam.get("seed_splits") or ["test"]):
            ws = w[seq_split == sp].reset_index(drop=True)
            hit = np.flatnonzero(seq_label[seq_split == sp] == entries[0].label)
            if len(hit):
                seed_window = (str(sp), int(hit[0]), str(ws["sequence_id"].iloc[hit[0]]))
                if i:
                    warnings.append(f"no {fam['seed_splits'][0]}-split sequence of {entries[0].name!r}: the seed motion "
                                    f"comes from the {sp} split ({seed_window[2]})")
                break
        if seed_window is None:
            raise GenerateError(f"no prepared sequence of class {entries[0].name!r} to start from; "
                                f"set glocal.seed_motion=zeros to start from the mean pose")
    return dict(fps=fps, frames=frames, entries=entries, steps=steps, classes=classes, k=k, M=M, t_in=t_in,
                pace=pace, seed_window=seed_window, warnings=warnings, stem="")


# ============================================================================ run

@dataclass
class Result:
    plan: Plan
    files: list[Path]
    positions: np.ndarray            # [N, T, J, 3] metres
    timings: dict[str, float]
    info: dict[str, Any]


def _load(info: RunInfo, cfg: dict):
    from .training.run import load_trained

    return load_trained(info.dir, _run_cfg_with_paths(info, cfg)["paths"])


def run(p: Plan) -> Result:
    """Load the model(s), generate, write the files."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(int(p.cfg["threads"]))
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    try:
        if p.family == "vae_lstm":
            model, train = _load(p.runs["vae_lstm"], p.cfg)
            timings["load_s"] = time.perf_counter() - t0
            t1 = time.perf_counter()
            positions, info = _generate_vae(p, model, train)
        else:
            glogen, train = _load(p.runs["glogen"], p.cfg)
            locgen, _ = _load(p.runs["locgen"], p.cfg)
            timings["load_s"] = time.perf_counter() - t0
            t1 = time.perf_counter()
            positions, info = _generate_glocal(p, glogen, locgen, train)
        timings["generate_s"] = time.perf_counter() - t1
    finally:
        torch.set_num_threads(threads)                  # process-wide state: give it back to a library caller
    files = write_outputs(p, positions, info, timings)
    return Result(p, files, positions, timings, info)


def generate(overrides: Seq[str] | Mapping = ()) -> Result:
    """The whole command: options (``key=value`` strings or a composed config dict) -> files."""
    cfg = dict(overrides) if isinstance(overrides, Mapping) else compose_config(overrides)
    return run(plan(cfg))


def _generate_vae(p: Plan, model, train) -> tuple[np.ndarray, dict]:
    import torch

    from .data.controls import integrate_controls, to_global

    T, ctrl = p.frames, p.controls
    f = int(getattr(model, "factor", 1))
    Tp = -(-T // f) * f
    c = np.concatenate([ctrl, np.repeat(ctrl[-1:], Tp - T, 0)]) if Tp > T else ctrl
    z = ((c - train.ctrl_mean) / train.ctrl_std).astype(np.float32)
    torch.manual_seed(int(p.cfg["seed"]))
    with torch.inference_mode():
        out = model.generate(None, torch.from_numpy(z)[None], length=Tp, num_samples=p.num_samples)[:, :T]
    local = train.norm.inverse(out.numpy().astype(np.float64))                   # [N, T, J, 3] root-relative
    root = integrate_controls(ctrl, p.fps, start=np.array([0.0, 0.0, p.start_heading]))   # [T, 3] x, z, heading
    glob = to_global(local, root)                                                 # [N, T, J, 3]
    info = {"controls": ctrl.astype(np.float32), "root": root.astype(np.float32),
            "path": p.path_name, "seed": int(p.cfg["seed"]), "start_heading_deg": math.degrees(p.start_heading)}
    return glob.astype(np.float32), info


def blend_seams(x: np.ndarray, seams: Seq[int], width: int) -> np.ndarray:
    """Remove the velocity jump at each seam pose ``q`` of ``x`` ``[n, F]`` (in increasing order):
    the excess ``(x[q] - x[q-1]) - (x[q-1] - x[q-2])`` is subtracted from ``x[q:]`` with a
    raised-cosine weight falling from 1 at ``q`` to 0 at ``q + width``, so pose ``q`` continues the
    previous velocity and later poses converge back to the generated ones."""
    x = x.copy()
    if width <= 0:
        return x
    w = 0.5 * (1 + np.cos(np.pi * np.arange(width) / width))                      # 1 .. ~0
    for q in sorted(seams):
        if q < 2 or q >= len(x):
            continue
        excess = (x[q] - x[q - 1]) - (x[q - 1] - x[q - 2])
        n = min(width, len(x) - q)
        x[q:q + n] -= w[:n, None] * excess
    return x


def seam_jumps(x: np.ndarray, at: Seq[int], window: int = 5) -> list[float]:
    """For each pose ``q`` in ``at``: the step into it, ``|x[q] - x[q-1]|``, over the median of the
    ``2 * window`` steps around it (1 = as smooth as the motion around it; a visible pop is
    several times that). Local, so it does not mistake a faster activity for a jump."""
    step = np.linalg.norm(np.diff(x, axis=0), axis=-1)                           # step[i] = |x[i+1] - x[i]|
    out = []
    for q in at:
        i = q - 1
        if not 0 <= i < len(step):
            continue
        near = np.r_[step[max(0, i - window):i], step[i + 1:i + 1 + window]]
        out.append(float(step[i] / max(float(np.median(near)) if len(near) else 1.0, 1e-12)))
    return out


def _generate_glocal(p: Plan, glogen, locgen, train) -> tuple[np.ndarray, dict]:
    import torch

    from .training.data import open_split

    J, D = train.spec.joints, train.spec.dims
    t = p.t_in
    ds_cfg = p.runs["glogen"].cfg["dataset"]
    if p.seed_window is not None:
        sp, idx, _ = p.seed_window
        wd = open_split(p.cfg["processed_dir"], p.cfg["splits_dir"], ds_cfg["name"], ds_cfg["training"], "glocal", sp)
        b = wd.batch(np.array([idx]))
        seed = b.pose[:, ::b.every][:, :t]
    else:
        seed = torch.zeros(1, t, J, D)
    bounds = np.cumsum([0, *p.steps])                 # entry e covers sparse poses [bounds[e], bounds[e+1])
    n_sparse = int(bounds[-1]) + 1                    # + the end keyframe of the last gap
    sparse, seams = seed, []
    with torch.inference_mode():
        for e, entry in enumerate(p.entries):         # one roll-out per entry: switches land exactly
            end = n_sparse if e == len(p.entries) - 1 else int(bounds[e + 1])
            start = sparse.shape[1]
            if end > start:
                out = glogen.generate(sparse[:, -t:], labels=torch.tensor([entry.label]), length=t + end - start)
                sparse = torch.cat([sparse, out[:, t:]], 1)
                seams += range(start, end, t)        # where GloGen starts a chunk
        x = sparse[0].reshape(n_sparse, -1).numpy().astype(np.float64)
        switches = [int(q) for q in bounds[1:-1]]
        g = p.cfg["glocal"]
        width = int(g.get("blend_poses") or 0)
        where = {"seams": seams, "switches": switches, "none": []}[g.get("blend_at", "seams")]
        chunk_only = [q for q in seams if q not in set(switches)]
        raw = seam_jumps(x, switches, t), seam_jumps(x, chunk_only, t)
        x_raw, x = x, blend_seams(x, where, width)
        fin = seam_jumps(x, switches, t), seam_jumps(x, chunk_only, t)
        xs = torch.from_numpy(x.astype(np.float32)).reshape(1, n_sparse, J, D)
        dense = locgen.generate(xs, M=p.M)[:, :p.frames]
    local = train.norm.inverse(dense.numpy().astype(np.float64))                 # [1, T, J, 3]
    sparse_labels = np.empty(n_sparse, np.int64)
    for e, entry in enumerate(p.entries):
        sparse_labels[bounds[e]:bounds[e + 1]] = entry.label
    sparse_labels[-1] = p.entries[-1].label
    frame_labels = sparse_labels[np.arange(p.frames) // (p.M + 1)]
    names = sorted(p.classes, key=p.classes.get)
    info = {"schedule": schedule_text(p.entries, p.steps, p.k, p.fps), "pace": p.pace,
            "effective_pace": p.k / (p.M + 1), "M": p.M, "k": p.k,
            "sparse": x.reshape(n_sparse, J, D).astype(np.float32),           # normalised keyframes (blended)
            "sparse_raw": x_raw.reshape(n_sparse, J, D).astype(np.float32),   # GloGen's output
            "labels": frame_labels, "class_names": np.array(names), "class_labels": np.array([p.classes[n] for n in names]),
            "switch_frames": np.array([q * (p.M + 1) for q in switches], np.int64),
            "switch_jump_raw": np.array(raw[0]), "switch_jump": np.array(fin[0]),
            "chunk_jump_raw": np.array(raw[1]), "chunk_jump": np.array(fin[1]),
            "blend_at": str(g.get("blend_at", "seams")) if width else "none", "blend_poses": width,
            "seed_motion": g.get("seed_motion"),
            "seed_sequence": p.seed_window[2] if p.seed_window else "", "root": np.zeros((p.frames, 3), np.float32)}
    return local.astype(np.float32), info


# ============================================================================ outputs

def write_outputs(p: Plan, positions: np.ndarray, info: dict, timings: dict) -> list[Path]:
    """BVH / GIF / MP4 / NPZ per character into ``p.out_dir``."""
    from .viz.bvh_export import dataset_scale, write_bvh

    p.out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    skel = p.data.skeleton
    N = len(positions)
    for i in range(N):
        stem = p.stem if N == 1 else f"{p.stem}_{i}"
        pos = positions[i]
        if "bvh" in p.formats:
            t = time.perf_counter()
            b = p.cfg["bvh"]
            files.append(write_bvh(p.out_dir / f"{stem}.bvh", pos, skel, p.fps, precision=int(b["precision"]),
                                   scale=dataset_scale(p.runs[next(iter(p.runs))].cfg["dataset"]),
                                   bone_tolerance=b.get("bone_tolerance")))
            timings["bvh_s"] = timings.get("bvh_s", 0.0) + time.perf_counter() - t
        if "npz" in p.formats:
            t = time.perf_counter()
            path = p.out_dir / f"{stem}.npz"
            extra = {k: (np.asarray(v) if v is not None else np.array("")) for k, v in info.items()}
            np.savez_compressed(path, positions=pos.astype(np.float32), fps=np.float32(p.fps),
                                joint_names=np.array(skel.names), parents=skel.parents, model=np.array(p.family),
                                dataset=np.array(p.dataset), runs=np.array([str(r.dir) for r in p.runs.values()]),
                                sample=np.int64(i), **extra)
            files.append(path)
            timings["npz_s"] = timings.get("npz_s", 0.0) + time.perf_counter() - t
        for fmt in ("gif", "mp4"):
            if fmt in p.formats:
                t = time.perf_counter()
                files.append(render_animation(p.out_dir / f"{stem}.{fmt}", pos, skel, p.fps, p, info,
                                              p.cfg[fmt], title=f"{p.stem}" + (f" #{i}" if N > 1 else "")))
                timings[f"{fmt}_s"] = timings.get(f"{fmt}_s", 0.0) + time.perf_counter() - t
    return files


def ffmpeg_path() -> str | None:
    """The ffmpeg binary MP4 output is encoded with (imageio-ffmpeg's bundled one, or
    ``$IMAGEIO_FFMPEG_EXE``: :func:`motionsynth.viz.animation.ffmpeg_exe`), None when there is none."""
    from .viz.animation import AnimationError, ffmpeg_exe

    try:
        return ffmpeg_exe()
    except AnimationError:
        return None


def render_animation(path: Path, pos: np.ndarray, skel, fps: float, p: Plan, info: dict, opts: Mapping,
                     title: str = "") -> Path:
    """A GIF (Pillow) or MP4 (H.264 through imageio-ffmpeg's ffmpeg) of one generated character:
    :func:`motionsynth.viz.animation.render_character` with this plan's view options (``gif:``
    in the config: size, palette, camera) and the format's ``fps`` / ``dpi`` (``opts``).

    Speed: the static figure is drawn once; each frame restores it and redraws only the moving
    artists (blitting, ~5 ms a frame), and GIF frames share one palette (no per-frame colour
    quantisation), so a 10 s GIF at 15 fps takes about a second."""
    from .viz.animation import render_character

    root_j = skel.index(skel.root) if skel.root else 0
    return render_character(path, pos, skel.parents, root_j, fps, p.family, info, p.cfg["gif"], opts, title=title,
                            pace=p.pace)


def summary_lines(res: Result) -> list[str]:
    """What the command prints on success."""
    p = res.plan
    t = res.timings
    lines = [f"generated {p.describe()}",
             f"  model load {t.get('load_s', 0):.2f} s, generation {t.get('generate_s', 0):.3f} s"
             + "".join(f", {k[:-2]} {v:.2f} s" for k, v in t.items() if k not in ("load_s", "generate_s"))]
    if p.family == "glocal":
        lines.append("  the character stays in place (GlocalNet generates root-relative poses, no trajectory)")
        if p.seed_window:
            lines.append(f"  starts from the real motion of {p.seed_window[2]} ({p.seed_window[0]} split)")
        i = res.info
        fmt = lambda v: ", ".join(f"{a:.2f}" for a in v)  # noqa: E731
        if len(i["switch_frames"]):
            lines.append("  class switches at " + ", ".join(f"{q / p.fps:.2f} s" for q in i["switch_frames"]))
        blended = i["blend_at"] != "none"
        lines.append(f"  smoothness (step into a pose / median of the steps around it; 1 = smooth): class switches {fmt(i['switch_jump_raw'])}"
                     + (f" -> {fmt(i['switch_jump'])}" if blended else "")
                     + (f"; GloGen chunk seams mean {np.mean(i['chunk_jump_raw']):.2f}"
                        + (f" -> {np.mean(i['chunk_jump']):.2f}" if blended else "") if len(i["chunk_jump_raw"]) else "")
                     + (f" (blended at {i['blend_at']} over {i['blend_poses']} poses)" if blended else " (no blending)"))
    for w in p.warnings:
        lines.append(f"  warning: {w}")
    lines.append("files:")
    lines += [f"  {f}" for f in res.files]
    return lines

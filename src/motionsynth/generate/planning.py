"""Checking and resolving every input into a :class:`Plan` before a model is loaded or a file
written."""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from .config import FAMILIES, FORMATS, GenerateError, _canon, _int, _number, _suggest
from .inputs import Entry, frames_per_step, parse_schedule, preset_controls, read_controls_csv, schedule_text
from .outputs import ffmpeg_path
from .runs import DataInfo, RunInfo, _data, _find_run, _hparams, _train_controls, class_names


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

"""What an animator asks for: a class schedule (GlocalNet), a control path from a CSV file or a
preset (VAE-LSTM), and the output pace."""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .config import SEGMENT_KEYS, GenerateError, _canon, _number, _suggest


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
    from ..data.controls import gaussian_smooth

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


def schedule_text(entries: list[Entry], steps: list[int], k: int, fps: float) -> str:
    return ",".join(f"{e.name}:{s * k / fps:g}s" for e, s in zip(entries, steps))


def frames_per_step(k: int, pace: float) -> int:
    """``M + 1``: the whole number of output frames per sparse step whose pace ``k / (M + 1)`` is
    nearest (as a ratio) to ``pace``; e.g. k = 5: pace 1 -> 5, 1.5 -> 3 (1.67), 2 -> 3 (1.67),
    2.5 -> 2, 0.5 -> 10."""
    x = k / pace
    lo, hi = max(1, math.floor(x)), max(1, math.ceil(x))
    return lo if abs(math.log(k / lo / pace)) <= abs(math.log(k / hi / pace)) else hi

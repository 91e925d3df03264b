"""The ``motionsynth`` command (``[project.scripts] motionsynth = "motionsynth.cli:main"``).

    motionsynth generate [key=value ...]     synthesise motion to BVH / GIF / NPZ (conf/generate.yaml)
    motionsynth generate --help              options and examples
    motionsynth ui [--port N]                browse the MLflow runs in a web browser (motionsynth/ui.py)

Input problems print one message (no traceback) and exit with code 2; unexpected failures exit
with 1 (set MOTIONSYNTH_DEBUG=1 for the traceback).
"""

from __future__ import annotations

import os
import sys
import textwrap
import traceback
from typing import Sequence

USAGE = """usage: motionsynth generate [key=value ...]
       motionsynth generate --help
       motionsynth ui [--port N] [--host 127.0.0.1] [--backend-store-uri URI]

commands:
  generate   make a motion clip with a trained model and write it as BVH (for animation
             tools), GIF (a quick look) and NPZ (joint positions for scripts)
  ui         start the MLflow UI on the project's runs and print its address (Ctrl-C stops it)
"""

GENERATE_HELP = """usage: motionsynth generate [key=value ...]

Makes a motion clip with a trained model and writes it into out_dir as
  <name>.bvh  skeleton animation (centimetres, like the Bandai source files) for Blender, Maya, MotionBuilder
  <name>.gif  a quick look: the character, and its path from above or its activity timeline
  <name>.npz  joint positions [frames, joints, 3] in metres, fps, joint names and the inputs used

Two kinds of model:

  model=vae_lstm   a character walks along a path (dataset bandai2_locomotion, 60 fps)
    path=NAME      a preset: {presets}
    path=FILE.csv  your own path: columns forward (m/s), sideways (m/s, + = left), turn (rad/s, + = left),
                   one row per frame at 60 fps, or add a time column (seconds) and rows are resampled
    num_samples=N  N different characters on the same path (one file set each)
    seed=S         another seed gives other characters

  model=glocal     a schedule of activities, played in place (dataset bandai1, 30 fps)
    schedule="walk:4s,run:3s,walk-left:3s"
                   class:seconds entries (seconds at normal pace); the last entry may leave out its
                   duration and fill up to seconds=. Classes of the trained model:
                   {classes}
    pace=P         2 = the same schedule twice as fast (half as long), 0.5 = half as fast ({pace_lo:g} to {pace_hi:g})

Common options:
  seconds=S        length of the output (at least {min_s:g} s; vae_lstm presets default to {vae_s:g} s)
  out_dir=DIR      where files go (default {out_dir}, relative to the current folder)
  name=STEM        file names (default: built from the inputs)
  formats=[bvh,gif,npz]   any of bvh, gif, npz, mp4 (mp4 needs ffmpeg)
  gif.fps=N        GIF frame rate (default {gif_fps:g}); fewer frames = faster to write
  dataset=NAME  vae_lstm.run=NAME  glocal.glogen_run=NAME  glocal.locgen_run=NAME
                   another trained model under models_dir/<dataset>/<run>/ (models_dir={models_dir})
  All options: conf/generate.yaml

Examples:
  motionsynth generate model=vae_lstm path=circle seconds=12
  motionsynth generate model=vae_lstm path=zigzag seconds=20 num_samples=3 out_dir=crowd
  motionsynth generate model=vae_lstm path=my_path.csv formats=[bvh]
  motionsynth generate model=glocal schedule="walk:4s,run:3s,walk-left:3s"
  motionsynth generate model=glocal schedule="walk:4s,bow:3s,walk" seconds=15 pace=1.5
"""


def _generate_help() -> str:
    from .generate import GenerateError, class_names, compose_config

    fill = {"presets": "straight, circle, zigzag, stop_and_go", "classes": "walk, run, walk-left, ... (see data)",
            "pace_lo": 0.25, "pace_hi": 5.0, "min_s": 10.0, "vae_s": 12.0, "out_dir": "outputs/generate",
            "gif_fps": 15, "models_dir": "models/"}
    try:
        cfg = compose_config([])
        fill.update(presets=", ".join(cfg["presets"]), pace_lo=cfg["glocal"]["pace_range"][0],
                    pace_hi=cfg["glocal"]["pace_range"][1], min_s=cfg["min_seconds"],
                    vae_s=cfg["vae_lstm"]["default_seconds"], out_dir=cfg["out_dir"], gif_fps=cfg["gif"]["fps"],
                    models_dir=cfg["models_dir"])
        try:  # the class names of the prepared data, when it is there
            from .generate import _data, _find_run

            info = _find_run(cfg, cfg["glocal"]["default_dataset"], cfg["glocal"]["glogen_run"], "glogen")
            names = ", ".join(class_names(_data(cfg, info)))
            fill["classes"] = "\n                   ".join(textwrap.wrap(names, 80))
        except GenerateError:
            pass
    except GenerateError:
        pass
    return GENERATE_HELP.format(**fill)


def _cmd_generate(args: list[str]) -> int:
    from .generate import GenerateError, compose_config, plan, run, summary_lines

    try:
        p = plan(compose_config(args))
    except GenerateError as e:
        print(f"motionsynth generate: {e}", file=sys.stderr)
        return 2
    print(f"generating {p.describe()} ...", flush=True)
    res = run(p)
    print("\n".join(summary_lines(res)))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (the console script exits with it)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        if args and args[1:2] == ["generate"]:
            print(_generate_help())
            return 0
        print(USAGE, file=sys.stdout if args else sys.stderr)
        return 0 if args else 2
    cmd, rest = args[0], args[1:]
    if cmd == "ui":
        from .ui import main as ui_main

        return ui_main(rest)
    if cmd != "generate":
        print(f"motionsynth: unknown command {cmd!r}\n\n{USAGE}", file=sys.stderr)
        return 2
    if any(a in ("-h", "--help", "help") for a in rest):
        print(_generate_help())
        return 0
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        return _cmd_generate(rest)
    except KeyboardInterrupt:
        print("motionsynth generate: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - an animator gets one line; developers set MOTIONSYNTH_DEBUG=1
        from .generate import GenerateError

        if isinstance(e, GenerateError):
            print(f"motionsynth generate: {e}", file=sys.stderr)
            return 2
        if os.environ.get("MOTIONSYNTH_DEBUG"):
            traceback.print_exc()
        print(f"motionsynth generate: internal error: {type(e).__name__}: {e}\n"
              f"(please report it; MOTIONSYNTH_DEBUG=1 shows the details)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

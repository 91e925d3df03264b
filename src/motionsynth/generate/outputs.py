"""Writing generated characters: BVH, NPZ, GIF and MP4 files, and the summary the command prints."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

import numpy as np

if TYPE_CHECKING:
    from .planning import Plan
    from .synthesis import Result


# ============================================================================ outputs

def write_outputs(p: Plan, positions: np.ndarray, info: dict, timings: dict) -> list[Path]:
    """BVH / GIF / MP4 / NPZ per character into ``p.out_dir``."""
    from ..viz.bvh_export import dataset_scale, write_bvh

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
    from ..viz.animation import AnimationError, ffmpeg_exe

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
    from ..viz.animation import render_character

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

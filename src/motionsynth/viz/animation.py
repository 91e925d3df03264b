"""Skeleton animations (GIF and MP4): side-by-side comparisons and the ``generate`` command's view.

Two figures share one renderer and one pair of writers:

* :func:`render_comparison` (the ``animate`` stage): one panel per method, ground truth first,
  every panel seen by the **same camera**; bones from ``parents``, a frame counter, method titles.
* :func:`render_character` (``motionsynth generate``): one character followed by the camera, with
  its root path from above (VAE-LSTM) or its activity timeline (GloGen + LocGen).

Speed (the whole evaluate + report + animate must fit in 5 minutes on 2 cores)
------------------------------------------------------------------------------
matplotlib's ``FuncAnimation`` + ``PillowWriter`` redraws the whole figure per frame (~40 ms a
panel). Here the static parts (axes, titles, ground line) are drawn **once**; per frame the canvas
restores that background and draws only the moving artists (:class:`Blitter`: one
``LineCollection`` per skeleton, one text), then hands the Agg buffer on. All screen coordinates
are projected for every frame at once, vectorised (:func:`project`, :func:`bone_segments`), so a
frame costs a few ms per panel. The motion is subsampled to ``fps`` output frames per second
(every ``round(source_fps / fps)``-th frame) and cut at ``max_seconds``. Each frame is rendered
once and streamed to both writers:

* **GIF**: Pillow, one palette for all frames (taken from the middle frame, no dithering): no
  per-frame colour quantisation search, and identical colours from frame to frame;
* **MP4**: H.264 (``libx264``, ``yuv420p``, CRF ``crf``) through the ffmpeg binary that
  ``imageio-ffmpeg`` bundles (:func:`ffmpeg_exe`; no system ffmpeg needed), frames piped in raw.

Camera (3-D)
------------
Orthographic, from azimuth ``azimuth_deg`` around the vertical (0: from +Z, the way the data's
characters face at the start; 90: from their left) and ``elevation_deg`` above the horizon:
screen x = ``p . r`` with ``r = (cos az, 0, -sin az)``, screen y = ``p . u`` with
``u = d x r`` (``d`` the unit vector towards the camera). ``follow`` places the camera's target:
``ground_truth`` (default) moves it with the ground truth's root over the floor, the same target
for every panel, so a model that walks off course is seen walking off (Table 1 of VAE-LSTM
measures exactly that); ``each`` follows each panel's own root (poses side by side regardless of
the path); ``fixed`` keeps it at the ground truth's mean root. A floor grid (``grid_m`` spacing)
is drawn under each character and moves with the floor, so walking does not look like walking in
place. Sizes (``half_width_m``, ``grid_m``) are metres for a person 1.7 m tall; when the ground
truth is not 1 to 2.5 units tall (data in other units, e.g. acLSTM's), the view is scaled by its
height and the "root ... from ground truth" labels count body heights. 2-D data (``space: 2d``,
image coordinates) is drawn as is with the image's y axis pointing down, all panels with the
ground truth's extent.

Measured (2 sequences of ground truth + 8 methods, 720 x 370 pixels, GIF + MP4, on a loaded
2-core machine): 1.0-2.7 s a sequence, 2.3-5.9 s a dataset (``index.json`` records it).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..data.types import MissingDataError

GROUND_TRUTH = "ground truth"


# ============================================================================ ffmpeg and writers

class AnimationError(RuntimeError):
    """An animation cannot be written (no ffmpeg, unknown format, bad input)."""


def ffmpeg_exe() -> str:
    """The ffmpeg binary to encode MP4 with: ``$IMAGEIO_FFMPEG_EXE`` if set, else the one bundled
    with ``imageio-ffmpeg`` (a project dependency). Raises :class:`AnimationError` when there is
    none or it does not exist."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise AnimationError("MP4 output needs the Python package imageio-ffmpeg (it bundles ffmpeg): "
                             "pip install imageio-ffmpeg") from None
    try:
        exe = imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as e:
        raise AnimationError(f"MP4 output needs ffmpeg: {e}") from None
    if os.sep in exe and not os.access(exe, os.X_OK):
        raise AnimationError(f"MP4 output needs ffmpeg, but {exe} (IMAGEIO_FFMPEG_EXE or imageio-ffmpeg's "
                             f"bundled binary) is not an executable file")
    return exe


def _even(frame: np.ndarray) -> np.ndarray:
    """H.264 in yuv420p needs even width and height: pad the last row / column by repetition."""
    h, w = frame.shape[:2]
    if h % 2 or w % 2:
        frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    return np.ascontiguousarray(frame)


def blend_palette(colors: Sequence[Any], levels: int = 14) -> np.ndarray:
    """A fixed GIF palette ``[<=256, 3] uint8`` for line drawings on white: each colour blended with
    white at ``levels`` strengths (the anti-aliased edges), so every frame keeps its exact colours."""
    from matplotlib.colors import to_rgb

    base = np.array([to_rgb(c) for c in colors])                                  # [C, 3] in 0..1
    a = np.linspace(1.0 / levels, 1.0, levels)[:, None, None]
    pal = (a * base[None] + (1 - a)) * 255                                         # [levels, C, 3]
    pal = np.unique(np.round(np.concatenate([[[255, 255, 255]], pal.reshape(-1, 3)])).astype(np.uint8), axis=0)
    if len(pal) > 256:
        raise AnimationError(f"a fixed palette holds at most 256 colours, got {len(pal)}")
    return pal


class VideoWriters:
    """Streams RGB frames ``[H, W, 3] uint8`` to any of ``.gif`` / ``.mp4`` paths at once.

    GIF palette, shared by all frames: ``palette`` (fixed ``[K, 3]`` uint8 colours, e.g.
    :func:`blend_palette`), else ``colors`` entries fitted to ``palette_frame`` (or the first frame)."""

    def __init__(self, paths: Sequence[Path], fps: float, palette_frame: np.ndarray | None = None, colors: int = 64,
                 crf: int = 23, palette: np.ndarray | None = None):
        self.paths = [Path(p) for p in paths]
        bad = [p for p in self.paths if p.suffix.lower() not in (".gif", ".mp4")]
        if bad:
            raise AnimationError(f"cannot write {bad[0].name}: animations are .gif or .mp4")
        self.fps = float(fps)
        self.crf = int(crf)
        self.colors = int(colors)
        self._palette = None
        self._palette_frame = palette_frame
        if palette is not None:
            from PIL import Image

            pal = np.asarray(palette, np.uint8).reshape(-1, 3)
            self._palette = Image.new("P", (1, 1))
            self._palette.putpalette(np.concatenate([pal, np.repeat(pal[-1:], 256 - len(pal), 0)]).ravel().tolist())
        self._gif: dict[Path, list] = {p: [] for p in self.paths if p.suffix.lower() == ".gif"}
        self._mp4: dict[Path, Any] = {}
        self.frames = 0
        for p in self.paths:
            p.parent.mkdir(parents=True, exist_ok=True)
        if any(p.suffix.lower() == ".mp4" for p in self.paths):
            self._exe = ffmpeg_exe()                # before any work: a clear error

    def _mp4_writer(self, path: Path, frame: np.ndarray):
        import imageio_ffmpeg

        h, w = frame.shape[:2]
        gen = imageio_ffmpeg.write_frames(str(path), (w, h), fps=self.fps, codec="libx264", pix_fmt_in="rgb24",
                                          pix_fmt_out="yuv420p", quality=None, macro_block_size=2,
                                          ffmpeg_log_level="error",
                                          output_params=["-crf", str(self.crf), "-preset", "veryfast",
                                                         "-movflags", "+faststart"])
        gen.send(None)
        return gen

    def add(self, frame: np.ndarray) -> None:
        frame = _even(np.asarray(frame, dtype=np.uint8)[..., :3])
        if self._gif:
            from PIL import Image

            im = Image.fromarray(frame)
            if self._palette is None:
                src = Image.fromarray(_even(np.asarray(self._palette_frame, np.uint8)[..., :3])) \
                    if self._palette_frame is not None else im
                self._palette = src.quantize(colors=self.colors)
            q = im.quantize(palette=self._palette, dither=Image.Dither.NONE)
            for frames in self._gif.values():
                frames.append(q)
        for p in self.paths:
            if p.suffix.lower() == ".mp4":
                if p not in self._mp4:
                    self._mp4[p] = self._mp4_writer(p, frame)
                self._mp4[p].send(frame)
        self.frames += 1

    def close(self) -> list[Path]:
        if not self.frames:
            raise AnimationError(f"no frames to write to {', '.join(p.name for p in self.paths)}")
        for p, frames in self._gif.items():
            frames[0].save(p, save_all=True, append_images=frames[1:], duration=round(1000 / self.fps), loop=0,
                           optimize=False)
        for gen in self._mp4.values():
            gen.close()
        return self.paths


class Blitter:
    """Draw a figure's static parts once, then per frame only the ``moving`` artists.

    ``moving``: ``(axes or figure, artist)`` pairs created with ``animated=True``."""

    def __init__(self, fig, moving: Sequence[tuple[Any, Any]]):
        self.fig = fig
        self.moving = list(moving)
        self.canvas = fig.canvas
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(fig.bbox)

    def frame(self) -> np.ndarray:
        """The current state as an RGB array (a copy)."""
        self.canvas.restore_region(self.background)
        for owner, artist in self.moving:
            owner.draw_artist(artist)
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def frame_indices(length: int, source_fps: float, out_fps: float, max_seconds: float | None = None) -> tuple[np.ndarray, int]:
    """Every ``step``-th frame (``step = round(source_fps / out_fps)``, at least 1) of the first
    ``max_seconds`` (all when None): ``(indices, step)``."""
    if length < 1:
        raise AnimationError("a motion to animate needs at least one frame")
    if not (source_fps > 0 and out_fps > 0):
        raise AnimationError(f"frame rates must be positive (source {source_fps}, output {out_fps})")
    step = max(1, round(source_fps / out_fps))
    end = length if not max_seconds else min(length, int(round(float(max_seconds) * source_fps)))
    return np.arange(0, max(end, 1), step), step


# ============================================================================ geometry

def camera_basis(azimuth_deg: float, elevation_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Screen-right and screen-up unit vectors of an orthographic camera (module docstring)."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    right = np.array([math.cos(az), 0.0, -math.sin(az)])
    toward = np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
    up = np.cross(toward, right)
    return right, up


def project(points: np.ndarray, space: str = "3d", azimuth_deg: float = 30.0, elevation_deg: float = 0.0) -> np.ndarray:
    """Points ``[..., D]`` -> screen coordinates ``[..., 2]`` (x right, y up). 3-D: the camera of
    :func:`camera_basis`; 2-D image coordinates: ``(x, -y)`` (the image's y points down)."""
    points = np.asarray(points, dtype=np.float64)
    if space == "2d":
        if points.shape[-1] != 2:
            raise AnimationError(f"2-D motion must have 2 coordinates per joint, got {points.shape[-1]}")
        return np.stack([points[..., 0], -points[..., 1]], -1)
    if space != "3d":
        raise AnimationError(f"space must be '3d' or '2d', got {space!r}")
    if points.shape[-1] != 3:
        raise AnimationError(f"3-D motion must have 3 coordinates per joint, got {points.shape[-1]}")
    right, up = camera_basis(azimuth_deg, elevation_deg)
    return np.stack([points @ right, points @ up], -1)


def bone_pairs(parents: Sequence[int]) -> np.ndarray:
    """``[B, 2]`` (child, parent) index pairs of a skeleton's bones (roots, parent -1, have none)."""
    parents = np.asarray(parents, dtype=np.int64)
    j = np.flatnonzero(parents >= 0)
    if len(j) and (parents[j] >= len(parents)).any():
        raise AnimationError(f"parents name joints beyond the {len(parents)} joints: {parents.tolist()}")
    return np.stack([j, parents[j]], 1)


def bone_segments(xy: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Screen joints ``[T, J, 2]`` -> bone segments ``[T, B, 2, 2]`` (vectorised over frames)."""
    return np.stack([xy[:, bones[:, 0]], xy[:, bones[:, 1]]], 2)


def root_joint(parents: Sequence[int]) -> int:
    roots = np.flatnonzero(np.asarray(parents) < 0)
    return int(roots[0]) if len(roots) else 0


# ============================================================================ side-by-side comparison

DEFAULTS: dict[str, Any] = {
    "fps": 15, "max_seconds": 10.0, "panel_in": [2.0, 2.4], "dpi": 72, "columns": 5, "colors": "fixed", "crf": 23,
    "azimuth_deg": 30.0, "elevation_deg": 12.0, "follow": "ground_truth", "half_width_m": 1.25, "grid_m": 0.5,
    "ghost": True, "margin": 0.08,
}


def _floor_grid(targets: np.ndarray, half: float, spacing: float, floor: float, az: float, el: float,
                extra: float = 1.0) -> np.ndarray:
    """Floor lines ``y = floor`` at multiples of ``spacing`` (X and Z) around each frame's camera
    target ``[T, 3]``, in screen coordinates relative to the target: ``[T, L, 2, 2]``."""
    reach = half + extra
    n = int(math.ceil(reach / spacing)) + 1
    offs = np.arange(-n, n + 1) * spacing                                        # [K]
    T = len(targets)
    segs = []
    for axis in (0, 2):                                                           # lines of constant X, of constant Z
        other = 2 - axis
        base = np.floor(targets[:, axis] / spacing) * spacing                     # [T]
        c = base[:, None] + offs[None, :]                                         # [T, K] line coordinates
        p0 = np.zeros((T, len(offs), 3))
        p1 = np.zeros((T, len(offs), 3))
        p0[..., axis] = p1[..., axis] = c
        p0[..., other] = targets[:, other, None] - reach
        p1[..., other] = targets[:, other, None] + reach
        p0[..., 1] = p1[..., 1] = floor
        rel0, rel1 = p0 - targets[:, None] * [1, 0, 1], p1 - targets[:, None] * [1, 0, 1]
        segs.append(np.stack([project(rel0, "3d", az, el), project(rel1, "3d", az, el)], 2))
    return np.concatenate(segs, 1)


def _fit_limits(ax, xlim: tuple[float, float], ylim: tuple[float, float], grow_up: bool) -> None:
    """Set limits that contain ``xlim`` x ``ylim`` at equal scale and fill the axes box exactly
    (the short side grows: y upwards from the floor when ``grow_up``, else about its centre)."""
    box = ax.get_window_extent()
    ratio = box.width / max(box.height, 1.0)
    (x0, x1), (y0, y1) = xlim, ylim
    w, h = x1 - x0, y1 - y0
    if w / h < ratio:                                          # too narrow: widen about the centre
        c, w = (x0 + x1) / 2, h * ratio
        x0, x1 = c - w / 2, c + w / 2
    else:                                                      # too flat: heighten
        h = w / ratio
        if grow_up:
            y1 = y0 + h
        else:
            c = (y0 + y1) / 2
            y0, y1 = c - h / 2, c + h / 2
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")


def render_comparison(paths: Sequence[Path], panels: Mapping[str, np.ndarray], parents: Sequence[int], fps: float,
                      space: str = "3d", opts: Mapping[str, Any] | None = None, title: str = "",
                      seed_frames: int = 0, units: str | None = None) -> dict[str, Any]:
    """Ground truth and every method side by side, written to ``paths`` (``.gif`` / ``.mp4``).

    ``panels``: method -> positions ``[T, J, D]`` (physical units: metres for 3-D, Y up; image
    coordinates for 2-D), the ground truth under ``"ground truth"`` (drawn first, in black);
    ``seed_frames``: the first frames every method was given (marked "seed" by the counter);
    ``units`` (3-D): ``"m"`` for metres; None: metres when the ground truth is 1 to 2.5 units tall,
    else the view is scaled to its height and distances are given in body heights.
    Methods may be shorter than the ground truth (they then hold their last pose). Returns
    ``{"frames", "step", "seconds", "panels", "render_s"}``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    t0 = time.perf_counter()
    o = {**DEFAULTS, **dict(opts or {})}
    if not panels:
        raise AnimationError("nothing to animate: no panels")
    names = sorted(panels, key=lambda n: (n != GROUND_TRUTH,))                    # ground truth first, rest in order
    arrays = {n: np.asarray(panels[n], dtype=np.float64) for n in names}
    J = len(parents)
    for n, a in arrays.items():
        if a.ndim != 3 or a.shape[1] != J:
            raise AnimationError(f"panel {n!r}: positions must be [frames, {J} joints, dims], got {list(a.shape)}")
    ref = arrays[GROUND_TRUTH] if GROUND_TRUTH in arrays else arrays[names[0]]
    T = max(len(a) for a in arrays.values())
    frames, step = frame_indices(T, fps, float(o["fps"]), o.get("max_seconds"))
    bones = bone_pairs(parents)
    rj = root_joint(parents)
    az, el = float(o["azimuth_deg"]), float(o["elevation_deg"])

    def at(a: np.ndarray) -> np.ndarray:                                          # the rendered frames of one panel
        return a[np.minimum(frames, len(a) - 1)]

    ref_f = at(ref)
    grid: dict[str, np.ndarray] = {}
    away: dict[str, np.ndarray] = {}                                              # [F] metres from the target
    if space == "3d":
        follow = str(o["follow"])
        if follow not in ("ground_truth", "each", "fixed"):
            raise AnimationError(f"follow must be ground_truth, each or fixed, got {follow!r}")
        floor = float(np.nanmin(ref[..., 1])) if np.isfinite(ref[..., 1]).any() else 0.0
        # the view is sized in metres for a 1.7 m person; data in other units (e.g. acLSTM's BVH units x 0.01)
        # is zoomed by its ground truth's height (vertical extent), so every dataset fills the panels alike
        height = float(np.subtract(*np.nanpercentile(ref[..., 1], [99.5, 0.5]))) if np.isfinite(ref[..., 1]).any() else 0
        metres = 1.0 < height < 2.5 if units is None else units == "m"
        scale = 1.0 if metres or height <= 0 else height / 1.7
        unit = "m" if metres else (units or "body heights")
        per_unit = 1.0 if (metres or units) else max(height, 1e-12)

        def target(a: np.ndarray) -> np.ndarray:                                  # [F, 3] camera target per frame
            if follow == "fixed":
                return np.repeat(np.nanmean(ref[:, rj], 0)[None] * [1, 0, 1], len(frames), 0)
            src = a if follow == "each" else ref_f
            return src[:, rj] * [1, 0, 1]

        xy = {n: project(at(a) - target(at(a))[:, None], "3d", az, el) for n, a in arrays.items()}
        half = float(o["half_width_m"]) * scale
        if follow == "fixed":
            span = np.nanpercentile(np.abs(xy[names[0]][..., 0]), 99) if len(xy) else half
            half = max(half, float(span) + 0.2 * scale)
        ys = project(np.array([[0, floor, 0]]), "3d", az, el)[0, 1]
        top = float(np.nanpercentile(xy[names[0]][..., 1], 99.5))
        ylim = (min(ys, float(np.nanmin(xy[names[0]][..., 1]))) - 0.15 * scale, top + 0.15 * scale)
        xlim = (-half, half)
        if follow == "ground_truth" and GROUND_TRUTH in arrays:      # how far each root is from the camera target
            gt_root = ref_f[:, rj] * [1, 0, 1]
            for n, a in arrays.items():
                if n != GROUND_TRUTH:
                    away[n] = np.linalg.norm(at(a)[:, rj] * [1, 0, 1] - gt_root, axis=-1)
        for n, a in arrays.items():
            if float(o.get("grid_m") or 0) > 0:
                grid[n] = _floor_grid(target(at(a)), half, float(o["grid_m"]) * scale, floor, az, el, extra=scale)
    else:
        xy = {n: project(at(a), "2d") for n, a in arrays.items()}
        pts = xy[names[0]].reshape(-1, 2)
        pts = pts[np.isfinite(pts).all(1)]
        lo, hi = np.percentile(pts, 0.5, 0), np.percentile(pts, 99.5, 0)
        pad = float(o["margin"]) * float(max(hi - lo))
        cx, cy = (lo + hi) / 2
        half_w, half_h = (hi - lo) / 2 + pad
        xlim, ylim = (cx - half_w, cx + half_w), (cy - half_h, cy + half_h)

    n_panels = len(names)
    cols = max(1, min(int(o["columns"]), n_panels))
    rows = int(math.ceil(n_panels / cols))
    pw, ph = (float(v) for v in o["panel_in"])
    dpi = int(o["dpi"])
    fig, axes = plt.subplots(rows, cols, figsize=(pw * cols, ph * rows + 0.35), dpi=dpi, squeeze=False)
    moving, colls = [], {}
    for k, ax in enumerate(axes.flat):
        ax.set_xticks([])
        ax.set_yticks([])
        if k >= n_panels:
            ax.axis("off")
            continue
        n = names[k]
        is_gt = n == GROUND_TRUTH
        ax.set_title(n, fontsize=8, fontweight="bold" if is_gt else "normal")
        for s in ax.spines.values():
            s.set_color("0.7")
        if n in grid:
            g = LineCollection([], colors="0.88", linewidths=0.6, animated=True)
            ax.add_collection(g)
            moving.append((ax, g))
            colls[(n, "grid")] = g
        if o["ghost"] and not is_gt and GROUND_TRUTH in arrays:
            gh = LineCollection([], colors="0.78", linewidths=1.6, animated=True)
            ax.add_collection(gh)
            moving.append((ax, gh))
            colls[(n, "ghost")] = gh
        lc = LineCollection([], colors="k" if is_gt else f"C{(k - 1) % 10}", linewidths=2.0, animated=True)
        ax.add_collection(lc)
        moving.append((ax, lc))
        colls[(n, "bones")] = lc
        if n in away:
            tx = ax.text(0.03, 0.03, "", transform=ax.transAxes, fontsize=7, color="0.3", animated=True)
            moving.append((ax, tx))
            colls[(n, "away")] = tx
    counter = fig.text(0.01, 0.995, "", va="top", ha="left", fontsize=8, family="monospace", animated=True)
    moving.append((fig, counter))
    if title:
        fig.suptitle(title, fontsize=9, x=0.99, ha="right", y=0.995, va="top")
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.3 / (ph * rows + 0.35)), pad=0.3, h_pad=0.4, w_pad=0.3)
    for ax in axes.flat[:n_panels]:
        _fit_limits(ax, xlim, ylim, grow_up=space == "3d")
    blit = Blitter(fig, moving)
    segs = {n: bone_segments(xy[n], bones) for n in names}
    gt_segs = segs.get(GROUND_TRUTH)
    seconds = T / fps

    def draw(i: int) -> np.ndarray:
        f = int(frames[i])
        for n in names:
            if (n, "grid") in colls:
                colls[(n, "grid")].set_segments(grid[n][i])
            if (n, "ghost") in colls:
                colls[(n, "ghost")].set_segments(gt_segs[i])
            colls[(n, "bones")].set_segments(segs[n][i])
            if (n, "away") in colls:
                d = away[n][i]
                colls[(n, "away")].set_text(f"root {d / per_unit:.1f} {unit} from ground truth" if d > 0.8 * half else "")
        counter.set_text(f"frame {f + 1:4d}/{T}  {f / fps:5.2f}/{seconds:.2f} s" + ("  seed" if f < seed_frames else ""))
        return blit.frame()

    try:
        mid = draw(len(frames) // 2)
        palette = blend_palette(["k", *[f"C{k}" for k in range(10)], "0.78", "0.88", "0.7", "0.3"]) \
            if o.get("colors") == "fixed" else None
        out = VideoWriters(paths, fps / step, palette_frame=mid, colors=int(o["colors"]) if palette is None else 0,
                           crf=int(o["crf"]), palette=palette)
        for i in range(len(frames)):
            out.add(draw(i))
        out.close()
    finally:
        plt.close(fig)
    return {"frames": len(frames), "step": step, "fps": fps / step, "seconds": len(frames) * step / fps,
            "panels": names, "size": list(mid.shape[1::-1]), "render_s": round(time.perf_counter() - t0, 3)}


# ============================================================================ the animate stage

def animate_samples(samples: Path, out_dir: Path, opts: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``data/samples/<ds>.npz`` (the ``evaluate`` stage's ``m:<method>`` arrays ``[N, T, J, D]``
    and ``meta`` JSON: ``fps``, ``parents``, ``space``, ``title``, ``seed_frames`` as one number or
    per method, optionally ``sequences`` / ``start_frames``) -> ``out_dir/seq<i>.gif`` / ``.mp4``
    (``opts["formats"]``) and ``out_dir/index.json`` (what was drawn, and how long it took)."""
    import json

    t0 = time.perf_counter()
    o = {**DEFAULTS, "formats": ["gif", "mp4"], "max_sequences": None, **dict(opts or {})}
    samples, out_dir = Path(samples), Path(out_dir)
    if not samples.exists():
        raise MissingDataError(f"{samples} is missing: the evaluate stage writes it "
                               f"(`dvc repro evaluate@{samples.stem}`)")
    formats = [str(f).lower().lstrip(".") for f in o["formats"]]
    if not formats or set(formats) - {"gif", "mp4"}:
        raise AnimationError(f"animate.formats must list gif and/or mp4, got {o['formats']!r}")
    with np.load(samples, allow_pickle=False) as d:
        meta = json.loads(str(d["meta"])) if "meta" in d.files else {}
        arrays = {k[2:]: d[k] for k in d.files if k.startswith("m:")}
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in [*out_dir.glob("seq*.gif"), *out_dir.glob("seq*.mp4"), out_dir / "index.json"]:
        old.unlink(missing_ok=True)
    ds = str(meta.get("dataset", samples.stem))
    index: dict[str, Any] = {"dataset": ds, "title": meta.get("title", ds), "space": meta.get("space", "3d"),
                             "source_fps": meta.get("fps"), "sequences": [], "options": o}
    if not arrays:
        index["total_s"] = round(time.perf_counter() - t0, 2)
        (out_dir / "index.json").write_text(json.dumps(index, indent=1, default=str) + "\n")
        return index
    missing = [k for k in ("fps", "parents") if k not in meta]
    if missing:
        raise AnimationError(f"{samples}: meta lacks {missing} (the evaluate suites pass them to ctx.sample)")
    fps, parents, space = float(meta["fps"]), list(meta["parents"]), str(meta.get("space", "3d"))
    seeds = meta.get("seed_frames") or 0
    names = sorted(arrays, key=lambda n: n != GROUND_TRUTH)
    n_seq = max(len(a) for a in arrays.values())
    if o.get("max_sequences") is not None:
        n_seq = min(n_seq, int(o["max_sequences"]))
    for i in range(n_seq):
        panels = {}
        for n in names:
            if i < len(arrays[n]):
                label = n
                if isinstance(seeds, Mapping) and n in seeds and n != GROUND_TRUTH:
                    label = f"{n} (seed {int(seeds[n])})"
                panels[label if n != GROUND_TRUTH else n] = arrays[n][i]
        paths = [out_dir / f"seq{i}.{f}" for f in formats]
        units = str(meta.get("units", "")).strip().lower()
        info = render_comparison(paths, panels, parents, fps, space, o, title=f"{ds} #{i}",
                                 seed_frames=int(seeds) if not isinstance(seeds, Mapping) else 0,
                                 units="m" if units in ("m", "metres", "meters") else None)
        source = ""
        if meta.get("sequences") and i < len(meta["sequences"]):
            source = str(meta["sequences"][i])
            if meta.get("start_frames") and i < len(meta["start_frames"]):
                source += f", from frame {meta['start_frames'][i]}"
        index["sequences"].append({"index": i, "gif": f"seq{i}.gif" if "gif" in formats else None,
                                   "mp4": f"seq{i}.mp4" if "mp4" in formats else None, "source": source, **info})
    index["total_s"] = round(time.perf_counter() - t0, 2)
    (out_dir / "index.json").write_text(json.dumps(index, indent=1, default=str) + "\n")
    return index


# ============================================================================ generate's character view

def render_character(path: Path, pos: np.ndarray, parents: Sequence[int], root_index: int, fps: float, family: str,
                     info: Mapping[str, Any], view: Mapping[str, Any], opts: Mapping[str, Any], title: str = "",
                     pace: float = 1.0) -> Path:
    """A GIF or MP4 of one generated character (``motionsynth generate``): seen from the
    front-right (``view.view_azimuth_deg``), followed by the camera (``view.follow_m`` half-width),
    and beside it the root path from above (``family="vae_lstm"``: ``info["root"]`` ``[T, 3]``
    ``x, z, heading``, ``info["controls"]``) or the activity timeline (``"glocal"``:
    ``info["labels"]``, ``class_labels``, ``class_names``). ``opts``: ``fps``, ``dpi`` of this
    format; ``view``: ``size_in``, ``colors``, ``follow_m``, ``view_azimuth_deg``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    path = Path(path)
    frames, step = frame_indices(len(pos), fps, float(opts["fps"]))
    uv = project(pos, "3d", float(view.get("view_azimuth_deg", 30.0)), 0.0)     # [T, J, 2]
    u, v = uv[..., 0], uv[..., 1]
    bones = bone_pairs(parents)
    half = float(view["follow_m"])
    ground = float(min(0.0, v.min()))
    height = max(float(np.percentile(v.max(1), 95)) + 0.2, ground + 2 * half * 0.5)

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=tuple(view["size_in"]), dpi=int(opts.get("dpi", 80)),
                                  gridspec_kw={"width_ratios": [1.2, 1]})
    lc = LineCollection([], colors="C0", linewidths=2.5, animated=True)
    ax.add_collection(lc)
    ax.axhline(ground, color="0.6", lw=1)
    ax.set_xlim(-half, half)
    ax.set_ylim(ground - 0.05, height)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xticks([])
    ax.set_ylabel("height (m)")
    label = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", fontsize=8, animated=True)
    moving: list[tuple[Any, Any]] = [(ax, lc), (ax, label)]
    if family == "vae_lstm":
        root = np.asarray(info["root"])
        ax2.plot(root[:, 0], root[:, 1], color="0.75", lw=1)
        trail, = ax2.plot([], [], color="C3", lw=1.5, animated=True)
        dot, = ax2.plot([], [], "o", color="C3", animated=True)
        arrow, = ax2.plot([], [], "-", color="k", lw=1.5, animated=True)
        moving += [(ax2, trail), (ax2, dot), (ax2, arrow)]
        span = max(float(np.ptp(root[:, 0])), float(np.ptp(root[:, 1])), 1.0)
        cx, cz = (root[:, 0].max() + root[:, 0].min()) / 2, (root[:, 1].max() + root[:, 1].min()) / 2
        ax2.set_xlim(cx + 0.6 * span, cx - 0.6 * span)          # +X (the character's left at the start) on the left
        ax2.set_ylim(cz - 0.6 * span, cz + 0.6 * span)
        ax2.set_aspect("equal")
        ax2.set_xlabel("X (m)", fontsize=8)
        ax2.set_ylabel("Z (m)", fontsize=8)
        ax2.set_title("path from above", fontsize=9)
    else:
        labels = np.asarray(info["labels"])
        names = dict(zip(np.asarray(info["class_labels"]).tolist(), np.asarray(info["class_names"]).tolist()))
        T = len(labels)
        edges = np.flatnonzero(np.diff(labels)) + 1
        for n, (a, b) in enumerate(zip(np.r_[0, edges], np.r_[edges, T])):
            ax2.barh(0, (b - a) / fps, left=a / fps, color=f"C{n % 10}", alpha=0.6)
            ax2.text((a + b) / 2 / fps, 0, names.get(int(labels[a]), "?"), ha="center", va="center", fontsize=8,
                     rotation=90 if (b - a) < 0.15 * T else 0)
        cursor = ax2.axvline(0, color="k", lw=2, animated=True)
        moving.append((ax2, cursor))
        ax2.set_xlim(0, T / fps)
        ax2.set_yticks([])
        ax2.set_xlabel("time (s)", fontsize=8)
        ax2.set_title(f"activities (pace {pace:g}, in place)", fontsize=9)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    blit = Blitter(fig, moving)
    segs = bone_segments(np.stack([u - u[:, root_index:root_index + 1], v], -1), bones)

    def draw(f: int) -> np.ndarray:
        lc.set_segments(segs[f])
        if family == "vae_lstm":
            c = info["controls"][f]
            label.set_text(f"{f / fps:5.2f} s   {c[0]:.2f} m/s" + (f", side {c[1]:+.2f}" if abs(c[1]) > 0.005 else "")
                           + f", turn {c[2]:+.2f} rad/s")
            trail.set_data(root[:f + 1, 0], root[:f + 1, 1])
            dot.set_data([root[f, 0]], [root[f, 1]])
            h = root[f, 2]
            arrow.set_data([root[f, 0], root[f, 0] + 0.1 * span * math.sin(h)],
                           [root[f, 1], root[f, 1] + 0.1 * span * math.cos(h)])
        else:
            label.set_text(f"{f / fps:5.2f} s  {names.get(int(labels[f]), '?')}")
            cursor.set_xdata([f / fps, f / fps])
        return blit.frame()

    try:
        mid = draw(int(frames[len(frames) // 2]))
        out = VideoWriters([path], fps / step, palette_frame=mid, colors=int(view.get("colors", 64)),
                           crf=int(opts.get("crf", 23)))
        for f in frames:
            out.add(draw(int(f)))
        out.close()
    finally:
        plt.close(fig)
    return path


# ============================================================================ reading back (tests, checks)

def read_gif(path: Path) -> tuple[int, np.ndarray]:
    """``(frame count, first frame RGB)`` of a GIF."""
    from PIL import Image

    with Image.open(path) as im:
        n = im.n_frames
        im.seek(0)
        first = np.asarray(im.convert("RGB"))
    return n, first


def read_mp4(path: Path) -> tuple[dict, list[np.ndarray]]:
    """``(meta, frames)`` of a video, decoded by imageio-ffmpeg's ffmpeg (RGB ``[H, W, 3]``)."""
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    w, h = meta["size"]
    frames = [np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in gen]
    return meta, frames


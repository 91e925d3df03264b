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
  bandai1 output: median 0.96, 90th percentile 1.9). By default (``glocal.blend_at=seams``;
  ``switches`` and ``none`` are the other choices) at every chunk start ``q`` the velocity change
  ``x[q] - 2 x[q-1] + x[q-2]`` is removed and faded back in over ``glocal.blend_poses`` (5) sparse
  poses with a raised-cosine weight: the pose at the seam continues the previous velocity, later
  poses converge to GloGen's (:func:`blend_seams`). Measured with the models of ``make run`` at
  ``566daa5`` (default profile), raw -> blended at seams:

  * cmu_aclstm ``indian:4s,martial:3s,salsa:3s``: switches 2.26 / 1.53 -> 1.18 / 1.05, chunk
    seams 2.14 -> 0.86 on average (90th percentile 2.94 -> 1.08): the pops are gone;
  * bandai1 ``walk:3s,bow:3s,run:3s,kick:3s``: switches 0.68 / 1.29 / 1.60 -> 1.29 / 1.45 / 0.98,
    seams 1.42 -> 1.20;
  * bandai1 ``walk:4s,run:3s,walk-left:3s``: switches 0.96 / 1.00 -> 1.75 / 1.00, seams
    1.17 -> 0.91.

  So blending removes real jumps but can roughen a switch that was already smooth: where the
  motion itself changes speed (walk -> run), the removed "velocity change" was the motion's own,
  and the pose after the seam lags, then catches up. ``blend_at=switches`` does the same there
  (0.96 -> 1.49); ``blend_at=none`` keeps GloGen's raw keyframes. Tried and not adopted, because
  each improved some seams and worsened others: blending only seams whose raw jump is above 1.25,
  measuring every seam's correction on the raw keyframes, removing the change of acceleration
  instead of the acceleration, and keeping a correction only where it lowers the jump. LocGen then
  fills in-betweens between the blended poses. The ratios before/after are printed and stored in
  the NPZ (``switch_jump_raw``, ``switch_jump``, ``chunk_jump_raw``, ``chunk_jump``; ``sparse_raw``
  / ``sparse`` hold the keyframes before/after, normalised).
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

Modules: :mod:`.config` (options and errors), :mod:`.inputs` (schedules, control paths, pace),
:mod:`.runs` (trained runs and their data), :mod:`.planning` (every check, before any work),
:mod:`.synthesis` (the models' roll-outs) and :mod:`.outputs` (files and the printed summary).
"""

from __future__ import annotations

from .config import FAMILIES, FORMATS, GenerateError, compose_config, quote_overrides, repo_root
from .inputs import Entry, frames_per_step, parse_schedule, preset_controls, read_controls_csv, schedule_text
from .outputs import ffmpeg_path, render_animation, summary_lines, write_outputs
from .planning import Plan, plan
from .runs import DataInfo, RunInfo, _data, _find_run, class_names
from .synthesis import Result, blend_seams, generate, run, seam_jumps

__all__ = ["FAMILIES", "FORMATS", "DataInfo", "Entry", "GenerateError", "Plan", "Result", "RunInfo", "blend_seams",
           "class_names", "compose_config", "ffmpeg_path", "frames_per_step", "generate", "parse_schedule", "plan",
           "preset_controls", "quote_overrides", "read_controls_csv", "render_animation", "repo_root", "run",
           "schedule_text", "seam_jumps", "summary_lines", "write_outputs", "_data", "_find_run"]

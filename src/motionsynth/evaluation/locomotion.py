"""Suite ``locomotion``: VAE-LSTM paper (Habibie et al. 2017), Tables 1 and 2, on the test split.

Our data: ``bandai2_locomotion`` (Bandai-Namco dataset 2, locomotion contents) stands in for the
paper's Edinburgh locomotion set, which is not available here: its config says so
(``evaluate.locomotion.compare_to``, the published dataset string its rows join). A dataset
without ``compare_to`` stands in for nothing: its rows get ``compare_to = "<ds> (ours)"``, tables
of their own, never joined with the published rows. Test windows are the
``vae_lstm`` family: 240 frames (4 s) at 60 fps, poses of 21 joints, root-relative and
facing-normalised (``pose``), the root trajectory ``(x, z, heading)`` and the controls
``(forward, sideways, turn)`` (:mod:`motionsynth.data.controls`). Windows: ``eval.max_windows``
evenly spaced test windows (:meth:`EvalContext.pick`), the same ones for every method; ``Row.n``.

What is measured
----------------
Both tables are errors at the frames ``70, 90, 120, 160, 210`` of the clip, counted 1-based
from its first frame (frame 70 = index 69 = the 10th frame after 60 seed frames), with
:func:`motionsynth.metrics.errors.prediction_error_values`, ``reduction="mse"``: per frame and
window, the **mean over the 21 joints of the squared 3-D distance** between predicted and
ground-truth joint positions, in **metres^2**; then the mean over windows (and, for VAE-LSTM,
the mean +- std over ``eval.seeds`` seeds of that mean, one sample per window and seed). The
paper says "mean squared error between generated joint positions and ground truth" and gives no
units; its Edinburgh numbers are therefore not comparable in absolute value with ours (only the
ordering of methods and the growth over frames are).

* **Table 1, "motion prediction error"**: global joint positions, ``to_global(pose, root)``.

  - *Baselines*: every next-frame model with the shared roll-out interface
    (:func:`rolls_out`: a ``rollout(seed, controls, labels, length)`` returning pose and controls,
    a ``control_mode`` and ``seed_frames``, :mod:`motionsynth.models.recurrent`): ERD, LSTM-3LR,
    cRBM CD-1, cRBM CD-15 (the paper's rows, in its order), then Seq2Seq, acLSTM, Scheduled
    Sampling; their plain runs, ``control_mode: predict``. Given the first ``seed_frames`` (60)
    ground-truth frames, pose and controls, they roll out pose AND controls; the predicted
    controls of frames ``S..T-1`` are de-normalised with the train statistics and integrated
    (:func:`~motionsynth.data.controls.integrate_controls`) from the ground-truth root at the
    last seed frame ``S-1``. The step ``S-1 -> S`` uses the seed's control of frame ``S-1``,
    which is ground truth (controls are forward differences of the root, so that one step is
    exact: a one-frame look-ahead inherited from the control definition and from what the
    models are given as seed). Frames before ``S`` keep the ground-truth root. Condition:
    "60 initial frames; no control".
  - *VAE-LSTM*: with 4 initial frames (``z_1`` from the posterior of the first pooled step,
    "4 initial frames; control") and with none (``z_1`` from the prior, method
    "VAE-LSTM (prior sample)", "0 initial frames; control"), driven by the ground-truth
    controls of all 240 frames. Its output is a local pose only; its **trajectory is the
    ground-truth root** (option ``vae_trajectory: ground_truth``, the default). Reason:
    integrating the ground-truth controls from the ground-truth root at frame 0 reproduces
    the ground-truth root exactly (measured: < 1e-12 m^2 at every table frame) on windows
    inside a sequence, but windows over sequences shorter than 240 frames are padded with
    the last frame (the paper's padding, ``pad: end``), where the root stands still while
    the stored controls repeat the last frame's velocity; integrating them there charges
    the method with a data artefact (0.77 m^2 at frame 210 averaged over our test windows,
    with the ground-truth pose). ``vae_trajectory: integrate`` gives the other choice.
    Consequence: with the same root and heading for prediction and ground truth, VAE-LSTM's
    motion error is the facing-normalised pose error *without* subtracting the hips (the
    squared distance is rotation invariant), so it differs from its Table-2 number only by
    the hip position error.
  - *Zero-velocity* (``kind="reference"``): repeats the last of the 60 seed poses; it
    predicts no controls, so its root **stands still** at the ground-truth root (position
    and heading) of the last seed frame. "60 initial frames; no control".
  - *Mean pose* (``kind="reference"``): the train split's mean pose after the 60 seed frames
    (:mod:`motionsynth.models.mean_pose`), its root held as zero-velocity's: the error of a
    model that has collapsed to the mean. Table 2: after the 4th frame.

* **Table 2, "pose prediction error (root-relative)"**: every model is given the ground-truth
  controls; the error ignores translation and rotation: our prepared poses are already
  facing-normalised, and ``kind="pose"`` subtracts each frame's root joint (``Hips``, the
  paper's origin "at the hip of the character") from prediction and ground truth.
  Baselines: the ``<model>-controls_given`` runs of the same models (``control_mode: given``,
  their ``seed_frames`` = 4, "4 initial frames; control"); VAE-LSTM from 4 and 0 frames (the same
  samples as Table 1, per seed); Zero-velocity repeats the 4th frame
  (``pose_seed_frames``, "4 initial frames; no control").

Stochastic vs deterministic: VAE-LSTM draws ``z_1`` (prior or posterior): mean +- std over
``ctx.seeds`` (``torch`` seeded with each seed before each generation). For the baselines it is
measured, not declared (:func:`is_stochastic`: the first ``stochastic_check_windows`` windows
rolled out under two seeds): the cRBM samples its hidden units at every Gibbs step, so its rows
are the mean +- std over ``ctx.seeds`` (at most ``stochastic_seeds`` of them), one roll-out per
window and seed, ``torch`` seeded before each; the recurrent baselines and zero-velocity are
deterministic: one value, ``std`` NaN. The paper gives one number per cell and no seeds.
Cost (measured on the quiet 2-core machine, 256 windows, 5 seeds): a cRBM run adds 14 s (Table 1,
180 frames x 30 Gibbs steps per frame) to 18 s (Table 2, 236 frames) to the suite (the four cRBM
runs 62 s; all the other runs together 6 s); bandai2_locomotion sets ``stochastic_seeds: 2``, which
cuts that by more than half (the spread over seeds of the cRBM's error is tiny at our budget: its hidden units move the
roll-out little, see :mod:`motionsynth.models.crbm`).

Outputs
-------
Rows ``Table 1`` / ``Table 2`` with the published ``metric`` / ``column`` / ``method`` strings
(``compare_to`` = the paper's dataset string), keys ``table1_motion/frame70`` ...
``table2_pose/frame210``; curves ``motion_error_vs_frame`` and ``pose_error_vs_frame`` (every
frame 1..240, mean over windows and seeds); animation samples: the first
``eval.animation.sequences`` picked windows, ground truth and every Table-1 method (VAE-LSTM:
the first seed; the cRBM: its first seed too) in global positions (metres) ``[N, 240, 21, 3]``.
Within each table the rows follow the papers' order: the baselines (:data:`BASELINE_ORDER`),
VAE-LSTM, then the references.

Options (``conf/dataset/<ds>.yaml: evaluate.locomotion``): ``family`` (window family,
``vae_lstm``), ``frames``, ``reduction`` (see errors.py), ``vae_trajectory``
(``ground_truth`` | ``integrate``), ``pose_seed_frames`` (Table-2 zero-velocity seed, 4),
``compare_to`` (the published dataset this one stands in for; none: ``"<ds> (ours)"``),
``stochastic_check_windows`` (windows of the stochasticity check, 4), ``stochastic_seeds`` (at most
this many of ``eval.seeds`` for a stochastic baseline; none: all).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch

from ..data.controls import integrate_controls, to_global
from ..data.types import Skeleton
from ..metrics.errors import REDUCTIONS, VAE_LSTM_FRAMES, prediction_error_values
from ..models.base import Batch, one_thread
from ..models.mean_pose import MeanPose
from ..models.recurrent import CONTROL_MODES
from ..models.zero_velocity import ZeroVelocity
from .context import EvalContext

log = logging.getLogger(__name__)

PAPER = "habibie2017_vae_lstm"
T1 = {"table": "Table 1", "metric": "motion prediction error", "key": "table1_motion", "curve": "motion_error_vs_frame"}
T2 = {"table": "Table 2", "metric": "pose prediction error (root-relative)", "key": "table2_pose",
      "curve": "pose_error_vs_frame"}
#: row order of the baselines: the VAE-LSTM paper's (ERD, LSTM-3LR, cRBM CD-1, CD-15), then ours beyond it;
#: other next-frame models of the dataset follow by name
BASELINE_ORDER = ("erd", "lstm3lr", "crbm", "crbm_cd15", "seq2seq", "aclstm", "scheduled_sampling")
#: windows rolled out under two seeds to tell a stochastic baseline (option stochastic_check_windows)
STOCHASTIC_CHECK_WINDOWS = 4
OPTIONS = ("family", "frames", "reduction", "vae_trajectory", "pose_seed_frames", "compare_to",
           "stochastic_check_windows", "stochastic_seeds")
VAE, ZERO = "vae_lstm", "zero_velocity"
TRAJECTORIES = ("ground_truth", "integrate")
UNITS = {"mse": "m^2", "mse_coord": "m^2", "rmse": "m", "mpjpe": "m", "l2": "m"}
REDUCTION_WORDS = {"mse": "mean over joints of the squared 3-D joint distance",
                   "mse_coord": "mean over joints and coordinates of the squared coordinate difference",
                   "rmse": "root of the mean over joints of the squared 3-D joint distance",
                   "mpjpe": "mean over joints of the 3-D joint distance",
                   "l2": "norm of the whole pose-vector difference"}


# ============================================================================ pieces (array level)

def root_from_controls(gt_root: np.ndarray, controls: np.ndarray, fps: float, seed_frames: int) -> np.ndarray:
    """``[B, T, 3]``: the ground-truth root for frames ``0..S-1``, then ``controls`` (physical)
    integrated from the ground-truth root of frame ``S-1`` (``S = seed_frames >= 1``)."""
    S = int(seed_frames)
    if not 1 <= S <= gt_root.shape[1]:
        raise ValueError(f"seed_frames must be in 1..{gt_root.shape[1]}, got {seed_frames}")
    tail = integrate_controls(controls[:, S - 1:], fps, gt_root[:, S - 1])
    return np.concatenate([gt_root[:, :S - 1], tail], axis=1)


def held_root(gt_root: np.ndarray, seed_frames: int) -> np.ndarray:
    """``[B, T, 3]``: the ground-truth root up to frame ``S-1``, then standing still there."""
    S = int(seed_frames)
    if not 1 <= S <= gt_root.shape[1]:
        raise ValueError(f"seed_frames must be in 1..{gt_root.shape[1]}, got {seed_frames}")
    out = np.array(gt_root, np.float64, copy=True)
    out[:, S:] = out[:, S - 1:S]
    return out


def motion_error(pred_pose: np.ndarray, pred_root: np.ndarray, gt_pose: np.ndarray, gt_root: np.ndarray,
                 frames: Any, reduction: str = "mse") -> np.ndarray:
    """Table 1 per window, ``[B, F]``: the error of the global positions ``to_global(pose, root)``
    (physical root-relative poses ``[B, T, J, 3]``, roots ``[B, T, 3]``) at 1-based ``frames``."""
    for name, pose, root in (("pred", pred_pose, pred_root), ("gt", gt_pose, gt_root)):
        if np.ndim(pose) != 4 or np.shape(pose)[-1] != 3 or np.shape(root) != np.shape(pose)[:2] + (3,):
            raise ValueError(f"motion_error: {name} pose must be [B, T, J, 3] and its root [B, T, 3], "
                             f"got {np.shape(pose)} and {np.shape(root)}")
    return prediction_error_values(to_global(pred_pose, pred_root), to_global(gt_pose, gt_root), frames,
                                   "motion", reduction=reduction)


def pose_error(pred_pose: np.ndarray, gt_pose: np.ndarray, frames: Any, root_index: int,
               reduction: str = "mse") -> np.ndarray:
    """Table 2 per window, ``[B, F]``: the error of the (facing-normalised) poses relative to each
    frame's ``root_index`` joint, at 1-based ``frames``; no trajectory enters."""
    return prediction_error_values(pred_pose, gt_pose, frames, "pose", root_index=root_index, reduction=reduction)


# ============================================================================ the suite

class _Table:
    """Collects one table's per-method results (rows + curve)."""

    def __init__(self, ctx: EvalContext, spec: dict, frames: list[int], n: int, note_tail: str, compare_to: str):
        self.ctx, self.spec, self.frames, self.n, self.note_tail = ctx, spec, frames, n, note_tail
        self.compare_to = compare_to

    def add(self, method: str, per_seed: list[np.ndarray], *, condition: str, run: str, note: str,
            kind: str = "model", stochastic: bool | None = None) -> None:
        """``per_seed``: one ``[B, T]`` per-window, per-frame array per seed (one for deterministic);
        ``stochastic``: whether the method samples (default: more than one array)."""
        curves = np.stack([v.mean(axis=0) for v in per_seed])                  # [seeds, T]
        common = dict(paper=PAPER, table=self.spec["table"], compare_to=self.compare_to, metric=self.spec["metric"],
                      method=method, condition=condition, n=self.n, run=run, kind=kind)
        stochastic = len(per_seed) > 1 if stochastic is None else bool(stochastic)
        how = (("stochastic: mean +- std over seeds" if len(per_seed) > 1 else "stochastic: one seed")
               if stochastic else "deterministic")
        for f in self.frames:
            kw = dict(common, column=f"frame{f}", key=f"{self.spec['key']}/frame{f}",
                      note=f"{note}; {how}; {self.note_tail}")
            if stochastic:
                self.ctx.add_seeds(curves[:, f - 1], **kw)
            else:
                self.ctx.add(value=float(curves[0, f - 1]), **kw)
        self.ctx.curve(self.spec["curve"], method, range(1, curves.shape[1] + 1), curves.mean(axis=0))


def _options(ctx: EvalContext) -> dict[str, Any]:
    o = dict(ctx.options.get("locomotion") or {})
    unknown = set(o) - set(OPTIONS)
    if unknown:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.locomotion has unknown option(s) {sorted(unknown)}")
    opts = {"family": o.get("family", ctx.dataset_cfg["training"].get("family", "vae_lstm")),
            "frames": [int(f) for f in o.get("frames", VAE_LSTM_FRAMES)],
            "reduction": o.get("reduction", "mse"),
            "vae_trajectory": o.get("vae_trajectory", "ground_truth"),
            "pose_seed_frames": int(o.get("pose_seed_frames", 4)),
            "compare_to": o.get("compare_to"),
            "stochastic_check_windows": o.get("stochastic_check_windows", STOCHASTIC_CHECK_WINDOWS),
            "stochastic_seeds": o.get("stochastic_seeds")}
    if opts["reduction"] not in REDUCTIONS:
        raise ValueError(f"evaluate.locomotion.reduction must be one of {REDUCTIONS}, got {opts['reduction']!r}")
    if opts["vae_trajectory"] not in TRAJECTORIES:
        raise ValueError(f"evaluate.locomotion.vae_trajectory must be one of {TRAJECTORIES}, "
                         f"got {opts['vae_trajectory']!r}")
    if not opts["frames"] or min(opts["frames"]) < 1:
        raise ValueError(f"evaluate.locomotion.frames must be 1-based frame numbers, got {opts['frames']}")
    for name, optional in (("stochastic_check_windows", False), ("stochastic_seeds", True)):
        v = opts[name]
        if (v is not None or not optional) and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise ValueError(f"evaluate.locomotion.{name} must be an integer >= 1{' or null' if optional else ''}, "
                             f"got {v!r}")
    return opts


def _references(ctx: EvalContext) -> list[str]:
    """Trained plain runs of the trivial predictors (zero-velocity, the mean pose: ``ZeroVelocity`` and
    its subclasses), zero-velocity first."""
    runs = [r for r in ctx.available(variant=None) if isinstance(ctx.model(r)[0], ZeroVelocity)]
    return sorted(runs, key=lambda r: (ctx.runs[r] != ZERO, r))


def rolls_out(model: Any) -> bool:
    """Whether ``model`` is a next-frame model with the shared roll-out interface
    (:mod:`motionsynth.models.recurrent`): ``rollout(seed, controls, labels, length) -> (pose, controls)``,
    a ``control_mode`` (``predict`` | ``given``) and ``seed_frames``. The recurrent baselines and the
    cRBM are; VAE-LSTM, zero-velocity and the mean pose are not."""
    return (callable(getattr(model, "rollout", None)) and getattr(model, "control_mode", None) in CONTROL_MODES
            and hasattr(model, "seed_frames"))


def _baselines(ctx: EvalContext, variant: str | None) -> list[str]:
    """Trained runs of ``variant`` whose model :func:`rolls_out` (papers' order first, :data:`BASELINE_ORDER`)."""
    models = sorted({m for m in ctx.runs.values() if m not in (VAE, ZERO)},
                    key=lambda m: (BASELINE_ORDER.index(m) if m in BASELINE_ORDER else len(BASELINE_ORDER), m))
    return [run for m in models for run in ctx.available(m, variant) if rolls_out(ctx.model(run)[0])]


def roll(ctx: EvalContext, model: Any, batch: Batch, S: int, length: int, seed: int | None = None):
    """``model.rollout`` of ``batch`` from its first ``S`` frames to ``length`` (normalised pose
    ``[B, length, J, D]`` and controls ``[B, length, 3]``), on one thread, ``torch`` seeded with ``seed``."""
    if seed is not None:
        ctx.torch_seed(seed)
    with one_thread(ctx.device):
        return model.rollout(batch.pose[:, :S], batch.controls, batch.labels, length=length)


def is_stochastic(ctx: EvalContext, model: Any, batch: Batch, S: int, length: int, windows: int) -> bool:
    """Whether ``model``'s roll-out from ``S`` seed frames differs between two seeds on the first
    ``windows`` windows of ``batch`` (:meth:`EvalContext.is_stochastic`)."""
    return ctx.is_stochastic(lambda b, seed: roll(ctx, model, b, S, length, seed)[0], batch, windows)


def run(ctx: EvalContext) -> None:
    opts = _options(ctx)
    frames, red = opts["frames"], opts["reduction"]
    data = ctx.data(opts["family"], "test")
    if data.controls is None:
        raise ValueError(f"{ctx.name}: the locomotion suite needs control signals (training.controls: true)")
    if data.rep.get("space") != "3d":
        raise ValueError(f"{ctx.name}: the locomotion suite needs 3-D positions, got space={data.rep.get('space')!r}")
    T, fps = data.length, float(data.rep["fps"])
    if max(frames) > T:
        raise ValueError(f"{ctx.name}: frames {frames} need windows of >= {max(frames)} frames; "
                         f"the {opts['family']} windows hold {T}")
    if abs(fps - 60.0) > 1e-6:
        log.warning("%s: the paper's frame numbers are at 60 fps; these windows are at %g fps", ctx.name, fps)
    rep = ctx.dataset_cfg["training"]["representation"]
    skel = Skeleton.load(ctx.paths["processed"] / ctx.name / rep / "skeleton.json")
    if skel.num_joints != data.pose.shape[1]:
        raise ValueError(f"skeleton.json has {skel.num_joints} joints, the poses {data.pose.shape[1]}")
    root_j = skel.index(skel.root) if skel.root else 0

    idx = ctx.pick(data, ctx.opts.get("max_windows"))
    n = len(idx)
    if n == 0:
        raise ValueError(f"{ctx.name}: no {opts['family']} test windows")
    raw = ctx.raw(data, idx)
    batch = data.batch(idx).to(ctx.device)
    gt_pose, gt_root = raw["pose"], raw["root"]
    all_frames = list(range(1, T + 1))
    n_anim = min(int(ctx.opts.get("animation", {}).get("sequences", 0)), n)
    samples: dict[str, np.ndarray] = {}
    seed_of: dict[str, int] = {}

    unit = UNITS[red]
    compare_to = opts["compare_to"] or f"{ctx.name} (ours)"
    role = f"stand-in for {opts['compare_to']}" if opts["compare_to"] else "no published counterpart"
    tail = (f"{REDUCTION_WORDS[red]} (errors.py reduction '{red}'), {unit}; mean over {n} test windows of "
            f"{ctx.name} ({T} frames at {fps:g} fps, {role}); frame = 1-based frame of "
            f"the clip; the paper does not state its units: absolute values are not comparable with its numbers")
    t1 = _Table(ctx, T1, frames, n, "global positions; " + tail, compare_to)
    t2 = _Table(ctx, T2, frames, n, f"positions relative to the {skel.root or 'root'} joint, facing-normalised; "
                + tail, compare_to)

    def motion(pose_phys, root):
        return motion_error(pose_phys, root, gt_pose, gt_root, all_frames, red)

    def pose(pose_phys):
        return pose_error(pose_phys, gt_pose, all_frames, root_j, red)

    def baseline_seeds(model, S: int) -> tuple[list[int], bool]:
        """The seeds a baseline is rolled out under: all evaluation seeds (at most ``stochastic_seeds``)
        when it samples, else the first."""
        if not is_stochastic(ctx, model, batch, S, T, opts["stochastic_check_windows"]):
            return ctx.seeds[:1], False
        k = opts["stochastic_seeds"]
        return (ctx.seeds if k is None else ctx.seeds[:k]), True

    def seeds_note(seeds: list[int], stochastic: bool) -> str:
        return f"; one roll-out per window and seed {seeds}" if stochastic else ""

    # ---------------------------------------------------------------- Table 1 baselines: own controls
    for r in _baselines(ctx, None):
        model, train = ctx.model(r)
        if not model.predict_controls:
            raise ValueError(f"run {r}: Table 1 needs control_mode 'predict' (plain run), got {model.control_mode!r}")
        S = int(model.seed_frames)
        label = ctx.label(ctx.runs[r])
        seeds, stochastic = baseline_seeds(model, S)
        m1 = []
        for i, s in enumerate(seeds):
            z, c = roll(ctx, model, batch, S, T, s)
            p = ctx.physical(train, z)
            ctrl = c.detach().cpu().numpy().astype(np.float64) * train.ctrl_std + train.ctrl_mean
            root = root_from_controls(gt_root, ctrl, fps, S)
            m1.append(motion(p, root))
            if i == 0 and n_anim:
                samples[label], seed_of[label] = to_global(p[:n_anim], root[:n_anim]), S
        t1.add(label, m1, condition=f"{S} initial frames; no control", run=r, stochastic=stochastic,
               note=f"own predicted controls integrated from the ground-truth root of frame {S}"
                    + seeds_note(seeds, stochastic))

    # ---------------------------------------------------------------- Table 2 baselines: controls given
    for r in _baselines(ctx, "controls_given"):
        model, train = ctx.model(r)
        if not model.given_controls:
            raise ValueError(f"run {r}: Table 2 needs control_mode 'given', got {model.control_mode!r}")
        S = int(model.seed_frames)
        if S != opts["pose_seed_frames"]:
            log.warning("%s: run %s has seed_frames=%d, Table 2's protocol is %d", ctx.name, r, S,
                        opts["pose_seed_frames"])
        seeds, stochastic = baseline_seeds(model, S)
        m2 = [pose(ctx.physical(train, roll(ctx, model, batch, S, T, s)[0])) for s in seeds]
        t2.add(ctx.label(ctx.runs[r]), m2, condition=f"{S} initial frames; control", run=r, stochastic=stochastic,
               note="ground-truth controls as input at every step" + seeds_note(seeds, stochastic))

    # ---------------------------------------------------------------- VAE-LSTM: ground-truth controls
    for r in ctx.available(VAE, None):
        model, train = ctx.model(r)
        label = ctx.label(VAE)
        g = model.factor
        for S, method, how in ((g, label, f"z_1 from the posterior of frames 1-{g}"),
                               (0, f"{label} (prior sample)", "z_1 from the prior")):
            seed = batch.pose[:, :S] if S else None
            m1, m2 = [], []
            for i, s in enumerate(ctx.seeds):
                ctx.torch_seed(s)
                p = ctx.physical(train, model.generate(seed, batch.controls, length=T))
                if opts["vae_trajectory"] == "ground_truth":
                    root = gt_root
                else:
                    ctrl = batch.controls.cpu().numpy().astype(np.float64) * train.ctrl_std + train.ctrl_mean
                    root = root_from_controls(gt_root, ctrl, fps, 1)
                m1.append(motion(p, root))
                m2.append(pose(p))
                if i == 0 and n_anim:
                    samples[method], seed_of[method] = to_global(p[:n_anim], root[:n_anim]), S
            traj = ("trajectory: the ground-truth root" if opts["vae_trajectory"] == "ground_truth"
                    else "trajectory: ground-truth controls integrated from the ground-truth root of frame 1")
            t1.add(method, m1, condition=f"{S} initial frames; control", run=r,
                   note=f"{how}, ground-truth controls; {traj}; one sample per window and seed")
            t2.add(method, m2, condition=f"{S} initial frames; control", run=r,
                   note=f"{how}, ground-truth controls; one sample per window and seed")

    # ---------------------------------------------------------------- zero-velocity, the mean pose (references)
    for r in _references(ctx):
        model, train = ctx.model(r)
        label = ctx.label(ctx.runs[r])
        what = (f"the train split's mean pose after frame {{S}}" if isinstance(model, MeanPose)
                else "repeats the pose of frame {S}")
        S = int(model.seed_frames)
        p = ctx.physical(train, model.generate(batch.pose[:, :S], length=T))
        root = held_root(gt_root, S)
        t1.add(label, [motion(p, root)], condition=f"{S} initial frames; no control", run=r, kind="reference",
               note=f"{what.format(S=S)}; root stands still at the ground-truth root of frame {S}")
        if n_anim:
            samples[label], seed_of[label] = to_global(p[:n_anim], root[:n_anim]), S
        S2 = opts["pose_seed_frames"]
        p2 = ctx.physical(train, model.generate(batch.pose[:, :S2], length=T))
        t2.add(label, [pose(p2)], condition=f"{S2} initial frames; no control", run=r, kind="reference",
               note=what.format(S=S2))

    # ---------------------------------------------------------------- animation samples
    if n_anim:
        ctx.sample("ground truth", to_global(gt_pose[:n_anim], gt_root[:n_anim]))
        for method, pos in samples.items():
            ctx.sample(method, pos)
        seeds = dict(ctx.sample_meta.get("seed_frames") or {})
        seeds.update(seed_of)
        ctx.sample_meta.update(
            fps=fps, parents=skel.parents.tolist(), joints=list(skel.names), space="3d", seed_frames=seeds,
            title=f"{ctx.name}: test windows {[int(i) for i in idx[:n_anim]]} (of {len(data)}), ground truth and "
                  f"the VAE-LSTM paper's Table 1 methods (global positions, metres)")
    if not ctx.rows or not any(r.paper == PAPER for r in ctx.rows):
        log.warning("%s: locomotion suite found no trained runs", ctx.name)

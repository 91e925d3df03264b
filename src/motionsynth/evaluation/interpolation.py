"""GlocalNet Table 1: LocGen against plain linear interpolation, on ``bandai1`` (ours) for NTU RGB+D 3D (theirs).

What the paper's Table 1 measures (sec. 3.2, 4.4)
-------------------------------------------------
Table 1 ("Comparison of Our Method GloLocalNet (GloGen + LocGen) in terms of Euclidean Distance
per frame on NTU RGB+D(3D)") has one row per *first-stage* method (Vae Seq2Seq, Seq2Seq,
att. Seq2Seq, acLSTM, Our Method = GloGen), all "trained from scratch using the same data
pre-processing" with "the same input (Class Label & Initial Poses)", and two columns: the dense
motion obtained from that method's output **with LocGen** and **with interpolation** (eq. 3).
The caption: "LocGen majorly contributes to the qualitative results rather than quantitative".
So a cell is: seed poses + class label -> method -> (sparse) poses -> densify by LocGen or by
linear interpolation -> Euclidean distance per frame to the ground truth. Our rows:

* ``GlocalNet`` (published string of "Our Method"): GloGen rolls out the window's sparse poses
  from its first ``t_in = 5`` ground-truth sparse poses and its class label; the dense motion is
  LocGen's (column ``with LocGen``, the GlocalNet chain, :func:`~motionsynth.models.locgen.glocal_generate`)
  or eq. 3's linear interpolation of the same GloGen poses (column ``with interpolation``).
* baselines: every plain trained run of the dataset (:func:`~motionsynth.evaluation.horizon.methods`),
  labelled as its config's ``label``. The Seq2Seq family has published rows: ``Seq2Seq``
  (Martinez et al. 2017), ``att. Seq2Seq`` (:mod:`motionsynth.models.att_seq2seq`: the decoder
  attends over every encoder state) and ``Vae Seq2Seq`` (:mod:`motionsynth.models.vae_seq2seq`: a
  Gaussian latent between encoder and decoder); so does ``acLSTM``. ``ERD``, ``LSTM-3LR``,
  ``Scheduled Sampling`` are ours only; ``Zero-velocity`` a reference. No row is special-cased by
  name: a Seq2Seq-family run is measured exactly as every other baseline. Ours are trained on *dense*
  frames, not on sparse poses as the paper's presumably were (the paper gives none of these
  baselines' settings; the two variants' recipes are ours, their modules' docstrings say which).
  Each is seeded with the same dense ground-truth frames ``0 .. S-1`` (``S = (t_in - 1) * every
  + 1 = 21``: up to and including GloGen's last seed pose, so every method starts from the same
  instant) and the class label; its output at the sparse instants (every 5th frame) is then
  densified by LocGen or by interpolation, as the table does with a first-stage output. A third column, ``as generated``,
  scores the baseline's own dense frames (beyond the paper).
* ``Ground-truth sparse poses`` (reference, beyond the paper): LocGen's and interpolation's own
  error when given the *true* sparse poses (every 5th frame of the window): the densification
  error alone, without any roll-out error.

Metric (same definition as Table 4, :func:`motionsynth.metrics.errors.euclidean_per_frame_values`)
-------------------------------------------------------------------------------------------------
* per frame: ONE L2 norm of the whole root-relative pose-vector difference (root = the dataset's
  ``skeleton.root``, ``Hips``, subtracted per frame; our prepared poses are also
  facing-normalised), in **metres** (Bandai BVH centimetres x 0.01), all 21 joints of bandai1;
* **frames scored**: roll-outs (``GlocalNet`` and the baselines): every dense frame after the
  last seed frame, ``S .. L-1`` (75 frames = 2.5 s at 30 fps), sparse instants included (they
  are generated too; LocGen keeps them, so the two columns differ only in the in-betweens);
  ground-truth sparse poses: the **in-between frames only** (frames not on a multiple of 5: 76 of
  the window's 96; at the sparse instants both methods return the given pose exactly). ``L`` is the
  last frame on a sparse instant, ``(n - 1) * every + 1`` (the whole 96-frame window here);
* averaging: the mean over the scored frames of each window, then the plain mean over windows
  (``n`` = windows: up to ``eval.max_windows`` test windows of family ``glocal``, evenly spaced
  over the split (:meth:`EvalContext.pick`), all classes pooled as the paper's single number is);
* stochastic or deterministic is measured, not declared
  (:func:`~motionsynth.evaluation.horizon.is_stochastic`: the method's roll-out of the first
  ``stochastic_check_windows`` windows under two seeds). A deterministic method (GloGen,
  LocGen, every plain recurrent baseline in eval mode) gives one value per cell
  (``seeds = 1``, note "deterministic"). A stochastic one (``Vae Seq2Seq``: every roll-out draws
  its latent) is rolled out once per evaluation seed (``ctx.seeds``, ``eval.seeds`` of them; torch
  seeded with each), each roll-out densified and scored as above; the cell is the mean +- std over
  the seeds of the per-seed value (``ctx.add_seeds``; the paper reports one number, no spread).
* interpolation is done on normalised poses; normalisation is affine per coordinate, so this is
  exactly eq. 3 in metres. Eq. 3 is read from ``X_i`` to ``X_{i+1}`` with ``M = every - 1 = 4``
  poses strictly between (:func:`motionsynth.models.locgen.interpolate`'s docstring).

Differences from the paper, stated in every row's ``note``: bandai1 (17 classes, 30 fps, 21
joints, metres), not NTU RGB+D 3D (60 classes, Kinect 25 joints, metres); our baselines dense.

Outputs: rows ``(Table 1, compare_to = "NTU RGB+D 3D (60 classes)", column "with LocGen" / "with
interpolation" / "as generated", method)``, keys ``table1/<column>``; option
``evaluate.interpolation.stochastic_check_windows`` (default 4); curve
``table1_error_vs_time`` (error per frame after the seed, per method and densifier; the mean over
seeds for a stochastic method); animation
samples of ``eval.animation.sequences`` test windows: ground truth, ``GlocalNet``, ``GloGen +
interpolation`` and every baseline, the whole window from the same seed, root-relative (no
trajectory).
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from ..metrics.errors import euclidean_per_frame_values, frames_to_ms
from ..models.locgen import interpolate
from .context import EvalContext
from ..models.base import Batch
from .horizon import (CHAIN, INTERP, METRIC, PAPER, Method, add_samples, is_stochastic, methods, rollout_normalised,
                      skeleton)

log = logging.getLogger(__name__)

PUBLISHED = "NTU RGB+D 3D (60 classes)"
WITH_LOCGEN, WITH_INTERP, AS_GENERATED = "with LocGen", "with interpolation", "as generated"
GT_SPARSE = "Ground-truth sparse poses"
#: option defaults (``conf/dataset/<ds>.yaml: evaluate.interpolation`` overrides any of them)
DEFAULTS = {"compare_to": PUBLISHED,
            "stochastic_check_windows": 4}   # windows rolled out under two seeds to tell stochastic methods


def frame_errors(pred: np.ndarray, gt: np.ndarray, fps: float, frames: np.ndarray, root_index: int) -> np.ndarray:
    """Euclidean distance per frame (Table 4's definition) of each window at each of ``frames``
    (0-based indices into the time axis), ``[B, F]``: frame ``i`` is the horizon ``(i + 1)`` frames
    after a 0-frame seed, so the library reads exactly that frame (no interpolation)."""
    frames = np.asarray(frames, dtype=np.int64)
    return euclidean_per_frame_values(pred, gt, fps, frames_to_ms(frames + 1, fps), root_index=root_index,
                                      seed_frames=0, frame_mapping="round")


def densify(locgen, sparse: torch.Tensor, every: int, how: str) -> torch.Tensor:
    """Normalised sparse poses ``[B, n, J, D]`` -> dense ``[B, (n-1)*every+1, J, D]`` by LocGen or eq. 3."""
    if how == WITH_LOCGEN:
        return locgen.generate(sparse, M=every - 1)
    B, n, J, D = sparse.shape
    return interpolate(sparse.reshape(B, n, J * D), every - 1)[0].reshape(B, -1, J, D)


def options(ctx: EvalContext) -> dict:
    """``evaluate.interpolation`` over :data:`DEFAULTS`; unknown names and bad values are refused."""
    given = ctx.options.get("interpolation") or {}
    unknown = sorted(set(given) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.interpolation has unknown option(s) {unknown}; "
                         f"known: {sorted(DEFAULTS)}")
    o = {**DEFAULTS, **given}
    k = o["stochastic_check_windows"]
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"evaluate.interpolation.stochastic_check_windows must be an integer >= 1, got {k!r}")
    return o


def rollouts(ctx: EvalContext, meth: Method, batch: Batch, length: int, windows: int) -> list[torch.Tensor]:
    """``meth``'s normalised dense roll-outs ``[B, length, J, D]`` of ``batch``: one per evaluation seed
    (``ctx.seeds``, torch seeded with each) for a stochastic method (measured on its first ``windows``
    windows, :func:`~motionsynth.evaluation.horizon.is_stochastic`), else one (seed ``ctx.seeds[0]``)."""
    seeds = ctx.seeds if is_stochastic(ctx, meth, batch, length, windows) else ctx.seeds[:1]
    return [rollout_normalised(ctx, meth, batch, length, s) for s in seeds]


def run(ctx: EvalContext) -> None:
    opts = options(ctx)
    compare_to = str(opts["compare_to"])
    data = ctx.data("glocal", "test")
    if len(data) == 0:
        raise ValueError(f"{ctx.name}: no glocal test windows")
    fps, every, T = float(data.rep["fps"]), data.every, data.length
    if every < 2:
        raise ValueError(f"{ctx.name}: glocal windows every {every} frame(s) have no in-between frames to "
                         "interpolate; Table 1 needs every >= 2")
    n_sparse = (T - 1) // every + 1
    L = (n_sparse - 1) * every + 1                                     # last frame on a sparse instant
    sk = skeleton(ctx)
    locgen_runs = ctx.available("locgen", None)
    locgen = ctx.model(locgen_runs[0])[0] if locgen_runs else None
    if locgen is None:
        log.warning("%s: no trained LocGen run: only the 'with interpolation' columns are measured", ctx.name)
    densifiers = [WITH_INTERP] + ([WITH_LOCGEN] if locgen is not None else [])
    meths, S = methods(ctx, every)
    if S >= L:
        raise ValueError(f"{ctx.name}: a {S}-frame seed leaves nothing to score in {L}-frame windows")

    idx = ctx.pick(data, ctx.opts.get("max_windows"))
    raw = ctx.raw(data, idx)
    gt = raw["pose"][:, :L]
    batch = data.batch(idx).to(ctx.device)
    B = len(idx)
    kw = dict(paper=PAPER, table="Table 1", compare_to=compare_to, metric=METRIC, n=B, protocol="test split")
    place = (f"ours on {ctx.name} ({len(sk.names)} joints, {fps:g} fps, metres), not NTU RGB+D 3D; "
             f"root-relative (root '{sk.names[sk.root_index]}'), facing-normalised")
    after_seed = np.arange(S, L)
    between = np.flatnonzero(np.arange(L) % every != 0)
    horizons_ms = frames_to_ms(after_seed - (S - 1), fps)

    # (a, b) ground-truth sparse poses densified: the densification error alone
    sparse = batch.pose[:, :L:every]
    for how in densifiers:
        pred = ctx.physical(data, densify(locgen, sparse, every, how))
        v = frame_errors(pred, gt, fps, between, sk.root_index)
        ctx.add(column=how, method=GT_SPARSE, value=float(v.mean()), kind="reference", run=locgen_runs[0]
                if how == WITH_LOCGEN else "", key=f"table1/{how.replace(' ', '_').lower()}",
                condition=f"ground-truth sparse poses every {every} frames (no roll-out)", seeds=1,
                note=f"beyond the paper: {len(between)} in-between frames per window scored (sparse instants "
                     f"excluded: exact for both); {place}; deterministic", **kw)

    # (c, d) GlocalNet and the baselines: seed -> roll-out -> sparse -> densified
    cond = (f"class label + initial poses: dense frames 0..{S - 1} ({(S - 1) // every + 1} sparse poses every "
            f"{every}); frames {S}..{L - 1} scored")

    def errors(pred: np.ndarray) -> np.ndarray:
        """Per window and scored frame ``[B, F]`` of a physical dense motion ``[B, L, J, D]``."""
        return frame_errors(pred, gt, fps, after_seed, sk.root_index)

    def add_rows(label: str, kind: str, note: str, cols: dict[str, tuple[str, list[np.ndarray]]]) -> None:
        """``cols``: ``{column: (run, per-seed errors [B, F] each)}``, one array per roll-out seed (one for a
        deterministic method); the cell is their mean, with the std over seeds when there are several."""
        n_seeds = len(next(iter(cols.values()))[1])
        how_seeds = ("deterministic" if n_seeds == 1 else
                     f"stochastic: mean +- std over {n_seeds} seeds {ctx.seeds[:n_seeds]} (one roll-out per window "
                     "and seed, each densified and scored)")
        for how, (run_name, per_seed) in cols.items():
            v = np.stack(per_seed)                                                 # [seeds, B, F]
            extra = "beyond the paper: the baseline's own dense output" if how == AS_GENERATED else f"{note} {how}"
            row = dict(column=how, method=label, kind=kind, run=run_name, key=f"table1/{how.replace(' ', '_').lower()}",
                       condition=cond, note=f"{extra}; {place}; {how_seeds}", **kw)
            if len(per_seed) > 1:
                ctx.add_seeds(v.mean(axis=(1, 2)), **row)
            else:
                ctx.add(value=float(v.mean()), seeds=1, **row)
            ctx.curve("table1_error_vs_time", f"{label} {how}", horizons_ms, v.mean(axis=(0, 1)))

    glogen_runs = ctx.available("glogen", None)
    if glogen_runs:                                   # GlocalNet: GloGen's sparse roll-out, densified both ways
        glogen = ctx.model(glogen_runs[0])[0]
        ctx.torch_seed(ctx.seeds[0])
        sp = glogen.generate(batch.pose[:, ::every][:, :glogen.t], labels=batch.labels, length=n_sparse)
        cols = {how: (f"{glogen_runs[0]}+{locgen_runs[0]}" if how == WITH_LOCGEN else glogen_runs[0],
                      [errors(ctx.physical(data, densify(locgen, sp, every, how)))])
                for how in densifiers}
        add_rows("GlocalNet", "model", "GloGen (sparse roll-out) densified", cols)
    else:
        log.warning("%s: no trained GloGen run: the GlocalNet row is left out", ctx.name)
    for meth in meths:
        if meth.role in (CHAIN, INTERP):
            continue                                  # GloGen's rows: measured above
        cols = {how: (meth.run, []) for how in densifiers + [AS_GENERATED]}
        for z in rollouts(ctx, meth, batch, L, opts["stochastic_check_windows"]):
            for how in densifiers:
                cols[how][1].append(errors(ctx.physical(data, densify(locgen, z[:, ::every], every, how))))
            cols[AS_GENERATED][1].append(errors(ctx.physical(data, z)))
        add_rows(meth.label, meth.kind, f"our baseline, trained on dense frames: its frames every {every} "
                                        "(the sparse instants) densified", cols)

    # animation samples: ground truth, GlocalNet, GloGen + interpolation, baselines, from the same seed
    add_samples(ctx, data, meths, sk, S, L, f"{ctx.name}: GlocalNet Table 1 protocol, {S}-frame seed + class "
                                            f"label, {T} frames at {fps:g} fps")

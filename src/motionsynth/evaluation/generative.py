"""Suite ``generative``: metrics beyond the seed papers, so our models can be set beside today's
literature. Paper ``beyond_papers``, table ``Generative metrics``, ``compare_to = "<ds> (ours)"``
(no published numbers: the rows are ours only).

Rows, per dataset (``conf/dataset/<ds>.yaml: evaluate.generative`` holds the options below)
------------------------------------------------------------------------------------------
* ``Real test data (classifier)`` (reference): the action classifier's accuracy on the whole test
  split, with chance (``1 / C``) and the majority-class share in the note.
* ``Real test data`` (reference): Action2Motion's "Real" row: real test windows (half ``A``,
  below) read as if they were generated: FID against the second half ``B``, accuracy,
  diversity and multimodality of ``A``.
* ``Gaussian noise`` (reference): i.i.d. ``N(0, 1)`` poses in normalised units, shaped like ``A``,
  labelled with ``A``'s classes: the FID / accuracy scale of "no motion at all".
* every trained run (``ctx.available()``), as its own protocol generates (below), labelled
  ``ctx.label(model)`` (``"<label> (controls given)"`` for the ``controls_given`` variant).

Metrics: ``FID``, ``Recognition accuracy``, ``Diversity``, ``Multimodality`` (column ``value``,
key ``generative/<metric>``); on 3-D data also ``Foot skating ratio`` and ``Bone length error``
(columns ``abs (m)`` and ``relative``); and ``Sample spread`` for every method (key
``generative/sample_spread``): for each conditioning window of half ``A``, ``spread_samples`` (10)
draws of the method's own protocol (VAE-LSTM: prior samples for the same control path); per frame
and joint the standard deviation across the draws of the joint's position relative to the root
joint (``sqrt`` of the summed per-coordinate variances), averaged over joints, over frames
``spread_from_frame`` (5) .. ``T`` and over windows; metres on 3-D data, pixels on 2-D
(:func:`sample_spread`). A deterministic method scores exactly 0 (not drawn: its draws are equal).

Jitter (column ``Jitter``, key ``generative/jitter``; column ``Jitter, relative``, key
``generative/jitter/relative``), for every method and for ``Real test data``: GlocalNet (sec. 4.4,
"Ablation Study on Loss Functions") reports "jitters in the generated sequence (without having
L_MF)" and that "L_MF enables the network to learn generating smoother transition", qualitatively
only; this column measures it (:func:`jitter`). Per joint and frame the magnitude of the
second difference of the joint's position,

    a_{t,j} = || x_{t+1,j} - 2 x_{t,j} + x_{t-1,j} ||_2          (frame-to-frame acceleration)

averaged over joints, over the generated frames and over the windows of ``A``: ``t`` runs over
the generated frames ``S .. T-2`` (0-based, ``S`` = the method's seed length), so the first term
reaches back to the last seed frame (the seed-to-generation transition counts) and the last one
to frame ``T-1``. Positions are those the models generate: the stored root-relative,
facing-normalised frame (no trajectory) in **metres per frame²** on 3-D data, the benchmark's
centred image coordinates in **pixels per frame²** on 2-D data (h36m), at the dataset's fps (the
note says which). ``Real test data``: the same quantity over the whole windows of ``A``.
``relative``: the method's jitter over its own scored frames divided by that of the ground truth
of the same windows over the same frames (1 = as smooth as real motion; > 1: jittery; < 1:
smoother than real motion, e.g. frozen or over-damped). With sparse windows (``every > 1``) a
linearly interpolated method's acceleration is 0 inside each gap and concentrated at the
keyframes: its jitter measures the keyframes' changes of velocity spread over the gaps. Stochastic
methods: mean +- std over ``ctx.seeds`` (one generation per seed, as the other columns).

The classifier and its feature space
------------------------------------
:class:`motionsynth.metrics.recognition.ActionClassifier` (Action2Motion's GRU: 2 x 128 GRU, the
last frame's state -> 30-d ``tanh`` features -> class logits; read that module for FID,
diversity and multimodality, which are used as defined there: FID on the 30-d features,
``S_d = 200`` diversity pairs over the whole set, ``S_l = 20`` pairs per class for
multimodality, pairs drawn with replacement as the reference code does).

* Input: the dataset's training representation (``training.representation`` / ``protocol``) in
  the window family the baselines train on (``training.family``; ``family`` option), normalised
  with the protocol's train statistics: the space every model generates in, so generated
  windows go through the classifier without any conversion. 3-D poses are root-relative and
  facing-normalised (the classifier sees no trajectory); 2-D poses are the benchmark's
  depth-scaled, centred image coordinates.
* ``frame_step``: the classifier reads every ``frame_step``-th frame of a window (the same
  frames of real and generated windows). Our choice, for the time budget: 2 on bandai1 (30 ->
  15 fps, 48 of 96 frames), 4 on bandai2_locomotion (60 -> 15 fps, 60 of 240), 1 on h36m
  (16.7 fps). Measured: bandai2 test accuracy 0.99 at step 2 and at step 4; bandai1 0.59 at
  step 1 and 2.
* Training (:func:`~motionsynth.metrics.recognition.train_classifier`): Adam, cross-entropy, on the
  TRAIN split only; ``epochs`` x at most ``max_batches_per_epoch`` batches of ``batch_size``;
  the epoch with the best accuracy on (at most ``val_windows`` evenly spaced) VAL windows is
  kept, and training stops ``patience`` (3) epochs after it: the later epochs could not change
  the kept weights (the cmu_aclstm classifier peaked at epoch 1 of 20 and trained on for 79 s).
  The TEST split is only used afterwards. Seeded (``cfg.seed``), deterministic for a
  given thread count.
* Precision (``dtype``, default ``float64``; the reference trains in float32): the classifier
  is trained and run in float64, so that a retrained classifier gives the same feature space
  on another CPU (the reasons and the measurements: "Precision" in
  :mod:`motionsynth.metrics.recognition`). It costs about twice the training time
  (``h36m``: 33 s -> 66-82 s; ``bandai1``: 7 s -> 12-15 s, on one thread).
* Threads: the suite runs on ``threads`` torch threads (default 1; ``null``: ``eval.threads``),
  restored afterwards. Its networks are small (GRU 128, batches of 64, the baselines' 128-unit
  roll-outs): a second thread gains little on a quiet machine and costs a lot on a busy one.
  Training the bandai2_locomotion classifier took 10.6 s on 1 thread and 7.4 s on 2 on a quiet
  2-core machine, but 16 s on 1 and 179 s on 2 while other processes kept the cores busy.
* Cache: ``<cache_dir>/<fingerprint>.pt`` (default ``cache_dir``: ``models/_classifiers/<ds>``, an output of the evaluate stage;
  set it elsewhere to evaluate a read-only models tree). The fingerprint hashes the bytes of
  every input file that defines the training windows (``pose.npy``, ``root.npy``,
  ``meta.parquet``, ``windows_<family>.parquet``, ``representation.json``, the split table and
  its statistics) and every training setting (hyper-parameters, seed, threads, torch
  version), so a rerun on the same data loads the classifier instead of training it, and any
  change retrains. Stale ``<fingerprint>.pt`` files of the folder are removed when a new one is
  written (no other file is touched).

Real test halves, sample counts
-------------------------------
FID needs two independent real sets for its "Real" row. The test windows are split per test
sequence by time: the first half of each sequence's windows (ordered by start frame) go to half
``A``, the rest to ``B`` (a sequence with an odd count gives the extra window to ``A`` and to ``B``
in turn over the sequences of a class, one-window sequences included), so both halves hold
nearly the same sequences, sizes and class mix; only windows at the boundary overlap in time.
Each half is then thinned evenly to at most ``windows`` (default ``eval.max_windows``). Models are
conditioned on ``A`` (seed frames, class labels, controls) and their FID is taken against ``B``;
so is the real row's (``A`` against ``B``), which is the FID of a perfect generator that returns
the true continuation. FID is biased upwards at small ``N`` (a few hundred samples here, 30-d
features): compare rows of one dataset with each other, not with published FIDs. ``Row.n`` = generated windows per seed.

Multimodality uses the classes of ``A`` with at least 2 windows (``skip_small``; the note says how
many). Randomness: the pair draws of diversity / multimodality use ``numpy`` generators seeded
with the seed of the generation (``ctx.seeds[0]`` for deterministic rows); the noise row uses
``ctx.seeds[0]``.

Generation protocols (each model's own seed frames; the whole window is classified)
-----------------------------------------------------------------------------------
Every generated window has the length ``T`` of the family's windows and starts with the
model's ground-truth seed frames (the share is in ``Row.condition``); class labels come from
the windows of ``A``.

* Next-frame models, i.e. every model with a ``rollout(seed, controls, labels, length)`` and
  ``seed_frames`` (the recurrent baselines ERD, LSTM-3LR, acLSTM, Scheduled Sampling, the
  Seq2Seq family Seq2Seq / att. Seq2Seq / Vae Seq2Seq, and the cRBM): ``seed_frames``
  ground-truth frames, the class label where the dataset has classes; with controls
  (bandai2_locomotion) ``control_mode: predict`` gets the seed's controls and predicts the
  rest (their predicted controls give the trajectory), ``given`` gets all ground-truth
  controls. The roll-out is :meth:`RecurrentBaseline.rollout` (the cRBM's has the same contract),
  which is ``generate`` keeping the roll-out's controls. Vae Seq2Seq draws its latent and the
  cRBM its hidden units anew on every roll-out: both are measured stochastic (below).
* Zero-velocity: the last seed pose held; its root is held too (zero controls after the seed).
* GloGen: its ``t_in`` ground-truth sparse poses and the label, rolled out to the window's
  ``n`` sparse poses. With sparse windows (``every > 1``, bandai1) two rows: ``GloGen``, the
  sparse poses linearly interpolated (LocGen's eq. 3 with no network: the GloGen-only
  ablation), and ``GlocalNet`` = GloGen then LocGen's in-betweens (``M = every - 1``) when a
  LocGen run exists. GloGen's loss ablations (runs of ``glogen_lj`` / ``glogen_lmf``, labels
  ``GloGen (L_J)`` / ``GloGen (L_MF)``) are GloGen models and get the same rows, their chain named
  after their label (``GlocalNet (L_J)``, ``GlocalNet (L_MF)``). ``LocGen`` alone densifies the
  ground-truth keyframes of ``A``: an in-betweening reference, not a generator (condition says so).
* VAE-LSTM: ``z_1`` from the prior (no seed frames) driven by ``A``'s ground-truth controls, as the
  paper synthesises; it takes no class label, so its class is the one the controls imply
  (bandai2_locomotion: walk / walk-turn-left / walk-turn-right / run).
* The GAN family (``model.adversarial``: SA-GCN, ...): one clip of noise and the window's class label
  after the model's ``seed_frames`` ground-truth poses, which are copied in front (these generators
  take no seed; the poses after the seed do not depend on it), as the MMD suite scores them.
* Stochastic or deterministic is measured, not declared: each method generates ``stochastic_check_windows`` (4) windows under
  two seeds; identical outputs -> deterministic (one generation, ``ctx.add``, note
  "deterministic"); else one generation per ``ctx.seeds`` (``ctx.add_seeds``, mean +- std).
  Multimodality of a deterministic model is the Action2Motion quantity (pairs of generated
  windows of one class) and is not 0: its within-class variation comes only from the
  different seed windows it is given; a per-condition multimodality (several samples for one
  seed and class) would be 0 by construction, which the note states.
* Training-seed replicas (``<run>-seed<k>`` runs: GloGen and Seq2Seq on ``cmu_aclstm``, the three GANs
  on ``h36m``; :func:`replica_methods`): the row's columns are mean +- std over every (training seed,
  evaluation seed) pair, as in the other suites; the sample spread is that of the seed-0 run.

Physical metrics (3-D data only; :mod:`motionsynth.metrics.physical`, metres)
-----------------------------------------------------------------------------
Computed on the generated frames only: from the last seed frame on (so the first generated
transition counts), ground truth on whole windows of ``A``.

* Bone length error: against the rest lengths of ``skeleton.json`` of the representation; mean
  ``|L - L0|`` (m) and mean ``|L - L0| / L0``. Bone lengths do not depend on the root, so
  root-relative poses suffice.
* Foot skating ratio (GMD's definition: a foot below 5 cm in two consecutive frames moving
  faster than 0.5 m/s, smoothed over ~0.25 s; feet = ``skeleton.feet``): needs world positions.
  Where the model's output defines a trajectory (datasets with controls: predicted or given
  controls integrated with :func:`~motionsynth.data.controls.integrate_controls` from the window's
  first root) it is computed in world space. Where models output root-relative poses only
  (bandai1) it is NOT reported for them: in the root frame a planted foot moves with the
  body's speed, so the ratio mostly measures locomotion (the ground-truth row's note gives
  its root-frame value beside its world value to show it), and a ground-truth trajectory
  would not match the generated legs. The ground truth's world-space ratio is still reported
  as the dataset's reference.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import re
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from ..data.controls import integrate_controls
from ..threads import resolve as resolve_threads
from ..data.types import Skeleton
from ..metrics import recognition as rec
from ..metrics.physical import bone_length_error, foot_skating_ratio
from .context import EvalContext
from .horizon import chain_label, variant_of

log = logging.getLogger(__name__)

PAPER, TABLE = "beyond_papers", "Generative metrics"
#: one results block per dataset, the metrics its columns (``Row.metric`` is this group name)
GROUP = "Generative metrics"
CLASSIFIER_ROW, REAL_ROW, NOISE_ROW = "Real test data (classifier)", "Real test data", "Gaussian noise"
METRICS = ("FID", "Recognition accuracy", "Diversity", "Multimodality")
SPREAD = "Sample spread"
JITTER, JITTER_REL = "Jitter", "Jitter, relative"
JITTER_KEY, JITTER_REL_KEY = "generative/jitter", "generative/jitter/relative"

#: option defaults (``conf/dataset/<ds>.yaml: evaluate.generative`` overrides any of them)
DEFAULTS: dict[str, Any] = {
    "family": None,              # window family; None: training.family
    "frame_step": 1,             # the classifier reads every k-th frame
    "epochs": 10,
    "batch_size": 64,
    "lr": 2.0e-3,
    "max_batches_per_epoch": None,
    "patience": 3,               # stop this many epochs after the best val epoch (None: all epochs)
    "dtype": "float64",          # the classifier's precision (module docstring: "Precision")
    "val_windows": 512,          # val windows that select the epoch (evenly spaced)
    "windows": None,             # windows per real half; None: eval.max_windows
    "cache_dir": None,           # None: <paths.models>/_classifiers/<ds> (the evaluate stage's output)
    "physical": True,            # foot skating / bone lengths on 3-D data
    "threads": 1,                # torch threads of the whole suite; None: eval.threads (module docstring)
    "spread_samples": 10,        # sample spread: draws per conditioning window
    "spread_from_frame": 5,      # sample spread: first (1-based) frame averaged over
    "stochastic_check_windows": 4,  # windows generated under two seeds to tell stochastic methods apart
}


# ============================================================================ options

def _options(ctx: EvalContext) -> dict[str, Any]:
    given = ctx.options.get("generative") or {}
    if not isinstance(given, dict):
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.generative must be a mapping, got {given!r}")
    unknown = sorted(set(given) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.generative has unknown option(s) {unknown}; "
                         f"known: {sorted(DEFAULTS)}")
    o = {**DEFAULTS, **given}
    for k in ("frame_step", "epochs", "batch_size", "val_windows", "spread_samples", "spread_from_frame",
              "stochastic_check_windows"):
        if isinstance(o[k], bool) or not isinstance(o[k], int) or o[k] < 1:
            raise ValueError(f"evaluate.generative.{k} must be an integer >= 1, got {o[k]!r}")
    if o["threads"] is not None and (isinstance(o["threads"], bool) or not isinstance(o["threads"], int)
                                     or o["threads"] < 1):
        raise ValueError(f"evaluate.generative.threads must be an integer >= 1 or null, got {o['threads']!r}")
    o["threads"] = resolve_threads(o["threads"] or ctx.opts.get("threads") or 1)
    if o["patience"] is not None and (isinstance(o["patience"], bool) or not isinstance(o["patience"], int)
                                      or o["patience"] < 1):
        raise ValueError(f"evaluate.generative.patience must be an integer >= 1 or null, got {o['patience']!r}")
    for k in ("max_batches_per_epoch", "windows"):
        if o[k] is not None and (isinstance(o[k], bool) or not isinstance(o[k], int) or o[k] < 2):
            raise ValueError(f"evaluate.generative.{k} must be an integer >= 2 or null, got {o[k]!r}")
    if not (isinstance(o["lr"], (int, float)) and math.isfinite(o["lr"]) and o["lr"] > 0):
        raise ValueError(f"evaluate.generative.lr must be a positive number, got {o['lr']!r}")
    if o["dtype"] not in rec.DTYPES:
        raise ValueError(f"evaluate.generative.dtype must be one of {rec.DTYPES}, got {o['dtype']!r}")
    if o["windows"] is None:
        o["windows"] = int(ctx.opts.get("max_windows") or 256)
    o["family"] = o["family"] or ctx.dataset_cfg["training"]["family"]
    return o


# ============================================================================ the classifier

def _file_digest(h: "hashlib._Hash", path: Path) -> None:
    h.update(path.name.encode())
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)


def classifier_fingerprint(ctx: EvalContext, family: str, settings: dict[str, Any]) -> str:
    """Hash of the files that define the classifier's train / val windows and of its settings."""
    tr = ctx.dataset_cfg["training"]
    rep = ctx.paths["processed"] / ctx.name / tr["representation"]
    spl = ctx.paths["splits"] / ctx.name / tr["representation"]
    files = [rep / "pose.npy", rep / "root.npy", rep / "meta.parquet", rep / f"windows_{family}.parquet",
             rep / "representation.json", spl / f"{tr['protocol']}.csv", spl / f"{tr['protocol']}_stats.npz"]
    h = hashlib.blake2b(digest_size=16)
    for f in files:
        if f.exists():
            _file_digest(h, f)
        else:
            h.update(f"missing:{f.name}".encode())
    h.update(json.dumps(settings, sort_keys=True, default=str).encode())
    return h.hexdigest()


def _x(data, idx: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    x, y = rec.window_arrays(data, idx)
    return np.ascontiguousarray(x[:, ::step]), y


def get_classifier(ctx: EvalContext, o: dict[str, Any]) -> tuple[rec.ActionClassifier, dict[str, Any]]:
    """The dataset's action classifier: loaded from the cache when its fingerprint matches,
    else trained on the train split (val selects the epoch) and cached. Returns it and its meta
    (``history``, ``selected_epoch``, ``val_acc``, ``n_train``, ``n_val``, ``cached``, ``seconds``)."""
    fam, step = o["family"], o["frame_step"]
    train, val = ctx.data(fam, "train"), ctx.data(fam, "val")
    if train.num_classes < 2:
        raise ValueError(f"{ctx.name}: the generative suite needs class labels (training.num_classes >= 2), "
                         f"got {train.num_classes}")
    if len(train) == 0:
        raise ValueError(f"{ctx.name}: no '{fam}' train windows for the action classifier")
    threads = o["threads"]
    settings = {k: o[k] for k in ("family", "frame_step", "epochs", "batch_size", "lr", "max_batches_per_epoch",
                                  "val_windows", "patience", "dtype")}
    settings.update(seed=int(ctx.cfg.get("seed", 0)), threads=threads, torch=str(torch.__version__),
                    num_classes=train.num_classes, arch=dict(hidden_size=128, num_layers=2, feature_size=30))
    fp = classifier_fingerprint(ctx, fam, settings)
    cache = Path(o["cache_dir"]) if o["cache_dir"] else ctx.paths["models"] / "_classifiers" / ctx.name
    path = cache / f"{fp}.pt"
    t0 = time.perf_counter()
    if path.exists():
        try:
            model, meta = rec.load_classifier(path)
        except Exception as e:  # noqa: BLE001 - an unreadable cache entry is retrained, never fatal
            log.warning("%s: cached classifier %s unreadable (%s); retraining", ctx.name, path, e)
        else:
            meta = {**meta, "cached": True, "seconds": time.perf_counter() - t0, "path": str(path)}
            log.info("%s: action classifier loaded from %s", ctx.name, path)
            return model, meta
    x, y = _x(train, np.arange(len(train)), step)
    vidx = ctx.pick(val, o["val_windows"]) if len(val) else None
    vx, vy = _x(val, vidx, step) if vidx is not None else (None, None)
    model, hist = rec.train_classifier(x, y, vx, vy, train.num_classes, epochs=o["epochs"],
                                       batch_size=o["batch_size"], lr=float(o["lr"]), seed=settings["seed"],
                                       threads=threads, max_batches_per_epoch=o["max_batches_per_epoch"],
                                       patience=o["patience"], dtype=o["dtype"])
    sel = next(i for i, r in enumerate(hist) if r.get("selected"))
    meta = {"fingerprint": fp, "settings": settings, "history": hist, "selected_epoch": sel,
            "val_acc": hist[sel].get("val_acc", math.nan), "train_acc": hist[sel]["train_acc"],
            "n_train": len(x), "n_val": 0 if vx is None else len(vx)}
    cache.mkdir(parents=True, exist_ok=True)
    for old in cache.glob("*.pt"):          # stale classifiers of this cache only (their names are fingerprints)
        if re.fullmatch(r"[0-9a-f]{32}", old.stem):
            old.unlink()
    tmp = path.with_suffix(".tmp")
    rec.save_classifier(model, tmp, **meta)
    tmp.replace(path)
    meta = {**meta, "cached": False, "seconds": time.perf_counter() - t0, "path": str(path)}
    log.info("%s: action classifier trained in %.1f s (val acc %.3f, epoch %d) -> %s", ctx.name,
             meta["seconds"], meta["val_acc"], sel, path)
    return model, meta


# ============================================================================ real halves

def _rank_within(keys: np.ndarray) -> np.ndarray:
    """Position of every element among the elements with the same key (in index order)."""
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    first = np.r_[True, k[1:] != k[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(len(k)), 0))
    rank = np.empty(len(k), dtype=np.int64)
    rank[order] = np.arange(len(k)) - start
    return rank


def real_halves(data, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Window indices ``(A, B)`` of two halves of ``data`` (module docstring): per sequence, its
    first windows (by start frame) in ``A`` and the rest in ``B``. A sequence of ``k`` windows gives
    ``A`` ``floor(k/2)`` or ``ceil(k/2)`` of them, alternating over the sequences of each class (so a
    one-window sequence goes to ``A`` and the next of its class to ``B``): the halves get equal
    sizes and class mixes. Each half is then thinned evenly to at most ``n`` windows."""
    w = data.windows
    if len(w) < 4:
        raise ValueError(f"the generative suite needs >= 4 test windows (two halves of >= 2), got {len(w)}")
    seq, start = w["seq"].to_numpy(), w["start"].to_numpy()
    order = np.lexsort((start, seq))                                        # by sequence, then time
    seq_o = seq[order]
    rank = _rank_within(seq_o)                                              # position in its sequence
    useq, inv, size = np.unique(seq_o, return_inverse=True, return_counts=True)
    extra = (_rank_within(np.asarray(data.labels)[useq]) % 2 == 0).astype(np.int64)   # alternate per class
    in_a = rank < (size[inv] + extra[inv]) // 2
    a, b = np.sort(order[in_a]), np.sort(order[~in_a])

    def thin(ix: np.ndarray) -> np.ndarray:
        if len(ix) <= n:
            return ix
        return ix[np.unique(np.linspace(0, len(ix) - 1, n).round().astype(int))]

    a, b = thin(a), thin(b)
    if len(a) < 2 or len(b) < 2:
        raise ValueError(f"test windows split into halves of {len(a)} and {len(b)}; each needs >= 2 "
                         "(too few test sequences with more than one window)")
    return a, b


# ============================================================================ generation

class Generated:
    """One generation of a method on the windows of ``A``: normalised poses ``z`` ``[N, T, J, D]``,
    optional physical controls ``[N, T, 3]`` (for the world trajectory), and the seed length ``S``."""

    def __init__(self, z: torch.Tensor | np.ndarray, seed_len: int, controls: np.ndarray | None = None):
        self.z = z.detach().cpu().numpy() if isinstance(z, torch.Tensor) else np.asarray(z)
        self.z = self.z.astype(np.float32)
        self.seed_len = int(seed_len)
        self.controls = controls


def _fit_length(z: torch.Tensor, T: int) -> torch.Tensor:
    """Pad a dense roll-out that stops short of ``T`` frames with its last pose (LocGen.predict's rule)."""
    if z.shape[1] >= T:
        return z[:, :T]
    return torch.cat([z, z[:, -1:].expand(-1, T - z.shape[1], -1, -1)], 1)


def _phys_controls(data, c_norm: torch.Tensor | np.ndarray) -> np.ndarray:
    c = c_norm.detach().cpu().numpy() if isinstance(c_norm, torch.Tensor) else np.asarray(c_norm)
    return c.astype(np.float64) * data.ctrl_std + data.ctrl_mean


class Method:
    """A row to generate: ``fn(batch, seed) -> Generated`` on the batch of ``A``."""

    def __init__(self, name: str, run: str, condition: str, fn: Callable[[Any, int], Generated], note: str = "",
                 source: str = ""):
        self.name, self.run, self.condition, self.fn, self.note = name, run, condition, fn, note
        self.source = source or run       # the trained run whose training-seed replicas stand beside it


def _variant_label(ctx: EvalContext, run: str, model_name: str) -> str:
    label = ctx.label(model_name)
    variant = run[len(model_name) + 1:] if run.startswith(model_name + "-") else ""
    return f"{label} ({variant.replace('_', ' ')})" if variant else label


def methods(ctx: EvalContext, data, T: int, runs: list[str] | None = None) -> list[Method]:
    """The rows to generate for the trained runs of the dataset (module docstring); ``runs`` (default
    ``ctx.available()``) names other runs, e.g. a run's training-seed replicas, in the same order of rows."""
    from ..models.glogen import GloGen
    from ..models.locgen import LocGen, interpolate
    from ..models.vae_lstm import VAELSTM
    from ..models.zero_velocity import ZeroVelocity

    def next_frame(model) -> bool:
        """A seeded next-frame model: ``rollout(seed, controls, labels, length) -> (poses, controls)``."""
        return (callable(getattr(model, "rollout", None)) and getattr(model, "seed_frames", None) is not None
                and not isinstance(model, (GloGen, LocGen, VAELSTM)))

    out: list[Method] = []
    trained = ctx.available()
    locgen_runs = [r for r in trained if isinstance(ctx.model(r)[0], LocGen)]
    runs = trained if runs is None else runs
    for run in runs:
        model, _ = ctx.model(run)
        name = _variant_label(ctx, run, ctx.runs[run])
        dev = next(model.parameters()).device
        fps = float(data.rep["fps"])

        if isinstance(model, ZeroVelocity) or next_frame(model):
            S = min(int(model.seed_frames), T - 1)
            zero = isinstance(model, ZeroVelocity)
            mode = "" if zero or data.controls is None else f", controls {model.control_mode}"
            cond = f"{S} ground-truth seed frames of {T}" + (", class label" if (not zero and data.num_classes
                                                                                   and model.spec.num_classes) else "")
            cond += mode

            def fn(b, s, model=model, S=S, zero=zero, dev=dev):
                pose = b.pose.to(dev)
                if zero:
                    z = model.generate(pose[:, :S], length=T)
                    ctrl = None
                    if b.controls is not None:
                        c = _phys_controls(data, b.controls)
                        c[:, S:] = 0.0                                     # the root stops with the pose
                        ctrl = c
                    return Generated(z, S, ctrl)
                labels = b.labels.to(dev) if (b.labels is not None and model.spec.num_classes) else None
                ctrl_in = b.controls.to(dev) if b.controls is not None else None
                z, c = model.rollout(pose[:, :S], ctrl_in, labels, T)
                return Generated(z, S, _phys_controls(data, c) if c is not None else None)

            out.append(Method(name, run, cond, fn))

        elif isinstance(model, GloGen):
            k, t = int(data.every), int(model.t)
            n_sparse = (T - 1) // k + 1
            S_dense = (t - 1) * k + 1

            def sparse_rollout(b, model=model, t=t, k=k, n_sparse=n_sparse, dev=dev):
                labels = b.labels.to(dev) if (b.labels is not None and model.num_classes) else None
                return model.generate(b.pose.to(dev)[:, ::k][:, :t], labels=labels, length=n_sparse)

            if k == 1:
                out.append(Method(name, run, f"{t} ground-truth seed poses of {T}, class label",
                                  lambda b, s, f=sparse_rollout, t=t: Generated(_fit_length(f(b), T), t)))
                continue

            def linear(b, s, f=sparse_rollout, k=k, model=model, S_dense=S_dense):
                sp = f(b)
                dense, _ = interpolate(model.flat(sp), k - 1)
                return Generated(_fit_length(model.unflat(dense), T), S_dense)

            out.append(Method(name, run, f"{t} ground-truth sparse seed poses (every {k} frames) of {n_sparse}, "
                                         f"class label; sparse output linearly interpolated (no LocGen)", linear))
            for lrun in locgen_runs:
                loc = ctx.model(lrun)[0]

                def glocal(b, s, f=sparse_rollout, loc=loc, k=k, S_dense=S_dense):
                    return Generated(_fit_length(loc.generate(f(b), M=k - 1), T), S_dense)

                base = ctx.label(variant_of(ctx, run) or ctx.runs[run])        # GloGen (L_J) -> GloGen
                gname = chain_label(name, base) + ("" if len(locgen_runs) == 1 else f" ({lrun})")
                out.append(Method(gname, f"{run}+{lrun}", f"GloGen from {t} ground-truth sparse seed poses (every "
                                  f"{k} frames), class label; LocGen in-betweens (M = {k - 1})", glocal, source=run))

        elif isinstance(model, LocGen):
            k = int(data.every)
            if k == 1:
                log.info("%s: LocGen has no in-betweens on every-frame windows; left out", ctx.name)
                continue

            def locgen_only(b, s, model=model, k=k, dev=dev):
                return Generated(_fit_length(model.generate(b.pose.to(dev)[:, ::k], M=k - 1), T), 1)

            out.append(Method(name, run, f"in-betweens of ALL ground-truth keyframes (every {k} frames): "
                              "an in-betweening reference, not a generator", locgen_only))

        elif isinstance(model, VAELSTM):
            if data.controls is None:
                log.warning("%s: VAE-LSTM needs controls; the data has none: left out", ctx.name)
                continue

            def vae(b, s, model=model, dev=dev):
                c = b.controls.to(dev)
                return Generated(model.generate(None, c, length=T), 0, _phys_controls(data, b.controls))

            out.append(Method(name, run, f"prior sample (no seed frames), ground-truth controls of {T} frames "
                                         f"({T / fps:.1f} s); no class input: the controls imply the class", vae))
        elif getattr(model, "adversarial", False):     # the GAN family: a clip from noise and the class
            S = min(int(model.seed_frames), T - 1)

            def gan(b, s, model=model, S=S, dev=dev):
                return Generated(model.generate(b.pose.to(dev)[:, :S], labels=b.labels.to(dev), length=T), S)

            out.append(Method(name, run, f"class label and noise; the {S} ground-truth seed frames of {T} are copied "
                              "in front (the generator takes no seed), as in the MMD suite", gan))
        else:
            S = min(int(getattr(model, "seed_frames", 0) or 0), T - 1)

            def generic(b, s, model=model, S=S, dev=dev):
                labels = b.labels.to(dev) if b.labels is not None else None
                ctrl = b.controls.to(dev) if b.controls is not None else None
                seed = b.pose.to(dev)[:, :S] if S else None
                return Generated(model.generate(seed, ctrl, labels, length=T), S)

            log.warning("%s: %s (%s) has no dedicated protocol here; generic generate() with %d seed frames",
                        ctx.name, run, type(model).__name__, S)
            out.append(Method(name, run, f"{S} ground-truth seed frames of {T} (generic generate)", generic))
    return out


def replica_methods(ctx: EvalContext, data, T: int, meths: list[Method]) -> dict[int, list[Method]]:
    """``id(method) -> [the same row of each training-seed replica of its run]`` (``<run>-seed<k>``,
    :meth:`EvalContext.replicas`), row for row as :func:`methods` builds them for the replica's run."""
    out: dict[int, list[Method]] = {}
    for source in dict.fromkeys(m.source for m in meths):
        mine = [m for m in meths if m.source == source]
        for r in ctx.replicas(source):
            theirs = methods(ctx, data, T, runs=[r])
            if len(theirs) != len(mine):
                raise AssertionError(f"{ctx.name}: replica {r} gives {len(theirs)} rows, {source} {len(mine)}")
            for m, rm in zip(mine, theirs):
                out.setdefault(id(m), []).append(rm)
    return out


def sample_spread(positions: np.ndarray, root_index: int | None, start: int) -> float:
    """Sample spread of ``positions`` ``[S, N, T, J, D]`` (``S`` samples for each of ``N`` conditioning
    windows, physical units): each frame's joints relative to its root joint ``root_index``; per
    window, frame and joint (``root_index`` None: poses already centred, e.g. the 2-D benchmark's
    hip-centred joints) the standard deviation across the ``S`` samples of that ``D``-vector
    (``sqrt`` of the summed per-coordinate variances: a distance in metres, or pixels); then the mean
    over joints, over frames ``start..T-1`` (0-based) and over windows."""
    x = positions if root_index is None else positions - positions[..., root_index:root_index + 1, :]
    sd = np.sqrt(x.var(axis=0).sum(-1))                                           # [N, T, J]
    return float(sd[:, start:].mean())


def jitter(positions: np.ndarray, start: int) -> float:
    """Jitter of ``positions`` ``[N, T, J, D]`` (physical units): the mean over windows, joints and the
    frames ``t = max(start, 1) .. T-2`` (0-based; ``start`` = the first generated frame) of the
    acceleration's magnitude ``||x_{t+1} - 2 x_t + x_{t-1}||_2`` (per frame², in the positions' units;
    module docstring). The first term reaches back to frame ``start - 1`` (the last seed frame)."""
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 4:
        raise ValueError(f"jitter: positions must be [N, T, J, D], got shape {x.shape}")
    x = x[:, max(int(start), 1) - 1:]
    if x.shape[1] < 3:
        raise ValueError(f"jitter: needs >= 3 frames from frame {max(int(start), 1) - 1}, got {x.shape[1]}")
    acc = x[:, 2:] - 2.0 * x[:, 1:-1] + x[:, :-2]                                 # [N, T', J, D]
    return float(np.sqrt((acc ** 2).sum(-1)).mean())


# ============================================================================ the suite

def run(ctx: EvalContext) -> None:
    o = _options(ctx)
    old = torch.get_num_threads()
    torch.set_num_threads(o["threads"])
    try:
        _run(ctx, o)
    finally:
        torch.set_num_threads(old)


def _run(ctx: EvalContext, o: dict[str, Any]) -> None:
    t_start = time.perf_counter()
    fam, step = o["family"], o["frame_step"]
    test = ctx.data(fam, "test")
    if test.num_classes < 2:
        raise ValueError(f"{ctx.name}: the generative suite needs class labels; training.num_classes = "
                         f"{test.num_classes}")
    T = int(test.length)
    fps = float(test.rep["fps"])
    C = test.num_classes

    clf, cmeta = get_classifier(ctx, o)
    t_clf = time.perf_counter() - t_start

    # ---- the classifier's own test accuracy (whole test split)
    tx, ty = _x(test, np.arange(len(test)), step)
    test_acc = rec.accuracy(clf, tx, ty)
    majority = float(np.bincount(ty, minlength=C).max() / len(ty))
    space = f"{ctx.dataset_cfg['training']['representation']} {test.rep.get('space', '')}".strip()
    per_epoch = (f", at most {o['max_batches_per_epoch']} batches of {o['batch_size']} per epoch"
                 if o["max_batches_per_epoch"] else "")
    feat_note = (f"feature space: 30-d tanh features of a GRU action classifier (Action2Motion) trained on the "
                 f"train split only ({cmeta.get('n_train')} '{fam}' windows{per_epoch}; {space}, normalised, "
                 f"every {step}. frame of {T} = {fps / step:.3g} fps)")
    ctx.add(paper=PAPER, table=TABLE, compare_to=f"{ctx.name} (ours)", metric=GROUP,
            column="Recognition accuracy", method=CLASSIFIER_ROW, value=test_acc, n=len(ty), kind="reference",
            key="generative/recognition_accuracy",
            condition="action classifier on every test window (train split only; val selects the epoch)",
            note=(f"{C} classes, chance {1 / C:.3f}, majority class {majority:.3f}; selected epoch "
                  f"{cmeta.get('selected_epoch')} of {o['epochs']} (val acc {cmeta.get('val_acc', math.nan):.3f} on "
                  f"{cmeta.get('n_val')} val windows, train acc {cmeta.get('train_acc', math.nan):.3f}); "
                  + feat_note))

    # ---- real halves and their features
    ia, ib = real_halves(test, o["windows"])
    batch_a = test.batch(ia)
    ya = batch_a.labels.numpy()
    xa = np.ascontiguousarray(rec.window_arrays(test, ia)[0][:, ::step])
    xb, _ = _x(test, ib, step)
    fb = rec.features(clf, xb)
    seed0 = ctx.seeds[0]
    counts = np.bincount(ya, minlength=C)
    mm_classes = int((counts >= 2).sum())
    count_note = (f"N = {len(ia)} windows (half A of the test windows: conditioning, and the set scored) vs "
                  f"{len(ib)} real windows of half B (FID reference); diversity {rec.DIVERSITY_PAIRS} pairs, "
                  f"multimodality {rec.MULTIMODALITY_PAIRS} pairs x {mm_classes} classes with >= 2 windows; "
                  + feat_note)

    def scores(x: np.ndarray, seed: int) -> dict[str, float]:
        f = rec.features(clf, x)
        return {"FID": rec.fid(fb, f),
                "Recognition accuracy": float((rec.predict(clf, x) == ya).mean()),
                "Diversity": rec.diversity(f, seed=seed),
                "Multimodality": (rec.multimodality(f, ya, seed=seed, skip_small=True) if mm_classes else math.nan)}

    def add_row(method: str, per_seed: list[dict[str, float]], kind: str, condition: str, note: str,
                run_name: str = "") -> None:
        for metric in METRICS:
            kw = dict(paper=PAPER, table=TABLE, compare_to=f"{ctx.name} (ours)", metric=GROUP, column=metric,
                      method=method, condition=condition, n=len(ia), kind=kind, run=run_name,
                      key=f"generative/{metric.lower().replace(' ', '_')}", note=note)
            if len(per_seed) > 1:
                ctx.add_seeds([d[metric] for d in per_seed], **kw)
            else:
                ctx.add(value=per_seed[0][metric], **kw)

    add_row(REAL_ROW, [scores(xa, seed0)], "reference",
            "real test windows of half A scored like generated ones (FID against half B)",
            "Action2Motion's 'Real' row: the FID of a perfect generator at these sample counts; " + count_note)
    noise = np.random.default_rng(seed0).standard_normal(xa.shape).astype(np.float32)
    add_row(NOISE_ROW, [scores(noise, seed0)], "reference",
            "i.i.d. N(0, 1) poses in normalised units, labelled with half A's classes",
            f"calibration: no motion at all; seed {seed0}; " + count_note)

    # ---- physical metrics setup (3-D)
    phys = bool(o["physical"]) and test.rep.get("space") == "3d"
    skel = None
    if phys:
        tr = ctx.dataset_cfg["training"]
        skel_path = ctx.paths["processed"] / ctx.name / tr["representation"] / "skeleton.json"
        if not skel_path.exists():
            raise FileNotFoundError(f"{skel_path}: the bone-length error needs the representation's skeleton")
        skel = Skeleton.load(skel_path)
        if skel.num_joints != test.pose.shape[1]:
            raise ValueError(f"{skel_path} has {skel.num_joints} joints, the poses {test.pose.shape[1]}")
        feet = skel.indices(list(skel.feet)) if skel.feet else None
        raw_a = ctx.raw(test, ia)
        has_traj = test.controls is not None

    def physical(pose: np.ndarray, root: np.ndarray | None, start: int) -> dict[str, float]:
        """Physical metrics of frames ``start - 1 ..`` (``start`` = seed length) of ``pose`` (metres)."""
        s0 = max(start - 1, 0)
        be = bone_length_error(pose[:, s0:], skeleton=skel)
        out = {"Bone length error|abs (m)": be.abs_error, "Bone length error|relative": be.rel_error}
        if root is not None and feet is not None and pose.shape[1] - s0 >= 2:
            g = ctx.global_positions(pose[:, s0:], root[:, s0:])
            fs = foot_skating_ratio(g, fps, feet)
            out["Foot skating ratio|ratio"] = fs.ratio
            out["_contact"] = fs.contact_ratio
        return out

    def add_physical(method: str, per_seed: list[dict[str, float]], kind: str, condition: str, note: str,
                     run_name: str = "") -> None:
        for key in [k for k in per_seed[0] if not k.startswith("_")]:
            metric, column = key.split("|")
            kw = dict(paper=PAPER, table=TABLE, compare_to=f"{ctx.name} (ours)", metric=GROUP,
                      column=f"{metric}, {column}",
                      method=method, condition=condition, n=len(ia), kind=kind, run=run_name,
                      key=f"generative/{metric.lower().replace(' ', '_')}/{column.split(' ')[0]}", note=note)
            if metric == "Foot skating ratio" and "_contact" in per_seed[0]:
                contact = float(np.mean([d["_contact"] for d in per_seed]))
                kw["note"] = note + f"; transitions with a foot in contact: {contact:.3f}"
                if contact < 0.05:
                    kw["note"] += (" (feet almost never within 5 cm of the floor: a ratio near 0 means floating "
                                   "feet here, not clean contacts)")
            if len(per_seed) > 1:
                ctx.add_seeds([d[key] for d in per_seed], **kw)
            else:
                ctx.add(value=per_seed[0][key], **kw)

    if phys:
        gt = physical(raw_a["pose"], raw_a["root"], 0)
        gt_note = (f"ground truth of half A ({len(ia)} windows x {T} frames, {fps:g} fps), metres; bone rest "
                   f"lengths from skeleton.json; feet {list(skel.feet)}")
        if not has_traj and feet is not None:
            local = foot_skating_ratio(raw_a["pose"], fps, feet).ratio
            gt_note += (f"; foot skating in WORLD space (the models here generate root-relative poses only, so theirs "
                        f"is not reported: in the root frame the ground truth itself scores {local:.3f}, i.e. the "
                        f"root-frame ratio measures locomotion, not skating)")
        add_physical(REAL_ROW, [gt], "reference", "real test windows (half A)", gt_note)

    # ---- sample spread: root joint and units
    tr = ctx.dataset_cfg["training"]
    names = json.loads((ctx.paths["processed"] / ctx.name / tr["representation"] / "skeleton.json").read_text())["names"]
    root_name = (ctx.dataset_cfg.get("skeleton") or {}).get("root")
    root_j = names.index(root_name) if root_name in names else None
    units = "metres" if test.rep.get("space") == "3d" else "pixels"
    real_a = raw_a if phys else ctx.raw(test, ia)                              # physical windows of half A
    spread_root = real_a["root"] if test.rep.get("space") != "3d" else None

    # ---- jitter (module docstring): the real reference over whole windows; per seed length for "relative"
    real_jitter: dict[int, float] = {}

    def real_jitter_from(start: int) -> float:
        if start not in real_jitter:
            real_jitter[start] = jitter(real_a["pose"], start)
        return real_jitter[start]

    jit_frame = (f"{units} per frame² at {fps:g} fps, joint positions as generated ("
                 + ("root-relative, facing-normalised: no trajectory" if units == "metres" else
                    "centred image coordinates") + ")")

    def add_jitter(method: str, per_seed: list[tuple[float, float]], kind: str, condition: str, note: str,
                   run_name: str = "") -> None:
        """``per_seed``: ``(jitter, jitter / real jitter over the same frames)`` per generation seed."""
        for i, (column, key, what) in enumerate(((JITTER, JITTER_KEY, f"mean acceleration magnitude, {jit_frame}"),
                                                 (JITTER_REL, JITTER_REL_KEY, "the jitter over the ground truth's of "
                                                  "the same windows and frames (1 = as smooth as real motion)"))):
            kw = dict(paper=PAPER, table=TABLE, compare_to=f"{ctx.name} (ours)", metric=GROUP, column=column,
                      method=method, condition=condition, n=len(ia), kind=kind, run=run_name, key=key,
                      note=f"{note}; {what}")
            if len(per_seed) > 1:
                ctx.add_seeds([d[i] for d in per_seed], **kw)
            else:
                ctx.add(value=per_seed[0][i], **kw)

    add_jitter(REAL_ROW, [(real_jitter_from(1), 1.0)], "reference", "real test windows (half A)",
               f"ground truth of half A, every frame of its {len(ia)} windows x {T} frames (the reference of "
               "'relative', which is 1 here by definition)")

    # ---- the models
    timings = {}
    meths = methods(ctx, test, T)
    replicas = replica_methods(ctx, test, T, meths)
    for m in meths:
        t0 = time.perf_counter()
        stochastic = ctx.is_stochastic(lambda b, seed: m.fn(b, seed).z, batch_a, o["stochastic_check_windows"])
        seeds = ctx.seeds if stochastic else [seed0]
        reps = replicas.get(id(m), [])
        per, per_phys, per_jit = [], [], []
        for fn, s in [(f, s) for f in [m.fn, *(r.fn for r in reps)] for s in seeds]:   # training x evaluation seeds
            ctx.torch_seed(s)
            g = fn(batch_a, s)
            if g.z.shape != tuple(batch_a.pose.shape):
                raise ValueError(f"{m.name}: generated {g.z.shape}, expected {tuple(batch_a.pose.shape)}")
            if not np.isfinite(g.z).all():
                raise ValueError(f"{m.name} ({m.run}): generated motion holds NaN or inf")
            per.append(scores(np.ascontiguousarray(g.z.reshape(len(g.z), T, -1)[:, ::step]), s))
            pose = ctx.physical(test, g.z, spread_root)                               # [N, T, J, D] m / px
            jit = jitter(pose, g.seed_len)
            per_jit.append((jit, jit / real_jitter_from(g.seed_len)))
            if phys:
                root = None
                if has_traj and g.controls is not None:
                    root = integrate_controls(g.controls, fps, raw_a["root"][:, 0])      # [B, T, 3], batched
                per_phys.append(physical(pose, root, g.seed_len))
        det = "" if stochastic else ("deterministic (same seed frames and class -> same motion: one generation; "
                                     "its multimodality comes from the different seed windows only, a "
                                     "per-condition multimodality would be 0 by construction); ")
        sto = f"stochastic: mean +- std over seeds {list(seeds)}; " if stochastic else ""
        if reps:
            sto = (f"{ctx.seeds_note([m.source, *(r.source for r in reps)])} x {len(seeds)} evaluation seed(s) "
                   f"{list(seeds)}; ")
        kind = ctx.kind(m.run) if m.run in ctx.runs else "model"
        add_row(m.name, per, kind, m.condition, det + sto + count_note, m.run)
        spread, spread_note = 0.0, "deterministic: every draw is the same motion"
        if stochastic:
            draws = []
            for i in range(o["spread_samples"]):
                ctx.torch_seed(seed0 + i)
                draws.append(ctx.physical(test, m.fn(batch_a, seed0 + i).z, spread_root))
            spread = sample_spread(np.stack(draws), root_j, o["spread_from_frame"] - 1)
            spread_note = (f"{o['spread_samples']} draws (seeds {seed0}..{seed0 + o['spread_samples'] - 1}) per "
                           f"window of half A ({len(ia)} windows, the same conditioning: {m.condition})"
                           + (f"; run {m.source} (training seed 0) only" if reps else ""))
        ctx.add(paper=PAPER, table=TABLE, compare_to=f"{ctx.name} (ours)", metric=GROUP, column=SPREAD,
                method=m.name, condition=m.condition, value=spread, n=len(ia), kind=kind, run=m.run,
                key="generative/sample_spread",
                note=f"{spread_note}; std across draws of the root-relative joint positions, mean over joints and "
                     f"frames {o['spread_from_frame']}..{T} ({units})")
        t0_jit = max(g.seed_len, 1)                                             # 0-based first centre
        add_jitter(m.name, per_jit, kind, m.condition,
                   (sto or "deterministic; ") + f"generated frames only: accelerations centred on frames "
                   f"{t0_jit + 1}..{T - 1} of {T} (1-based; the first reaches back to frame {t0_jit}, the last seed "
                   "frame)", m.run)
        if phys:
            pnote = (det + sto + "generated frames only (from the last seed frame), metres; "
                     + ("world positions from the model's own controls (integrated)" if "Foot skating ratio|ratio"
                        in per_phys[0] else "root-relative poses (no trajectory: foot skating not reported)"))
            add_physical(m.name, per_phys, kind, m.condition, pnote, m.run)
        timings[m.name] = round(time.perf_counter() - t0, 2)
    log.info("%s: generative suite %.1f s (classifier %.1f s, %s); per method %s", ctx.name,
             time.perf_counter() - t_start, t_clf, "cached" if cmeta.get("cached") else "trained", timings)

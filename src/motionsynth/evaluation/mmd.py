"""GlocalNet Table 3: MMD_avg and MMD_seq on the Human3.6M 2-D benchmark, with calibration rows.

What is measured
----------------
Every trained model of the dataset (``ctx.runs``; on ``h36m``: GloGen, ERD, LSTM-3LR, Seq2Seq,
acLSTM, Scheduled Sampling, Zero-velocity) is given the ``seed_poses`` = 10 poses before each drawn
real clip (see Clips) and its class label and generates the next ``predicted`` = 50 poses
(``model.generate(seed, labels=..., length=60)[:, 10:60]``). The 50 generated poses are compared
with the 50-pose real clips of the same class by :func:`motionsynth.metrics.mmd.mmd` (the SA-GCN /
c-SkeletonGAN reference definition; its docstring has the details):

* kernel ``exp(-||x - y||^2 / b)`` for ``b = 1e-4, 1e-3, ..., 1e9``, the maximum over ``b``;
  the unbiased ``MMD^2_u`` (diagonal removed), then the square root; per class (at most
  ``max_per_class`` = 2000 samples a side), then the plain mean over the classes;
* ``MMD_avg``: the mean over the 50 frames of the per-frame MMD (each pose one 30-vector);
  ``MMD_seq``: each 50-pose clip flattened to one 1500-vector;
* ``velocity MMD_avg`` / ``velocity MMD_seq`` (ours, not in the paper): the same on the 49
  frame-to-frame differences of the 50 compared poses (``velocity=True``): the motion-sensitive
  variant (a pose held still has velocity 0 everywhere).

GloGen's loss ablation (GlocalNet Table 2, eq. 5 with one term: ``GloGen (L_J)``, ``GloGen (L_MF)``):
every trained run whose model is a GloGen and whose config is a variant of another model's
(``model.overrides_as``; :func:`motionsynth.evaluation.horizon.glogen_runs`, by class and config,
not by name) is a model like any other here: rows of its own under its config's label, in both
protocols and with the velocity columns, its note giving its loss weights. The full GloGen's rows
are unchanged. The paper's ablation is on NTU RGB+D 2-D; the report's GlocalNet Table 2 section
sets these rows beside it (the orderings only are comparable).

Space and units: the models' own normalised space, which is the reference's (SA-GCN's
``create_2d_data_corrected``; ``bench2d`` under the ``csgan`` protocol, ``conf/dataset/h36m.yaml``):
camera 55011271 alone; 15 joints x 2 image coordinates centred on the hip; multiplied by the hip's
camera depth over ``avg_z``, its mean over every 50 Hz frame of the five training subjects (S1, S5,
S7, S8, S9, the validation carve-out included); then standardised per dimension with the mean and
std (ddof 0) of those same frames. ``tests/test_csgan_reference.py`` pins these statistics to an
independent implementation of the reference's steps (equal within 1e-6 relative). The figures are
unitless; the poses are at 16.7 Hz (every third 50 Hz frame). (Until issue 12 ``csgan`` pooled all
4 cameras and took its statistics over the train split alone, another space, up to 1.78 std units
from this one; that version is the protocol ``csgan_4cam``, labelled ours.)

Clips: the reference's sampler (SA-GCN ``train.py: h36m_data_loader``)
--------------------------------------------------------------------
A *take* is one source sequence seen by the protocol's camera: ``N`` frames at the source rate (50
Hz), prepared as its ``k`` = 3 phase sequences (``all_phases``, :mod:`motionsynth.data.prepare`),
``k`` = source rate / pose rate. A clip of a take starts at a frame ``t`` drawn uniformly from the
integers ``min_start .. N - 1 - k * predicted``, both ends included (``evaluate.mmd.min_start`` =
300: the first 6 s are never used; the upper end is the reference's ``N - 1 - 150``), and holds the
frames ``t, t + k, ..., t + k * (predicted - 1)``: 50 poses at 16.7 Hz, at any of the 3 phases (the
pose ``t // k`` of phase sequence ``t mod k``). The ``seed_poses`` poses before it at the same phase
(frames ``t - 30 .. t - 3``; ``t >= 300`` leaves room; a smaller ``min_start`` is raised to ``k *
seed_poses``) seed the models, so GloGen's 10 + 50 protocol is kept; the reference's generator
takes no seed. A take too short for one clip is left out (the condition counts them).

Per class, ``evaluate.mmd.per_class`` = 100 clips a side (10 classes: 1000, the reference's test
batch, GlocalNet sec. 4.2): clip ``i`` of a class comes from its take ``i mod m`` (``m`` takes, in
the prepared order: subject, action, trial), as the reference's loader visits every sequence of an
action in turn and cuts one clip at a fresh random start per visit. Choices where the reference is
vague or unseeded: the count is per class (the reference's batch is balanced only because each of
its actions has 10 training takes), and the draws are seeded (numpy ``default_rng([seed, protocol,
0])`` for the real set; the reference calls Python's ``random`` unseeded). Every model and every
calibration row is scored against the same real clips.

Two protocols (``Row.protocol``), the same procedure on two pools of takes
-------------------------------------------------------------------------
For pool ``p``, ``R_p`` = the clips drawn from it as above. The models are seeded with the 10 poses
before each clip of ``R_p`` and their 50 generated poses are scored against the real clips ``R_p``:
the batch of generated continuations against the batch of real clips they continue.

* **test split (ours)**: ``p`` = the takes of the csgan test split, subject S11, which no model saw.
* **train split (reference code)**: ``p`` = the takes of every training subject (S1, S5, S7, S8, S9:
  the csgan train split *and* its validation carve-out), which the SA-GCN / c-SkeletonGAN
  evaluation code draws its real clips from (its test loader reads the training set; it has no
  carve-out): the rows to set beside the published numbers. The models trained on the train
  split's windows (60 poses from frame 0, stride 10, every phase) and chose their checkpoint on
  the validation takes. Choice: the models are seeded with these training-subject clips, rather
  than with test clips, so that they stand on the same footing as the real-data rows of this
  protocol (a generated set seeded from other clips would be compared with clips it has no
  relation to, while the still pose and the reversed clips below are derived from the real set
  itself).

Calibration rows (``kind="reference"``), per protocol, from real data and no model:

* ``Real <p> clips, 2nd draw``: another draw of the same sampler from the same pool (its own
  seed): the same takes, other random starts, as a second batch of the reference's loader. A clip
  of it may overlap in time with a clip of ``R_p`` of the same take; this level is therefore low.
* ``Real train clips`` (test protocol) / ``Real test clips`` (train protocol): the real last 50
  poses of ``R_train`` against those of ``R_test``; one number for both (MMD is symmetric;
  deterministic): the gap between subjects.
* ``Still real pose``: each real clip of ``R_p`` replaced by one of its own 50 poses (a random one)
  held for all 50 frames. Its velocity columns are exactly those of any still sequence (all
  velocities 0), so they equal Zero-velocity's and do not vary over seeds (the row's mean over the
  seeds of that one value may differ from it in the last bit).
* ``Reversed real clips``: the real clips of ``R_p`` played backwards (deterministic).
* ``Gaussian noise``: independent normal vectors per sample and frame with, per class and dimension,
  the mean and std of the real clips of ``R_p``.

Stochastic generators (the GAN family, measured by :meth:`EvalContext.is_stochastic`: two seeds, four
clips) generate once per seed of ``ctx.seeds`` (torch seeded with it before each protocol's batch) and
report mean +- std over the seeds, like the random calibration rows; deterministic models one value.
A run with training-seed replicas (``<run>-seed<k>``, :meth:`EvalContext.replicas`; on ``h36m`` the three
GANs) reports one row: mean +- std over every (training seed, evaluation seed) pair, so its std holds the
spread of the training itself, which for a GAN is far larger than that of its evaluation seeds.

Random rows are repeated for every seed of ``ctx.seeds`` (numpy ``default_rng([seed, i])``, ``i`` the
protocol's index; one generator per seed for the 2nd draw, the still poses and the noise, in that order) and
reported as mean +- std over seeds (``ctx.add_seeds``). The models are deterministic at evaluation
(GloGen without dropout, the recurrent baselines, zero-velocity): one value, note "deterministic".
The velocity figures of still sequences (every velocity exactly 0: the still pose, Zero-velocity)
are computed once per protocol and reused: the same inputs give the same result.

Negative estimates: ``MMD^2_u`` is unbiased and so now and then negative when the two sets are
alike. We clamp it at 0, cell by cell, before the square root (``negative="clamp"``, default);
the reference takes ``sqrt`` of the negative value, gets NaN and silently drops that bandwidth.
Every row's note counts the cells that were negative at the reported bandwidth. Cross term: the
standard estimator over all cross pairs (``cross="full"``, independent of sample order); the
reference's ``paired`` variant and its NaN-dropping are options (``evaluate.mmd.cross`` /
``negative``) for a reference-exact run (the suite gives equal counts per class, as it needs).

What MMD can and cannot tell
----------------------------
MMD_avg and MMD_seq compare *distributions of poses* (per frame, or of whole clips) with a Gaussian
kernel whose width is chosen afterwards to make the discrepancy largest. They can tell whether
generated poses lie where real poses of the class lie, and they do separate a model that drifts
away from the poses of the class (large MMD) from one that stays among them. They cannot tell
whether the motion is plausible, or whether there is motion at all: the order of frames and the
amount of movement hardly count, and with the generated batch seeded from the real batch, staying
close to the seed pose is rewarded. The issue behind this suite measured it with the reference code
on this benchmark: scored against training-subject clips (the reference protocol), one real pose
held still for 50 frames scores MMD_avg 0.018 / MMD_seq 0.071 and real clips played backwards
0.025 / 0.061, both better than GlocalNet's published 0.103 / 0.102; scored against held-out S11,
real training-subject clips score 0.184 / 0.183 and the still pose 0.173 / 0.197. So a low MMD_avg
or MMD_seq shows neither motion quality nor, on the train-split protocol, generalisation (it
rewards reproducing the training subjects). This table's calibration rows show the same with our
own numbers (``Still real pose``, ``Reversed real clips`` and the Zero-velocity baseline against
the models and the published figures), and the velocity columns are the motion-sensitive check:
there a still pose, and Zero-velocity, score about 1 (as far from real motion as Gaussian noise),
while reversed clips keep their speeds and pass. Read a model's MMD against these rows, never alone.

Other outputs: ``ctx.curve("mmd_per_class", method, class names, values)`` (test protocol, MMD_avg
per class; random calibration rows as their mean over seeds) and ``ctx.sample``:
``animation.sequences`` clips of ``R_test`` spread evenly over it, ground truth and every model's 60
poses (10 seed + 50 generated), de-normalised with the clips' own hip depth to hip-centred image
pixels (y down), ``[N, 60, 15, 2]`` (``sequences`` / ``start_frames`` in the sample metadata: the
phase sequence and its first seed pose).
"""

from __future__ import annotations

import json
import logging
import math
import time
from typing import Any

import numpy as np
import pandas as pd
import torch

from ..checks import one_of
from ..data.clips import gather
from ..data.types import ConfigError
from ..metrics.mmd import CROSS, NEGATIVE, MMDResult, mmd
from ..models.base import Batch
from .context import EvalContext, slug
from .horizon import ablation_note, glogen_runs

log = logging.getLogger(__name__)

PAPER = "battan2021_glocalnet"
TABLE = "Table 3"
#: the ``dataset`` string of Table 3 in published_results.csv (the report joins on it)
COMPARE_TO = "Human3.6M 2D (10 classes, 15 joints, ~16 Hz; 10 input, 50 predicted frames)"
METRIC = "MMD"
#: figure -> (column, mode, velocity); the first two columns are the paper's
FIGURES = {"mmd_avg": ("MMD_avg", "avg", False), "mmd_seq": ("MMD_seq", "seq", False),
           "mmd_vel_avg": ("velocity MMD_avg", "avg", True), "mmd_vel_seq": ("velocity MMD_seq", "seq", True)}
PROTOCOLS = {"test": "test split (ours)", "train": "train split (reference code)"}
#: the splits whose takes each protocol draws its real clips from (the reference's: every training subject)
POOLS = {"test": ("test",), "train": ("train", "val")}
SUBJECTS = {"test": "S11", "train": "S1,5,7,8,9"}
DEFAULTS: dict[str, Any] = {"per_class": 100, "seed_poses": 10, "predicted": 50, "min_start": 0, "max_per_class": 2000,
                            "negative": "clamp", "cross": "full"}


# ----------------------------------------------------------------------------- options and data


def options(ctx: EvalContext) -> dict[str, Any]:
    """``evaluate.mmd`` of the dataset config over :data:`DEFAULTS`, checked."""
    given = dict(ctx.options.get("mmd") or {})
    unknown = sorted(set(given) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.mmd has unknown key(s) {unknown}; "
                         f"known: {sorted(DEFAULTS)}")
    o = {**DEFAULTS, **given}
    for k, lo in (("per_class", 2), ("seed_poses", 1), ("predicted", 2), ("min_start", 0), ("max_per_class", 2)):
        v = o[k]
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.mmd.{k} must be an integer >= {lo}; got {v!r}")
    one_of(o["negative"], "evaluate.mmd.negative", NEGATIVE)
    one_of(o["cross"], "evaluate.mmd.cross", CROSS)
    return o


def split_table(ctx: EvalContext) -> pd.Series:
    """``sequence_id -> split`` of every prepared sequence under the dataset's training protocol."""
    tr = ctx.dataset_cfg["training"]
    path = ctx.paths["splits"] / ctx.name / tr["representation"] / f"{tr['protocol']}.csv"
    return pd.read_csv(path).set_index("sequence_id")["split"]


def takes(data, table: pd.Series, splits: tuple[str, ...]) -> tuple[pd.DataFrame, int]:
    """The takes (a source sequence in one camera view) of ``data``'s representation whose split
    (``table``: :func:`split_table`) is in ``splits``, in the prepared order, and ``k``, the number of
    phases of every take.

    One row per take: ``label``, ``seqs`` (the sequence index of phase ``p`` at position ``p``) and
    ``frames`` (``N``, its source frames: the sum of its phase sequences' frames, which hold every
    source frame once). Needs a representation prepared with ``all_phases``."""
    m = data.meta.assign(seq=np.arange(len(data.meta)), split=data.meta["sequence_id"].map(table).to_numpy())
    m = m[m["split"].isin(list(splits))]
    rows = []
    for (_, _), g in m.groupby(["source_id", "view"], sort=False):
        g = g.sort_values("phase")
        rows.append({"label": int(g["label"].iloc[0]), "seqs": g["seq"].to_numpy(), "frames": int(g["frames"].sum()),
                     "phases": tuple(g["phase"].tolist())})
    t = pd.DataFrame(rows, columns=["label", "seqs", "frames", "phases"])
    kinds = set(t["phases"])
    if len(kinds) > 1 or (kinds and next(iter(kinds)) != tuple(range(len(next(iter(kinds)))))):
        raise ValueError(f"takes with other phases than 0..k-1 for one k: {sorted(kinds)[:3]}")
    return t.drop(columns="phases"), len(next(iter(kinds))) if kinds else 1


def draw(pool: pd.DataFrame, k: int, counts: dict[int, int], o: dict[str, Any], rng: np.random.Generator
         ) -> pd.DataFrame:
    """``counts[c]`` clips of each class ``c`` (in class order) from the takes ``pool`` (see :func:`takes`),
    the reference's way (module docstring): clip ``i`` of a class from its take ``i mod m``, its start
    frame ``t`` uniform in ``max(min_start, k * seed_poses) .. N - 1 - k * predicted``.

    Returns one row per clip: ``seq``, ``start`` (the first seed pose in the phase sequence ``seq``),
    ``length`` (seed + predicted poses), ``label`` and ``frame`` (``t``, the clip's first frame at the
    source rate)."""
    S, P = o["seed_poses"], o["predicted"]
    lo = max(o["min_start"], k * S)
    out = []
    for c, n in counts.items():
        tk = pool[pool["label"] == c]
        take = tk.iloc[np.arange(n) % len(tk)]
        t = rng.integers(lo, take["frames"].to_numpy() - k * P, endpoint=False)   # high exclusive: N - k*P - 1 inclusive
        seq = np.array([s[i % k] for s, i in zip(take["seqs"], t)], dtype=np.int64)
        out.append(pd.DataFrame({"seq": seq, "start": t // k - S, "length": S + P, "label": c, "frame": t}))
    return pd.concat(out, ignore_index=True)


def usable(pool: pd.DataFrame, k: int, o: dict[str, Any]) -> pd.Series:
    """Which takes of ``pool`` are long enough for one clip (:func:`draw`'s range not empty)."""
    return pool["frames"] - 1 - k * o["predicted"] >= max(o["min_start"], k * o["seed_poses"])


def raw_clips(data, table: pd.DataFrame) -> dict[str, np.ndarray]:
    """The clips of ``table`` (:func:`draw`) in physical units: ``pose`` ``[B, S + P, J, D]`` (pixels),
    ``root`` ``[B, S + P, 3]``, float64."""
    return {"pose": gather(data.pose, data.offsets, data.frames, table).astype(np.float64),
            "root": gather(data.root, data.offsets, data.frames, table).astype(np.float64)}


def clips(data, table: pd.DataFrame) -> np.ndarray:
    """The clips of ``table`` normalised as the models see them, ``[B, S + P, J, D]`` float64."""
    r = raw_clips(data, table)
    return data.norm(r["pose"], r["root"])


def even_pick(idx: np.ndarray, n: int) -> np.ndarray:
    """``n`` of ``idx`` spread evenly (all when fewer)."""
    if n >= len(idx):
        return idx
    return idx[np.unique(np.linspace(0, len(idx) - 1, n).round().astype(int))]


def generate(model, seed: np.ndarray, labels: np.ndarray, length: int, device) -> np.ndarray:
    """``model.generate`` from normalised seed poses ``[B, S, J, D]`` and labels ``[B]`` ->
    ``[B, length, J, D]`` float64 (the seed in front)."""
    p = next(model.parameters(), None)
    s = torch.as_tensor(seed, dtype=p.dtype if p is not None else torch.float32, device=device)
    y = torch.as_tensor(labels, dtype=torch.long, device=device)
    with torch.no_grad():
        out = model.generate(s, labels=y, length=length)
    out = out.detach().cpu().numpy().astype(np.float64)
    if out.shape != (len(seed), length, *seed.shape[2:]):
        raise ValueError(f"{type(model).__name__}.generate returned shape {out.shape}; expected "
                         f"{(len(seed), length, *seed.shape[2:])}")
    return out


# ----------------------------------------------------------------------------- the calibration fakes


def still(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each clip ``[N, T, J, D]`` replaced by one of its own poses (random frame) held for all T frames."""
    t = rng.integers(0, x.shape[1], size=len(x))
    return np.repeat(x[np.arange(len(x)), t][:, None], x.shape[1], axis=1)


def noise(x: np.ndarray, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gaussian samples shaped like ``x``: per class and dimension the mean / std of ``x`` over
    clips and frames, independent over samples and frames."""
    out = np.empty_like(x)
    z = rng.standard_normal(x.shape)
    for c in np.unique(labels):
        m = labels == c
        mu, sd = x[m].mean(axis=(0, 1)), x[m].std(axis=(0, 1))
        out[m] = mu + sd * z[m]
    return out


# ----------------------------------------------------------------------------- scoring


class Scorer:
    """The four MMD figures of a fake set ``[N, P, J, D]`` against a protocol's real set.

    A figure depends on the fake set only through the features it compares and their labels. The
    velocity figures of still sequences (all velocities exactly 0: the still pose, Zero-velocity)
    are therefore the same for all of them and are computed once per protocol and label set.
    """

    def __init__(self, real: dict[str, tuple[np.ndarray, np.ndarray]], o: dict[str, Any], device):
        self.real, self.o, self.device = real, o, device
        self.still: dict[tuple, MMDResult] = {}
        self.computed = self.reused = 0

    def figure(self, proto: str, fake: np.ndarray, labels: np.ndarray, mode: str, vel: bool) -> MMDResult:
        r, rl = self.real[proto]
        self.computed += 1
        return mmd(r, fake, rl, labels, mode=mode, velocity=vel, max_per_class=self.o["max_per_class"],
                   negative=self.o["negative"], cross=self.o["cross"], device=self.device)

    def __call__(self, proto: str, fake: np.ndarray, labels: np.ndarray) -> dict[str, MMDResult]:
        fake = np.ascontiguousarray(fake, dtype=np.float64)
        labels = np.asarray(labels, dtype=np.int64)
        is_still = not (fake[:, 1:] != fake[:, :-1]).any()
        out = {}
        for key, (_, mode, vel) in FIGURES.items():
            if vel and is_still:
                k = (proto, mode, fake.shape, labels.tobytes())
                if k in self.still:
                    self.reused += 1
                else:
                    self.still[k] = self.figure(proto, fake, labels, mode, vel)
                out[key] = self.still[k]
            else:
                out[key] = self.figure(proto, fake, labels, mode, vel)
        return out


def negatives(results: list[dict[str, MMDResult]], key: str) -> str:
    """What the note says about negative MMD^2_u estimates of one figure (summed over seeds)."""
    neg = sum(r[key].n_negative for r in results)
    cells = sum(r[key].n_cells for r in results)
    dropped = sum(r[key].n_dropped for r in results)
    what = "(class, frame) cells" if FIGURES[key][1] == "avg" else "classes"
    s = f"MMD^2_u < 0 in {neg} of {cells} {what}" + (" (clamped to 0)" if neg else "")
    return s + (f"; {dropped} (class, bandwidth) pairs dropped (negative=nan)" if dropped else "")


# ----------------------------------------------------------------------------- the suite


def run(ctx: EvalContext) -> None:
    t_start = time.perf_counter()
    o = options(ctx)
    S, P = o["seed_poses"], o["predicted"]
    family = ctx.dataset_cfg["training"]["family"]
    rep_name = ctx.dataset_cfg["training"]["representation"]
    data = {"test": ctx.data(family, "test"), "train": ctx.data(family, "train")}
    if not data["test"].rep.get("all_phases"):
        raise ConfigError(f"conf/dataset/{ctx.name}.yaml: the mmd suite draws clips at any source frame, as the "
                          f"reference's sampler does; prepare.representations.{rep_name}.all_phases must be true")

    # ---- the takes each protocol draws from, and the classes
    table = split_table(ctx)
    pools, k = {}, {}
    for p, d in data.items():
        pools[p], k[p] = takes(d, table, POOLS[p])
    if k["test"] != k["train"]:
        raise AssertionError(f"{ctx.name}: {k} phases per take in the two pools")
    k = k["test"]
    short = {p: int((~usable(t, k, o)).sum()) for p, t in pools.items()}
    pools = {p: t[usable(t, k, o)].reset_index(drop=True) for p, t in pools.items()}
    meta = data["test"].meta
    names = dict(zip(meta["label"].astype(int), meta["label_name"].astype(str)))
    if (meta["label"] < 0).any():
        raise ValueError(f"{ctx.name}: the mmd suite compares per class; {int((meta['label'] < 0).sum())} prepared "
                         "sequences have no class label")
    present = sorted(set(pools["test"]["label"]) | set(pools["train"]["label"]))
    classes = [c for c in present if (pools["test"]["label"] == c).any() and (pools["train"]["label"] == c).any()]
    if not classes:
        raise ValueError(f"{ctx.name}: no class has a take long enough for a clip in both the test split and the "
                         f"training subjects (train + val)")
    left_out = [names.get(c, str(c)) for c in present if c not in classes]
    if left_out:
        log.warning("%s mmd: classes %s have no usable take in the test split or the training subjects; left out",
                    ctx.name, left_out)
    counts = {c: o["per_class"] for c in classes}
    n_total = sum(counts.values())
    R = {p: draw(pools[p], k, counts, o, np.random.default_rng([ctx.seeds[0], i, 0]))   # the real sets (and seeds)
         for i, p in enumerate(PROTOCOLS)}
    lab = np.array(R["test"]["label"], dtype=np.int64)
    if not np.array_equal(lab, R["train"]["label"].to_numpy()):
        raise AssertionError("per-class draws are not aligned by class")
    windows = {p: clips(data[p], R[p]) for p in data}                # [N, S + P, J, D] normalised
    real = {p: (w[:, S:S + P], lab) for p, w in windows.items()}
    score = Scorer(real, o, ctx.device)
    class_names = [names.get(c, str(c)) for c in classes]

    src_fps = float(data["test"].rep["fps"]) * k
    condition = (f"{S} seed + {P} predicted poses (one pose every {k} frames of {src_fps:g} Hz); real clips drawn as the "
                 f"reference's loader (start >= {max(o['min_start'], k * S)} at {src_fps:g} Hz, any phase; seeded); "
                 f"{n_total} clips a side = {len(classes)} classes x {o['per_class']}; c-SkeletonGAN normalised units "
                 f"(the reference's statistics); MMD^2_u < 0: {o['negative']}; cross term: {o['cross']}")
    if left_out:
        condition += f"; classes left out (no usable take): {', '.join(left_out)}"
    if any(short.values()):
        condition += "; takes too short for a clip: " + ", ".join(f"{n} {p}" for p, n in short.items() if n)
    base = dict(paper=PAPER, table=TABLE, compare_to=COMPARE_TO, metric=METRIC, condition=condition, n=n_total)

    def add(proto: str, method: str, results: list[dict[str, MMDResult]], note: str, **kw: Any) -> None:
        for key, (col, _, _) in FIGURES.items():
            vals = [r[key].value for r in results]
            row = dict(base, column=col, method=method, protocol=PROTOCOLS[proto],
                       key=f"mmd/{proto}/{slug(col)}", note=f"{note}; {negatives(results, key)}", **kw)
            if len(vals) > 1:
                ctx.add_seeds(vals, **row)
            else:
                ctx.add(value=float(vals[0]), **row)

    def per_class_curve(method: str, results: list[dict[str, MMDResult]]) -> None:
        vals = [float(np.mean([r["mmd_avg"].per_class[c] for r in results])) for c in classes]
        ctx.curve("mmd_per_class", method, class_names, vals)

    # ---- the models
    timings: dict[str, float] = {}
    outputs: dict[str, tuple[str, Any]] = {}
    trained = ctx.available()
    plain_glogen, ablations = glogen_runs(ctx, trained)              # by class and config, not by name
    for run_name in trained:
        t0 = time.perf_counter()
        model_name = ctx.runs[run_name]
        method = ctx.label(model_name)
        model, train_data = ctx.model(run_name)
        every = int(getattr(model.spec, "every", 1))
        if every != 1:
            log.warning("%s mmd: run %s generates sparse poses (every %d); left out (needs dense output)",
                        ctx.name, run_name, every)
            continue
        if not (np.allclose(train_data.norm.mean, data["test"].norm.mean)
                and np.allclose(train_data.norm.std, data["test"].norm.std)):
            raise ValueError(f"{ctx.name}: run {run_name} was trained with other normalisation statistics than "
                             f"the {family} test windows (another representation or protocol?)")
        few = windows["test"][:4, :S]
        stochastic = ctx.is_stochastic(lambda b, s: generate(model, b.pose.numpy(), b.labels.numpy(), S + P, ctx.device),
                                       Batch(torch.as_tensor(few), labels=torch.as_tensor(lab[:4])), 4)
        seeds = list(ctx.seeds) if stochastic else ctx.seeds[:1]
        note = (f"stochastic (a generator of noise): mean +- std over {len(seeds)} seeds ({seeds[0]}..{seeds[-1]}), "
                "one generated clip per real clip and seed" if stochastic else "deterministic")
        seed_frames = getattr(model, "seed_frames", S)
        if seed_frames != S:
            note += f"; the model's own seed_frames is {seed_frames}, given {S} here"
        if run_name in plain_glogen or run_name in ablations:
            note += (f"; {method} alone on dense poses (every 1, t_in {model.t}, t_out {model.t_out}): its output is "
                     "already dense on this benchmark, so it is the whole GlocalNet generator here (no LocGen)")
            note += ("; as the paper's Table 3 row 'Our Method (GloGen)'; the published numbers were scored on the "
                     "train split" if run_name in plain_glogen else f"; {ablation_note(model)}; the paper's Table 2 "
                     "ablation is on NTU RGB+D 2-D, not on this benchmark")
        reps = ctx.replicas(run_name)                              # training-seed replicas: <run>-seed<k>
        if reps:
            note = f"{ctx.seeds_note([run_name, *reps])} x {len(seeds)} evaluation seeds; each {note}"
        fakes = {proto: [] for proto in PROTOCOLS}
        for gen in [model, *(ctx.model(r)[0] for r in reps)]:     # one value per (training seed, evaluation seed)
            for s in seeds:
                for proto in PROTOCOLS:
                    ctx.torch_seed(s)
                    fakes[proto].append(generate(gen, windows[proto][:, :S], lab, S + P, ctx.device)[:, S:S + P])
        if not all(np.isfinite(f).all() for fs in fakes.values() for f in fs):
            log.warning("%s mmd: run %s generated non-finite poses; its rows are NaN", ctx.name, run_name)
            for proto in PROTOCOLS:
                for col, _, _ in FIGURES.values():
                    ctx.add(value=math.nan, column=col, method=method, protocol=PROTOCOLS[proto],
                            key=f"mmd/{proto}/{slug(col)}", run=run_name, kind=ctx.kind(run_name),
                            note="the model generated non-finite poses", **base)
            continue
        for proto in PROTOCOLS:
            res = [score(proto, f, lab) for f in fakes[proto]]
            add(proto, method, res, f"{note}; seeded with the {S} poses before each real clip ({SUBJECTS[proto]}) "
                "it is scored against", run=run_name, kind=ctx.kind(run_name))
            if proto == "test":
                per_class_curve(method, res)
        outputs[run_name] = (method, model)
        timings[run_name] = round(time.perf_counter() - t0, 2)

    # ---- calibration rows
    t0 = time.perf_counter()
    gap = score("test", real["train"][0], lab)  # R_train against R_test: one number for both protocols
    gap_note = ("deterministic (the real sets' seeded draws): real S1,5,7,8,9 clips against real S11 clips, the gap "
                "between subjects; the same number in both protocols (MMD is symmetric)")
    add("test", "Real train clips", [gap], gap_note, kind="reference")
    add("train", "Real test clips", [gap], gap_note, kind="reference")
    per_class_curve("Real train clips", [gap])
    for i, proto in enumerate(PROTOCOLS):
        x = real[proto][0]
        rev = score(proto, x[:, ::-1], lab)
        add(proto, "Reversed real clips", [rev], "deterministic: the real clips played backwards", kind="reference")
        draws: dict[str, list[dict[str, MMDResult]]] = {"second": [], "still": [], "noise": []}
        for s in ctx.seeds:
            rng = np.random.default_rng([s, i])
            other = draw(pools[proto], k, counts, o, rng)
            draws["second"].append(score(proto, clips(data[proto], other)[:, S:S + P], lab))
            draws["still"].append(score(proto, still(x, rng), lab))
            draws["noise"].append(score(proto, noise(x, lab, rng), lab))
        seeds = f"{len(ctx.seeds)} random draws (seeds {ctx.seeds[0]}..{ctx.seeds[-1]})"
        rows = {"second": (f"Real {proto} clips, 2nd draw",
                           f"{seeds} of the same sampler from the same takes ({SUBJECTS[proto]}): other random "
                           "starts (a clip may overlap in time with one of the real set: this level is low)"),
                "still": ("Still real pose", f"{seeds}: each real clip's own random pose held for {P} frames "
                                             "(velocity columns: every still sequence scores the same)"),
                "noise": ("Gaussian noise", f"{seeds}: i.i.d. normal poses with the real clips' per-class, "
                                            "per-dimension mean and std")}
        for key, (method, note) in rows.items():
            add(proto, method, draws[key], note, kind="reference")
            if proto == "test":
                per_class_curve(method, draws[key])
        if proto == "test":
            per_class_curve("Reversed real clips", [rev])
    timings["calibration"] = round(time.perf_counter() - t0, 2)

    # ---- animation samples: animation.sequences clips of R_test, spread evenly over it
    n_anim = int((ctx.opts.get("animation") or {}).get("sequences", 0))
    if n_anim > 0:
        test = data["test"]
        pick = R["test"].iloc[even_pick(np.arange(len(R["test"])), n_anim)]
        raw = raw_clips(test, pick)
        z = test.norm(raw["pose"], raw["root"])
        skel = json.loads((ctx.paths["processed"] / ctx.name / rep_name / "skeleton.json").read_text())
        ctx.sample("ground truth", raw["pose"], fps=float(test.rep["fps"]), parents=skel["parents"],
                   joints=skel["names"], space="2d", seed_frames=S, trajectory=False,
                   frame="hip-centred image coordinates (y down); no trajectory: the models predict none",
                   units="pixels", sequences=[str(x) for x in meta["sequence_id"].to_numpy()[pick["seq"].to_numpy()]],
                   start_frames=[int(x) for x in pick["start"]],
                   title=f"{ctx.name}: GlocalNet Table 3 protocol, test clips at {src_fps:g} Hz frames "
                         f"{[int(f) for f in pick['frame']]}, {S} seed + {P} generated poses")
        for run_name, (method, model) in outputs.items():
            ctx.torch_seed(ctx.seeds[0])
            g = generate(model, z[:, :S], np.array(pick["label"], dtype=np.int64), S + P, ctx.device)
            ctx.sample(method, ctx.physical(test, g, raw["root"]))

    timings["total"] = round(time.perf_counter() - t_start, 2)
    log.info("%s mmd: %d clips a side (%d classes); %d MMD figures computed, %d reused; timings %s",
             ctx.name, n_total, len(classes), score.computed, score.reused, timings)

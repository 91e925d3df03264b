"""GlocalNet Table 3: MMD_avg and MMD_seq on the Human3.6M 2-D benchmark, with calibration rows.

What is measured
----------------
Every trained model of the dataset (``ctx.runs``; on ``h36m``: GloGen, ERD, LSTM-3LR, Seq2Seq,
acLSTM, Scheduled Sampling, Zero-velocity) is given the first ``seed_poses`` = 10 poses of each
chosen window and its class label and generates the next ``predicted`` = 50 poses
(``model.generate(seed, labels=..., length=60)[:, 10:60]``). The 50 generated poses are compared
with 50-pose real clips of the same class by :func:`motionsynth.metrics.mmd.mmd` (the SA-GCN /
c-SkeletonGAN reference definition; its docstring has the details):

* kernel ``exp(-||x - y||^2 / b)`` for ``b = 1e-4, 1e-3, ..., 1e9``, the maximum over ``b``;
  the unbiased ``MMD^2_u`` (diagonal removed), then the square root; per class (at most
  ``max_per_class`` = 2000 samples a side), then the plain mean over the classes;
* ``MMD_avg``: the mean over the 50 frames of the per-frame MMD (each pose one 30-vector);
  ``MMD_seq``: each 50-pose clip flattened to one 1500-vector;
* ``velocity MMD_avg`` / ``velocity MMD_seq`` (ours, not in the paper): the same on the 49
  frame-to-frame differences of the 50 compared poses (``velocity=True``): the motion-sensitive
  variant (a pose held still has velocity 0 everywhere).

Space and units: the models' own normalised space, the c-SkeletonGAN normalisation of ``bench2d``
(15 joints x 2 image coordinates centred on the hip, multiplied by the hip's camera depth over its
mean train depth, then standardised per dimension with the csgan train split's mean and std). The
reference compares in this space too. The figures are unitless; the 2-D poses are at 16.7 Hz
(every third 50 Hz frame), windows of 60 poses with stride 10 (the ``glocal`` family of ``bench2d``).

Samples: ``evaluate.mmd.per_class`` (default 100) windows per class and side, ``n_c =
min(per_class, windows of the class in the split // 2)`` (halved so that a disjoint second draw
exists); 100 x 10 classes on the full data, the reference's test batch of 1000 (GlocalNet sec. 4.2)
and the sample size of the issue's calibration measurement. ``eval.max_windows`` is not used: MMD
is a two-sample statistic per class and needs this many per class.

Two protocols (``Row.protocol``), the same procedure on two splits
-----------------------------------------------------------------
For split ``p``, ``R_p`` = ``n_c`` windows per class spread evenly over the class's windows (in
window order, deterministic). The models are seeded with the first 10 poses of ``R_p`` and their 50
generated poses are scored against the real last 50 poses of the same windows ``R_p``: the batch of
generated continuations against the batch of real clips they were seeded from, which is how the
reference evaluation code pairs them (a generated batch from the real batch's seeds).

* **test split (ours)**: ``p`` = the csgan test split, subject S11, which no model saw.
* **train split (reference code)**: ``p`` = the csgan train split (S1, S5, S7, S8, S9; not the
  ``val`` sequences), which the SA-GCN / c-SkeletonGAN evaluation code scores on and on which the
  models were trained: the rows to set beside the published numbers. Choice: the models are seeded
  with training windows here, as the reference does, rather than with test windows, so that they
  stand on the same footing as the real-data rows of this protocol (a generated set seeded from
  other clips would be compared with clips it has no relation to, while the still pose and the
  reversed clips below are derived from the real set itself).

Calibration rows (``kind="reference"``), per protocol, from real data and no model:

* ``Real <p> clips, 2nd draw``: ``n_c`` other windows per class of the same split, drawn at
  random outside ``R_p``. Windows of one sequence overlap in time (stride 10 poses), so a
  second-draw window may share frames with a window of ``R_p``; this level is therefore low.
* ``Real train clips`` (test protocol) / ``Real test clips`` (train protocol): the real last 50
  poses of ``R_train`` against those of ``R_test``; one number for both (MMD is symmetric;
  deterministic): the gap between subjects.
* ``Still real pose``: each real clip of ``R_p`` replaced by one of its own 50 poses (a random one)
  held for all 50 frames. Its velocity columns are exactly those of any still sequence (all
  velocities 0), so they equal Zero-velocity's and do not vary over seeds.
* ``Reversed real clips``: the real clips of ``R_p`` played backwards (deterministic).
* ``Gaussian noise``: independent normal vectors per sample and frame with, per class and dimension,
  the mean and std of the real clips of ``R_p``.

Random rows are repeated for every seed of ``ctx.seeds`` (numpy ``default_rng([seed, k])``) and
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
per class; random calibration rows as their mean over seeds) and ``ctx.sample``: the first
``animation.sequences`` windows of ``ctx.pick`` over the test windows, ground truth and every
model's 60 poses (10 seed + 50 generated), de-normalised with the windows' own hip depth to
hip-centred image pixels (y down), ``[N, 60, 15, 2]``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from typing import Any

import numpy as np
import torch

from ..checks import one_of
from ..metrics.mmd import CROSS, NEGATIVE, MMDResult, mmd
from .context import EvalContext, slug

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
SUBJECTS = {"test": "S11", "train": "S1,5,7,8,9"}
DEFAULTS: dict[str, Any] = {"per_class": 100, "seed_poses": 10, "predicted": 50, "max_per_class": 2000,
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
    for k, lo in (("per_class", 2), ("seed_poses", 1), ("predicted", 2), ("max_per_class", 2)):
        v = o[k]
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.mmd.{k} must be an integer >= {lo}; got {v!r}")
    one_of(o["negative"], "evaluate.mmd.negative", NEGATIVE)
    one_of(o["cross"], "evaluate.mmd.cross", CROSS)
    return o


def window_labels(data) -> np.ndarray:
    """Class label of every window ``[len(data)]``."""
    return np.asarray(data.labels)[data.windows["seq"].to_numpy()].astype(np.int64)


def even_pick(idx: np.ndarray, n: int) -> np.ndarray:
    """``n`` of ``idx`` spread evenly (all when fewer)."""
    if n >= len(idx):
        return idx
    return idx[np.unique(np.linspace(0, len(idx) - 1, n).round().astype(int))]


def per_class(labels: np.ndarray, counts: dict[int, int], exclude: np.ndarray | None = None,
              rng: np.random.Generator | None = None) -> np.ndarray:
    """Window indices, ``counts[c]`` of each class ``c`` (in class order), none of ``exclude``:
    spread evenly in window order, or drawn at random without replacement with ``rng``."""
    out = []
    for c, n in counts.items():
        idx = np.flatnonzero(labels == c)
        if exclude is not None:
            idx = np.setdiff1d(idx, exclude)
        if len(idx) < n:
            raise ValueError(f"class {c}: {len(idx)} windows, {n} needed")
        out.append(even_pick(idx, n) if rng is None else np.sort(rng.choice(idx, n, replace=False)))
    return np.concatenate(out)


def clips(data, idx: np.ndarray) -> np.ndarray:
    """Normalised windows ``[B, T, J, D]`` float64 (the models' space)."""
    return data.batch(idx).pose.numpy().astype(np.float64)


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
    data = {"test": ctx.data(family, "test"), "train": ctx.data(family, "train")}
    for split, d in data.items():
        if len(d) == 0:
            raise ValueError(f"{ctx.name}: no {family} windows in the {split} split")
        if d.every != 1 or d.length < S + P:
            raise ValueError(f"{ctx.name}: the mmd suite needs dense windows (every 1) of >= {S + P} poses "
                             f"(evaluate.mmd.seed_poses + predicted); the {split} split's {family} windows have "
                             f"{d.length} poses every {d.every}")

    # ---- classes and windows
    labels = {p: window_labels(d) for p, d in data.items()}
    for p, v in labels.items():
        if (v < 0).any():
            raise ValueError(f"{ctx.name}: the mmd suite compares per class; {int((v < 0).sum())} {p} windows "
                             "have no class label")
    names = dict(zip(data["test"].meta["label"].astype(int), data["test"].meta["label_name"].astype(str)))
    size = 1 + max(int(v.max()) for v in labels.values())
    count = {p: np.bincount(v, minlength=size) for p, v in labels.items()}
    present = sorted(set(labels["test"].tolist()) | set(labels["train"].tolist()))
    classes = [c for c in present if min(count["test"][c], count["train"][c]) >= 4]
    if not classes:
        raise ValueError(f"{ctx.name}: no class has >= 4 {family} windows in both the test and the train split")
    left_out = [names.get(c, str(c)) for c in present if c not in classes]
    if left_out:
        log.warning("%s mmd: classes %s have < 4 windows in the test or the train split; left out", ctx.name, left_out)
    counts = {c: int(min(o["per_class"], count["test"][c] // 2, count["train"][c] // 2)) for c in classes}
    n_total = sum(counts.values())
    R = {p: per_class(labels[p], counts) for p in data}              # the real sets (and the models' seeds)
    lab = labels["test"][R["test"]]
    if not np.array_equal(lab, labels["train"][R["train"]]):
        raise AssertionError("per-class picks are not aligned by class")
    windows = {p: clips(data[p], R[p]) for p in data}                # [N, S + P, J, D] normalised
    real = {p: (w[:, S:S + P], lab) for p, w in windows.items()}
    score = Scorer(real, o, ctx.device)
    class_names = [names.get(c, str(c)) for c in classes]

    condition = (f"{S} seed + {P} predicted poses (16.7 Hz); {n_total} clips a side = {len(classes)} classes x "
                 f"{'/'.join(sorted({str(v) for v in counts.values()}))}; c-SkeletonGAN normalised units; "
                 f"MMD^2_u < 0: {o['negative']}; cross term: {o['cross']}")
    if left_out:
        condition += f"; classes left out (too few windows): {', '.join(left_out)}"
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
    for run_name in ctx.available():
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
        note = "deterministic"
        seed_frames = getattr(model, "seed_frames", S)
        if seed_frames != S:
            note += f"; the model's own seed_frames is {seed_frames}, given {S} here"
        if model_name == "glogen":
            note += ("; GloGen alone on dense poses (every 1, t_in 10, t_out 50): its output is already dense on "
                     "this benchmark, so it is the whole GlocalNet generator here (no LocGen), as the paper's "
                     "Table 3 row 'Our Method (GloGen)'; the published numbers were scored on the train split")
        fakes = {}
        for proto in PROTOCOLS:
            ctx.torch_seed(ctx.seeds[0])
            fakes[proto] = generate(model, windows[proto][:, :S], lab, S + P, ctx.device)[:, S:S + P]
        if not all(np.isfinite(f).all() for f in fakes.values()):
            log.warning("%s mmd: run %s generated non-finite poses; its rows are NaN", ctx.name, run_name)
            for proto in PROTOCOLS:
                for col, _, _ in FIGURES.values():
                    ctx.add(value=math.nan, column=col, method=method, protocol=PROTOCOLS[proto],
                            key=f"mmd/{proto}/{slug(col)}", run=run_name, kind=ctx.kind(run_name),
                            note="the model generated non-finite poses", **base)
            continue
        for proto in PROTOCOLS:
            res = score(proto, fakes[proto], lab)
            add(proto, method, [res], f"{note}; seeded with the {proto}-split windows ({SUBJECTS[proto]}) it is "
                "scored against", run=run_name, kind=ctx.kind(run_name))
            if proto == "test":
                per_class_curve(method, [res])
        outputs[run_name] = (method, model)
        timings[run_name] = round(time.perf_counter() - t0, 2)

    # ---- calibration rows
    t0 = time.perf_counter()
    gap = score("test", real["train"][0], lab)  # R_train against R_test: one number for both protocols
    gap_note = ("deterministic (windows spread evenly): real S1,5,7,8,9 clips against real S11 clips, the gap "
                "between subjects; the same number in both protocols (MMD is symmetric)")
    add("test", "Real train clips", [gap], gap_note, kind="reference")
    add("train", "Real test clips", [gap], gap_note, kind="reference")
    per_class_curve("Real train clips", [gap])
    for k, proto in enumerate(PROTOCOLS):
        x = real[proto][0]
        rev = score(proto, x[:, ::-1], lab)
        add(proto, "Reversed real clips", [rev], "deterministic: the real clips played backwards", kind="reference")
        draws: dict[str, list[dict[str, MMDResult]]] = {"second": [], "still": [], "noise": []}
        for s in ctx.seeds:
            rng = np.random.default_rng([s, k])
            other = per_class(labels[proto], counts, exclude=R[proto], rng=rng)
            draws["second"].append(score(proto, clips(data[proto], other)[:, S:S + P], lab))
            draws["still"].append(score(proto, still(x, rng), lab))
            draws["noise"].append(score(proto, noise(x, lab, rng), lab))
        seeds = f"{len(ctx.seeds)} random draws (seeds {ctx.seeds[0]}..{ctx.seeds[-1]})"
        rows = {"second": (f"Real {proto} clips, 2nd draw",
                           f"{seeds} of other {proto}-split windows ({SUBJECTS[proto]}) than the real set's "
                           "(windows of a sequence overlap in time, stride 10 poses: this level is low)"),
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

    # ---- animation samples: the first animation.sequences windows of ctx.pick over the test windows
    n_anim = int((ctx.opts.get("animation") or {}).get("sequences", 0))
    if n_anim > 0:
        test = data["test"]
        idx = ctx.pick(test, n_anim)
        raw = ctx.raw(test, idx)
        z = clips(test, idx)
        rep = ctx.dataset_cfg["training"]["representation"]
        skel = json.loads((ctx.paths["processed"] / ctx.name / rep / "skeleton.json").read_text())
        ctx.sample("ground truth", raw["pose"][:, :S + P], fps=float(test.rep["fps"]), parents=skel["parents"],
                   joints=skel["names"], space="2d", seed_frames=S, trajectory=False,
                   frame="hip-centred image coordinates (y down); no trajectory: the models predict none",
                   units="pixels",
                   title=f"{ctx.name}: GlocalNet Table 3 protocol, test windows {[int(i) for i in idx]} "
                         f"(of {len(test)}), {S} seed + {P} generated poses")
        for run_name, (method, model) in outputs.items():
            ctx.torch_seed(ctx.seeds[0])
            g = generate(model, z[:, :S], raw["labels"], S + P, ctx.device)
            ctx.sample(method, ctx.physical(test, g, raw["root"][:, :S + P]))

    timings["total"] = round(time.perf_counter() - t_start, 2)
    log.info("%s mmd: %d clips a side (%d classes); %d MMD figures computed, %d reused; timings %s",
             ctx.name, n_total, len(classes), score.computed, score.reused, timings)

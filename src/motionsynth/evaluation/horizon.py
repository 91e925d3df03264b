"""GlocalNet Table 4: Euclidean distance per frame at 80, 160, ..., 640 ms on CMU dances (``cmu_aclstm``).

The paper (Battan et al. 2021, sec. 4.3 / Table 4) compares acLSTM, Scheduled Sampling, Seq2Seq
and "Our Method (GloGen)" on the CMU dances acLSTM (Li et al. 2018) redistributes, with "the
euclidean distance from the ground truth for the corresponding frame" at 80 ... 640 ms after the
seed. Published datasets: "CMU walking" (we have no walking), "CMU Indian dance", "CMU martial
arts"; our third class, salsa, has no published row (``compare_to`` "CMU salsa (ours only)").

Metric (exact definition: :func:`motionsynth.metrics.errors.euclidean_per_frame_values`)
-----------------------------------------------------------------------------------------
* **space**: root-relative positions: the root joint (``skeleton.root`` = ``hip``) of each
  frame is subtracted from every joint, separately for prediction and ground truth (our
  prepared poses already have the hip at x = z = 0; the subtraction also removes its height,
  as acLSTM's hip-relative frame vector does). Our prepared poses are also **facing-normalised**
  (each frame rotated about +Y to a smoothed heading): the models see and predict that frame and
  none of them predicts the heading, so errors are measured there. acLSTM's frame keeps the
  world orientation; the reference row ``Zero-velocity (world-oriented)`` measures the frozen
  pose in that frame from the real heading, which shows how much the facing normalisation
  changes the numbers (it lowers them where dancers turn).
* **norm and units**: ONE L2 norm of the whole flattened 57 x 3 pose-vector difference per frame,
  in acLSTM's units (BVH file units x 0.01, all 57 joints incl. End Sites), which our
  ``cmu_aclstm`` store holds (``reader.scale: 0.01``). Model outputs are de-normalised with the
  protocol's train statistics (:meth:`EvalContext.physical`); the ground truth is read from the
  store (:meth:`EvalContext.raw`). ``bench/acLSTM_units_check.py`` confirmed this reading: a
  zero-velocity predictor then scores the magnitudes of the published acLSTM row.
* **fps and horizon -> frame**: the paper (and acLSTM's source files) count horizons at 120 fps;
  our store is prepared at 30 fps (acLSTM trains at 30 fps too), where 80 ms is frame 2.4 after
  the seed. We read both sequences **linearly interpolated at the exact fractional frame**
  ``h * 30 / 1000`` (``frame_mapping: interpolate``, option ``horizon.frame_mapping``): on the
  zero-velocity check it reproduces the 120-fps numbers within 2 % (Indian 2.3 %, martial 2.0 %)
  where rounding to the nearest 30-fps frame is 4-5 % off and biased at 80 ms (frame 2 = 67 ms).
  ``frame_mapping: round`` is available; the rows' ``condition`` says which was used.
* **seed (one common seed for every model)**: each test window (family ``glocal``: 96 dense
  frames = 20 sparse poses every 5 frames) gives GloGen its first ``t_in`` sparse poses
  (``t_in = 5``: dense frames 0, 5, ..., 20), so its **last seed frame is dense frame
  ``S - 1 = (t_in - 1) * every = 20``** and every model is seeded with exactly the ``S = 21``
  dense ground-truth frames ``0 .. 20`` (``generate(seed=pose[:, :S], labels=..., length=L)``);
  horizon ``h`` is the frame ``S - 1 + h * fps / 1000`` of the window, the same ground-truth
  frame for every model. (The recurrent baselines were trained with their own default seed
  length, ``window // 6 = 16`` frames on these windows; at test time all get the same 21.)
  Class labels are given to every model that uses them (GloGen and the recurrent baselines;
  zero-velocity and LocGen ignore them).
* **GlocalNet / "GloGen" row**: our GloGen lives on sparse poses (every 5th frame = 167 ms apart
  at 30 fps), so 80 ms falls between its outputs. The row ``GloGen`` (the published method
  string of Table 4, "Our Method (GloGen)") is the full GlocalNet chain: GloGen rolls out sparse
  poses from the 5 seed poses and the class label, LocGen fills the 4 in-between frames of each
  gap (:func:`motionsynth.models.locgen.glocal_generate`). The paper's GloGen for Table 4 was
  likely trained on the baselines' settings ("For fair comparison, we follow the same settings
  as followed in these methods"), which the paper does not give; the note says so. A second row
  ``GloGen + interpolation`` densifies the same GloGen poses by eq. 3 (linear interpolation)
  instead, isolating LocGen's part.
* **GloGen's loss ablation** (GlocalNet Table 2: ``L = lambda_joint * L_J + lambda_flow * L_MF``,
  eq. 5, trained with one term only): every trained run whose model is a GloGen and whose config
  is a variant of another model's (``model.overrides_as``, e.g. ``conf/model/glogen_lj.yaml``,
  label ``GloGen (L_J)``) gets the same two rows as the full GloGen under its own label:
  ``GloGen (L_J)`` (its sparse roll-out densified by the same LocGen; LocGen's loss is not
  ablated) and ``GloGen (L_J) + interpolation``. The full GloGen's rows are unchanged. No model is
  recognised by its name: the family is the model class, the variant the config
  (:func:`glogen_runs`). A variant must share the full GloGen's ``t_in`` and sparse spacing (the
  common seed); one that does not is left out with a warning.
* **samples and seeds**: stochastic or deterministic is measured, not declared
  (:func:`is_stochastic`: the method's roll-out of the first ``stochastic_check_windows`` windows,
  option ``evaluate.horizon.stochastic_check_windows``, default 4, under two seeds). A
  deterministic method (GloGen, LocGen, the recurrent baselines in eval mode) gives one value per
  cell (``seeds = 1``, note "deterministic"; torch is seeded anyway, ``ctx.seeds[0]``). A
  stochastic one (``Vae Seq2Seq``: every roll-out draws its latent) is rolled out once per
  evaluation seed (``ctx.seeds``, torch seeded with each); the cell is the mean +- std over the
  seeds of the per-seed value (the paper reports one number, no spread). With training-seed
  replicas as well, one value per (training seed, evaluation seed).
* **windows and averaging**: per class (Indian dance = label ``indian``, martial arts =
  ``martial``, salsa), up to ``eval.max_windows`` test windows of that class, evenly spaced (all
  of them on the default data: 50 / 95 / 245). The windows overlap (stride 10 frames), so they
  are not independent samples. Value = the plain mean over the class's windows of the per-window
  error (``n`` = windows).

Outputs: rows ``(Table 4, compare_to = class's published dataset, column "80ms".."640ms",
method)`` with keys ``euclid_<class>/<h>ms``; curves ``euclid_vs_horizon_<class>``; animation
samples (ground truth and every method, the whole 96-frame window from the same seed) of
``eval.animation.sequences`` test windows spread over the split (:meth:`EvalContext.pick`), in
the store's root-relative facing-normalised frame (no trajectory: the models predict none).

Shared helpers (also used by the ``interpolation`` and ``mmd`` suites): :func:`skeleton`, :func:`seed_length`,
:func:`methods` (one seeded roll-out function per trained run, the GlocalNet chain included),
:func:`glogen_runs` / :func:`variant_of` / :func:`ablation_note` (GloGen's family and its loss ablations),
:func:`rollout` / :func:`rollout_normalised`, :func:`spread`, :func:`sample_meta`, :func:`class_names`.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch
import yaml

from ..metrics.errors import DEFAULT_HORIZONS_MS, euclidean_per_frame_values, horizon_frames
from ..models.base import Batch
from ..models.locgen import interpolate
from ..training.data import WindowData
from .context import EvalContext, slug

log = logging.getLogger(__name__)

PAPER = "battan2021_glocalnet"
METRIC = "Euclidean distance per frame"
GLOCALNET = "GlocalNet"                     # sample key of the GloGen + LocGen chain
INTERP_SUFFIX = " + interpolation"        # GloGen's sparse roll-out densified by eq. 3: "<label> + interpolation"
GLOGEN_INTERP = "GloGen" + INTERP_SUFFIX
DEFAULT_CLASSES = {"indian": "CMU Indian dance", "martial": "CMU martial arts", "salsa": "CMU salsa (ours only)"}
MAPPINGS = ("interpolate", "round")
#: windows rolled out under two seeds to tell a stochastic method (option evaluate.horizon.stochastic_check_windows)
STOCHASTIC_CHECK_WINDOWS = 4


# ============================================================================ shared helpers

@dataclass(frozen=True)
class Skeleton:
    names: list[str]
    parents: list[int]
    root_index: int


def skeleton(ctx: EvalContext) -> Skeleton:
    """Joint names, parents and the root joint's index of the dataset's training representation
    (``processed/<ds>/<rep>/skeleton.json``; the root is ``skeleton.root`` of the dataset config)."""
    rep = ctx.dataset_cfg["training"]["representation"]
    path = ctx.paths["processed"] / ctx.name / rep / "skeleton.json"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no skeleton file (run the prepare stage for {ctx.name})")
    s = json.loads(path.read_text())
    root = (ctx.dataset_cfg.get("skeleton") or {}).get("root")
    if root not in s["names"]:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: skeleton.root {root!r} is not a joint of {path} "
                         f"(joints: {s['names'][:8]}...)")
    return Skeleton(list(s["names"]), [int(p) for p in s["parents"]], s["names"].index(root))


def seed_length(t_in: int, every: int) -> int:
    """Dense frames up to and including the last of ``t_in`` sparse seed poses taken every
    ``every`` frames: ``(t_in - 1) * every + 1``."""
    if t_in < 1 or every < 1:
        raise ValueError(f"t_in and every must be >= 1, got t_in={t_in}, every={every}")
    return (t_in - 1) * every + 1


def spread(ids: np.ndarray, n: int | None) -> np.ndarray:
    """``n`` of ``ids`` evenly spaced (all when ``n`` is None or larger): :meth:`EvalContext.pick`'s
    rule applied to a subset (e.g. one class's windows)."""
    ids = np.asarray(ids)
    if n is None or n >= len(ids):
        return ids
    return ids[np.unique(np.linspace(0, len(ids) - 1, n).round().astype(int))]


@dataclass
class Method:
    """A roll-out: ``fn(batch, length)`` -> normalised dense poses ``[B, length, J, D]`` whose
    first ``seed`` frames are the batch's ground truth (or, for GlocalNet, whose keyframes
    ``0, every, ..., seed - 1`` are)."""

    label: str                     # Row.method
    run: str                       # models/<ds>/<run> ("glogen+locgen" for the chain)
    kind: str                      # model | reference
    fn: Callable[[Batch, int], torch.Tensor]
    sample_key: str = ""           # key in the animation samples (default: label)
    #: the same method trained with other seeds (``<run>-seed<k>`` runs): ``(run, fn)`` each; a row then
    #: reports the mean +- std over the training seeds (this one, seed 0, first)
    replicas: list = field(default_factory=list)
    #: GloGen-family rows: ``CHAIN`` (GloGen + LocGen), ``INTERP`` (GloGen + eq. 3); "" for the others
    role: str = ""
    #: the run's config is a variant of another model's (``model.overrides_as``): GloGen's loss ablations
    variant: bool = False
    #: what the row is, put before the suite's own note (GloGen-family rows)
    note: str = ""


CHAIN, INTERP = "chain", "interpolation"


def _check_every(run: str, model: Any, every: int) -> None:
    if int(model.spec.every) != int(every):
        raise ValueError(f"run {run}: trained on windows every {model.spec.every} frames, but the test "
                         f"windows are every {every}")


def variant_of(ctx: EvalContext, run: str) -> str | None:
    """The model a run's config is a variant of (``model.overrides_as`` of ``models/<ds>/<run>/config.yaml``,
    e.g. ``glogen`` for GloGen's loss ablations ``glogen_lj`` / ``glogen_lmf``), else ``None``."""
    path = ctx.run_dir(run) / "config.yaml"
    if not path.exists():
        return None
    cfg = yaml.safe_load(path.read_text()) or {}
    return (cfg.get("model") or {}).get("overrides_as") or None


def glogen_runs(ctx: EvalContext, runs: list[str]) -> tuple[list[str], list[str]]:
    """The GloGen-family runs among ``runs``: ``(plain, variants)``. A run is GloGen-family when its model
    is a :class:`~motionsynth.models.glogen.GloGen` (the class, not the name); a *variant* when its
    config is a variant of another model's (:func:`variant_of`: GlocalNet Table 2's loss ablations)."""
    from ..models.glogen import GloGen

    family = [r for r in runs if isinstance(ctx.model(r)[0], GloGen)]
    variants = [r for r in family if variant_of(ctx, r)]
    return [r for r in family if r not in variants], variants


def ablation_note(model: Any) -> str:
    """What a GloGen loss-ablation row is: its eq.-5 weights ``L = lambda_joint * L_J + lambda_flow * L_MF``."""
    return (f"GloGen's loss ablation (GlocalNet Table 2, eq. 5): trained with lambda_joint = {model.lambda_joint:g} "
            f"(L_J, eq. 6), lambda_flow = {model.lambda_flow:g} (L_MF, eqs. 7-8)")


def chain_label(label: str, base: str) -> str:
    """The animation key of a GloGen-family chain: ``GlocalNet`` for the full GloGen (``label == base``), the
    label's qualifier kept for a variant (``GloGen (L_J)`` -> ``GlocalNet (L_J)``)."""
    return GLOCALNET + label[len(base):] if label.startswith(base) else f"{GLOCALNET} ({label})"


def _glocal(glogen: Any, locgen: Any | None, every: int) -> Callable[[Batch, int], torch.Tensor]:
    """GloGen rolls out sparse poses from the window's first ``t_in`` sparse poses and its label;
    LocGen (or, with ``locgen=None``, eq. 3's linear interpolation) fills ``every - 1`` frames per gap."""

    def fn(batch: Batch, length: int) -> torch.Tensor:
        t = glogen.t
        n = max(-(-(length - 1) // every) + 1, t)                      # sparse poses covering length
        sparse = glogen.generate(batch.pose[:, ::every][:, :t], labels=batch.labels, length=n)
        if locgen is not None:
            dense = locgen.generate(sparse, M=every - 1)
        else:
            B, _, J, D = sparse.shape
            dense = interpolate(sparse.reshape(B, n, J * D), every - 1)[0].reshape(B, -1, J, D)
        return dense[:, :length]

    return fn


def _seeded(model: Any, S: int) -> Callable[[Batch, int], torch.Tensor]:
    def fn(batch: Batch, length: int) -> torch.Tensor:
        return model.generate(batch.pose[:, :S], labels=batch.labels, length=length)

    return fn


def methods(ctx: EvalContext, every: int, default_t_in: int = 5,
            variants: bool = False) -> tuple[list[Method], int]:
    """Every trained plain run of the dataset as a :class:`Method`, all seeded from the same
    ground-truth frames, and that seed's length ``S`` (dense frames).

    GloGen's ``t_in`` seed poses fix ``S = (t_in - 1) * every + 1`` (``default_t_in`` when no GloGen
    run is trained). With GloGen: ``GloGen`` (+ LocGen when trained: the GlocalNet chain) and
    ``GloGen + interpolation``; LocGen alone is no roll-out and is used only inside the chain.
    GloGen-family runs are found by class and config (:func:`glogen_runs`), never by name; with
    ``variants=True`` GloGen's loss ablations get the same two rows under their own labels
    (``GloGen (L_J)``, ``GloGen (L_J) + interpolation``; module docstring), else they are left out.
    Trivial predictors (zero-velocity, the mean pose) are ``reference`` rows; VAE-LSTM-style
    control-driven models are left out."""
    from ..models.locgen import LocGen
    from ..models.vae_lstm import VAELSTM

    runs = ctx.available(variant=None)
    plain, ablations = glogen_runs(ctx, runs)
    locgen_runs = [r for r in runs if isinstance(ctx.model(r)[0], LocGen)]
    family = plain + ablations
    glogen = ctx.model(family[0])[0] if family else None
    if glogen is not None:
        _check_every(family[0], glogen, every)
    locgen = ctx.model(locgen_runs[0])[0] if locgen_runs else None
    S = seed_length(glogen.t if glogen is not None else int(default_t_in), every)
    out: list[Method] = []
    for i, run in enumerate(family):
        is_variant = run in ablations
        if is_variant and not variants:
            log.info("%s: run %s (a GloGen variant) is not scored by this suite", ctx.name, run)
            continue
        g = ctx.model(run)[0]
        if i and (int(g.t) != int(glogen.t) or int(g.spec.every) != int(every)):
            log.warning("%s: run %s has t_in %d / every %d, not the common %d / %d; left out", ctx.name, run,
                        g.t, g.spec.every, glogen.t, every)
            continue
        label = ctx.label(ctx.runs[run])
        base = ctx.label(variant_of(ctx, run)) if is_variant else label     # GloGen (L_J) -> GloGen
        reps = [(r, ctx.model(r)[0]) for r in ctx.replicas(run)]
        what = f"; {ablation_note(g)}" if is_variant else ""
        if locgen is not None:
            out.append(Method(label, f"{run}+{locgen_runs[0]}", "model", _glocal(g, locgen, every),
                              chain_label(label, base),
                              [(f"{r}+{locgen_runs[0]}", _glocal(x, locgen, every)) for r, x in reps],
                              role=CHAIN, variant=is_variant,
                              note=f"GlocalNet chain: {label} sparse roll-out (every {every}) densified by LocGen, set "
                                   f"beside the paper's 'Our Method (GloGen)' (whose Table-4 training setting the "
                                   f"paper does not give){what}"))
        else:
            log.warning("%s: no trained LocGen run: the GlocalNet chain (%s + LocGen) is left out", ctx.name, label)
        out.append(Method(label + INTERP_SUFFIX, run, "model", _glocal(g, None, every),
                          replicas=[(r, _glocal(x, None, every)) for r, x in reps], role=INTERP, variant=is_variant,
                          note=f"{label} sparse roll-out densified by linear interpolation (eq. 3), beyond the "
                               f"paper{what}"))
    for run in runs:
        if run in family or run in locgen_runs:
            continue
        name = ctx.runs[run]
        model = ctx.model(run)[0]
        if getattr(model, "uses_controls", False) and getattr(model, "control_mode", "predict") == "given":
            log.warning("%s: run %s needs given controls; left out", ctx.name, run)
            continue
        if isinstance(model, VAELSTM):
            log.warning("%s: run %s (control-driven VAE-LSTM) has no seeded roll-out here; left out", ctx.name, run)
            continue
        out.append(Method(ctx.label(name), run, ctx.kind(run), _seeded(model, S),
                          replicas=[(r, _seeded(ctx.model(r)[0], S)) for r in ctx.replicas(run)]))
    return out, S


def rollout_normalised(ctx: EvalContext, method: Method, batch: Batch, length: int,
                       seed: int | None = None) -> torch.Tensor:
    """``method``'s dense roll-out of ``batch``, normalised ``[B, length, J, D]`` (torch seeded with
    ``seed``, default ``ctx.seeds[0]``, first; the shape is checked)."""
    ctx.torch_seed(ctx.seeds[0] if seed is None else seed)
    z = method.fn(batch, length)
    want = (batch.size, length) + tuple(batch.pose.shape[2:])
    if tuple(z.shape) != want:
        raise ValueError(f"{method.label} ({method.run}): roll-out has shape {tuple(z.shape)}, expected {want}")
    return z


def is_stochastic(ctx: EvalContext, method: Method, batch: Batch, length: int, windows: int) -> bool:
    """Whether ``method``'s roll-out (``length`` frames) differs between two torch seeds on the first
    ``windows`` windows of ``batch`` (:meth:`EvalContext.is_stochastic`)."""
    return ctx.is_stochastic(lambda b, seed: rollout_normalised(ctx, method, b, length, seed), batch, windows)


def rollout(ctx: EvalContext, data: WindowData, method: Method, batch: Batch, length: int,
            seed: int | None = None) -> np.ndarray:
    """``method``'s dense roll-out of ``batch`` in physical units, ``[B, length, J, D]`` float64."""
    return ctx.physical(data, rollout_normalised(ctx, method, batch, length, seed))


def sample_meta(ctx: EvalContext, data: WindowData, sk: Skeleton, S: int, title: str) -> dict[str, Any]:
    return {"fps": float(data.rep["fps"]), "parents": sk.parents, "joints": sk.names, "space": "3d",
            "seed_frames": int(S), "title": title, "trajectory": False,
            "frame": "root-relative, facing-normalised poses as stored (root joint at x = z = 0, heights kept); "
                     "no trajectory: the models predict none",
            "units": "dataset units (metres; acLSTM units = BVH x 0.01 on cmu_aclstm)"}


def class_names(data: WindowData) -> dict[int, str]:
    """``{label index: label name}`` from the prepared meta table."""
    m = data.meta[["label", "label_name"]].drop_duplicates()
    return {int(a): str(b) for a, b in zip(m["label"], m["label_name"])}


# ============================================================================ the suite

def run(ctx: EvalContext) -> None:
    opts = dict(ctx.options.get("horizon") or {})
    horizons = [int(h) for h in opts.get("horizons_ms", DEFAULT_HORIZONS_MS)]
    mapping = str(opts.get("frame_mapping", "interpolate"))
    n_check = opts.get("stochastic_check_windows", STOCHASTIC_CHECK_WINDOWS)
    if isinstance(n_check, bool) or not isinstance(n_check, int) or n_check < 1:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.horizon.stochastic_check_windows must be an "
                         f"integer >= 1, got {n_check!r}")
    if mapping not in MAPPINGS:
        raise ValueError(f"conf/dataset/{ctx.name}.yaml: evaluate.horizon.frame_mapping must be one of "
                         f"{MAPPINGS}, got {mapping!r}")
    compare = {**DEFAULT_CLASSES, **(opts.get("classes") or {})}

    data = ctx.data("glocal", "test")
    if len(data) == 0:
        raise ValueError(f"{ctx.name}: no glocal test windows")
    fps, every, T = float(data.rep["fps"]), data.every, data.length
    sk = skeleton(ctx)
    meths, S = methods(ctx, every, variants=True)
    if not meths:
        log.warning("%s: horizon: no trained runs; nothing to evaluate", ctx.name)
    k = (horizon_frames(horizons, fps).astype(float) if mapping == "round"
         else np.asarray(horizons, float) * fps / 1000.0)
    L = S + int(math.ceil(float(k.max()) - 1e-9))                   # frames 0 .. S-1+k_max
    if L > T:
        raise ValueError(f"{ctx.name}: {max(horizons)} ms after a {S}-frame seed needs {L} frames; windows "
                         f"hold {T}")

    # windows: per class, up to max_windows evenly spaced
    names = class_names(data)
    win_labels = data.labels[data.windows["seq"].to_numpy()]
    idx_parts = []
    for c in sorted(names):
        ids = np.flatnonzero(win_labels == c)
        if len(ids) == 0:
            log.warning("%s: class %s has no test windows", ctx.name, names[c])
            continue
        idx_parts.append(spread(ids, ctx.opts.get("max_windows")))
    idx = np.concatenate(idx_parts)
    raw = ctx.raw(data, idx)
    gt = raw["pose"][:, :L]
    batch = data.batch(idx).to(ctx.device)
    labels = raw["labels"]
    reading = ("linearly interpolated at the exact fractional frame" if mapping == "interpolate"
               else "rounded to the nearest frame")
    cond = (f"seed: dense frames 0..{S - 1} ({(S - 1) // every + 1} sparse poses every {every}) + class label; "
            f"{fps:g} fps, horizons {reading}")
    note_space = (f"root-relative (root '{sk.names[sk.root_index]}' subtracted per frame) and facing-normalised, "
                  f"{len(sk.names)} joints, dataset units; the paper: 120 fps, world-oriented")
    kw = dict(paper=PAPER, table="Table 4", metric=METRIC, seeds=1, protocol="test split")

    def add_rows(label: str, run: str, kind: str, values: np.ndarray | list[np.ndarray], note: str,
                 condition: str = cond) -> None:
        """``values`` ``[B, H]``, or one such array per training seed (mean +- std over the seeds)."""
        per_seed = values if isinstance(values, list) else [values]
        for c in sorted(names):
            m = labels == c
            if not m.any():
                continue
            v = np.stack([x[m].mean(axis=0) for x in per_seed])                        # [seeds, H]
            cls = names[c]
            for j, h in enumerate(horizons):
                row = dict(compare_to=compare.get(cls, f"CMU {cls} (ours only)"), column=f"{h}ms", method=label,
                           condition=condition, n=int(m.sum()), key=f"euclid_{slug(cls)}/{h}ms", run=run,
                           kind=kind, note=note, **kw)
                if len(per_seed) > 1:
                    ctx.add_seeds(v[:, j], **{k: x for k, x in row.items() if k != "seeds"})
                else:
                    ctx.add(value=float(v[0, j]), **row)
            ctx.curve(f"euclid_vs_horizon_{slug(cls)}", label, horizons, v.mean(axis=0))

    score = dict(root_index=sk.root_index, seed_frames=S, frame_mapping=mapping)
    for meth in meths:
        stochastic = is_stochastic(ctx, meth, batch, L, n_check)
        seeds = ctx.seeds if stochastic else ctx.seeds[:1]
        values = [euclidean_per_frame_values(rollout(ctx, data, Method(meth.label, r, meth.kind, fn), batch, L, s),
                                             gt, fps, horizons, **score)        # [B, H] per training x eval seed
                  for r, fn in [(meth.run, meth.fn), *meth.replicas] for s in seeds]
        how = (f"stochastic (measured): one roll-out per evaluation seed {list(seeds)}" if stochastic
               else "deterministic")
        note = f"{how}; {note_space}"
        if meth.replicas:
            note = f"{ctx.seeds_note([meth.run, *(r for r, _ in meth.replicas)])}; each {how}; {note_space}"
        elif stochastic:
            note = f"mean +- std over {len(values)} evaluation seeds; {note}"
        if meth.note:
            note = f"{meth.note}; {note}"
        add_rows(meth.label, meth.run, meth.kind, values if len(values) > 1 else values[0], note)

    # calibration: the frozen last seed pose in acLSTM's world-oriented root-relative frame
    world = ctx.global_positions(raw["pose"][:, :L], raw["root"][:, :L])
    frozen = np.repeat(world[:, S - 1:S], L, axis=1)
    frozen[:, :S] = world[:, :S]
    values = euclidean_per_frame_values(frozen, world, fps, horizons, **score)
    add_rows("Zero-velocity (world-oriented)", "", "reference", values,
             "calibration: last seed pose held, scored root-relative in the world orientation (acLSTM's "
             "frame, real heading) instead of the facing-normalised one; no model",
             condition=cond.replace(" + class label", ""))

    # animation samples: the whole window from the same seed
    add_samples(ctx, data, meths, sk, S, T, f"{ctx.name}: GlocalNet Table 4 protocol, {S}-frame seed, "
                                            f"{T} frames at {fps:g} fps")


def add_samples(ctx: EvalContext, data, meths, sk, S: int, length: int, title: str) -> None:
    """Animation samples: the first ``length`` frames of ``eval.animation.sequences`` picked test
    windows, ground truth and every method rolled out from the same ``S``-frame seed."""
    n_anim = int((ctx.opts.get("animation") or {}).get("sequences", 2))
    if n_anim <= 0:
        return
    sidx = ctx.pick(data, n_anim)
    sbatch = data.batch(sidx).to(ctx.device)
    meta = sample_meta(ctx, data, sk, S, title)
    meta["sequences"] = [str(s) for s in data.windows.iloc[sidx]["sequence_id"]]
    meta["start_frames"] = [int(s) for s in data.windows.iloc[sidx]["start"]]
    ctx.sample("ground truth", ctx.raw(data, sidx)["pose"][:, :length], **meta)
    for meth in meths:
        ctx.sample(meth.sample_key or meth.label, rollout(ctx, data, meth, sbatch, length))

"""The ``generative`` suite (FID, recognition accuracy, diversity, multimodality, foot skating, bone
lengths) on tiny real projects: rows, calibration, the classifier cache, and its array-level pieces."""

from __future__ import annotations

import copy
import math

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth.data.types import Skeleton
from motionsynth.evaluation import EvalContext, evaluate
from motionsynth.evaluation import generative as gen
from motionsynth.metrics.physical import bone_length_error
from motionsynth.metrics.recognition import features, fid

DS = "bandai1"
RUNS = {"glogen": ("glogen", "none"), "locgen": ("locgen", "none"), "erd": ("erd", "none"),
        "zero_velocity": ("zero_velocity", "none"), "glogen_lj": ("glogen_lj", "none"),
        "vae_seq2seq": ("vae_seq2seq", "none")}
OPTS = {"epochs": 3, "frame_step": 2}      # small and fast: the suite's mechanics, not the classifier's quality
#: deterministic rows (a GloGen loss ablation's chain is named after its label)
METHODS = {"GloGen", "GlocalNet", "LocGen", "ERD", "Zero-velocity", "GloGen (L_J)", "GlocalNet (L_J)"}
STOCHASTIC = {"Vae Seq2Seq"}               # draws its latent on every roll-out


def _cfg(r, cache):
    cfg = compose_cfg(r, DS, "eval.threads=1", f"paths.reports={r}/reports", f"paths.samples={r}/samples")
    cfg["dataset"]["evaluate"] = {"suites": ["generative"], "generative": {**OPTS, "cache_dir": str(cache)}}
    return cfg


@pytest.fixture(scope="module")
def built(tmp_path_factory, one_thread):
    r = tmp_path_factory.mktemp("genroot")
    runs = build_eval_root(r, DS, RUNS, max_items=20)   # 6 classes with test windows
    (r / "conf").symlink_to(REPO / "conf")          # ctx.label reads <paths.root>/conf/model/<m>.yaml
    cache = r / "cls"
    ctx = evaluate(_cfg(r, cache), runs)
    return {"root": r, "runs": runs, "cache": cache, "ctx": ctx, "table": pd.DataFrame([vars(x) for x in ctx.rows])}


def cell(table, method, metric, column=None):
    """One row: the generative block's column ``metric`` (``"<metric>, <column>"`` for the physical ones)."""
    col = metric if column is None else f"{metric}, {column}"
    hit = table[(table.method == method) & (table.metric == gen.GROUP) & (table.column == col)]
    assert len(hit) == 1, (method, metric, column, len(hit))
    return hit.iloc[0]


# ----------------------------------------------------------------------------- rows

def test_every_method_has_every_metric_finite(built):
    t = built["table"]
    assert set(t.paper) == {"beyond_papers"} and set(t.table) == {"Generative metrics"}
    assert set(t.compare_to) == {f"{DS} (ours)"}
    assert METHODS | STOCHASTIC <= set(t.method)
    for method in METHODS | STOCHASTIC | {gen.REAL_ROW, gen.NOISE_ROW}:
        for metric in gen.METRICS:
            r = cell(t, method, metric)
            assert math.isfinite(r.value) and r.n >= 2, (method, metric)
    for method in METHODS | STOCHASTIC:
        for column in ("abs (m)", "relative"):
            assert math.isfinite(cell(t, method, "Bone length error", column).value)
        # root-relative outputs only on bandai1: no foot-skating row for the models ...
        assert t[(t.method == method) & t.column.str.startswith("Foot skating ratio")].empty
    # ... but the ground truth's world-space reference, with the root-frame value in its note
    gt = cell(t, gen.REAL_ROW, "Foot skating ratio", "ratio")
    assert 0 <= gt.value < 0.2 and "root frame" in gt.note
    acc = cell(t, gen.CLASSIFIER_ROW, "Recognition accuracy")
    assert acc.kind == "reference" and 0 <= acc.value <= 1 and "chance" in acc.note
    assert all(0 <= v <= 1 for v in t[t.column == "Recognition accuracy"].value)


def test_deterministic_models_are_one_value_with_a_note(built):
    t = built["table"]
    for method in METHODS:           # eval mode: no dropout, no sampling anywhere in these models
        r = cell(t, method, "FID")
        assert r.seeds == 1 and math.isnan(r["std"]) and r.note.startswith("deterministic")
        assert "0 by construction" in r.note


def test_sample_spread_is_zero_for_deterministic_methods(built):
    t = built["table"]
    for method in METHODS:
        r = cell(t, method, gen.SPREAD)
        assert r.value == 0.0 and r.note.startswith("deterministic") and r.key == "generative/sample_spread"


def test_stochastic_rows_are_mean_and_std_over_seeds_with_a_non_zero_spread(built):
    t, ctx = built["table"], built["ctx"]
    for method in STOCHASTIC:
        for column in (*gen.METRICS, gen.JITTER, gen.JITTER_REL):
            r = cell(t, method, column)
            assert r.seeds == len(ctx.seeds) > 1 and math.isfinite(r["std"]) and r.note.startswith("stochastic")
        r = cell(t, method, gen.SPREAD)
        assert r.value > 0 and "draws" in r.note                 # its samples differ


def test_sample_spread_known_answer():
    """Two draws of one window: one joint 2 cm apart along x (root-relative), the others equal."""
    rng = np.random.default_rng(0)
    base = rng.standard_normal((1, 1, 10, 4, 3))                            # [S=1, N=1, T=10, J=4, 3]
    draws = np.concatenate([base, base], axis=0)
    draws[1, :, :, 2, 0] += 0.02
    # per frame, joint 2: std over the 2 draws of a 2-cm difference = 1 cm; joints 0, 1, 3: 0
    assert gen.sample_spread(draws, root_index=0, start=0) == pytest.approx(0.01 / 4)
    moved_root = draws.copy()
    moved_root[1] += 0.5                                                     # a global shift is no spread
    assert gen.sample_spread(moved_root, root_index=0, start=0) == pytest.approx(0.01 / 4)
    assert gen.sample_spread(draws, root_index=0, start=5) == pytest.approx(0.01 / 4)


def test_real_fid_is_small_against_noise(built):
    t = built["table"]
    real, noise = cell(t, gen.REAL_ROW, "FID").value, cell(t, gen.NOISE_ROW, "FID").value
    assert real < 0.5 * noise, (real, noise)
    # zero velocity repeats a real pose: between real motion and noise
    assert cell(t, "Zero-velocity", "FID").value < noise


def test_real_fid_row_is_the_fid_of_the_two_real_halves(built):
    ctx = built["ctx"]
    clf, _ = gen.get_classifier(ctx, gen._options(ctx))
    test = ctx.data("glocal", "test")
    a, b = gen.real_halves(test, ctx.opts["max_windows"])
    fa, fb = (features(clf, gen._x(test, ix, OPTS["frame_step"])[0]) for ix in (a, b))
    assert cell(built["table"], gen.REAL_ROW, "FID").value == pytest.approx(fid(fb, fa), rel=1e-12)


# ----------------------------------------------------------------------------- the classifier cache

def test_classifier_cache_is_reused_and_gives_identical_numbers(built):
    files = list(built["cache"].glob("*.pt"))
    assert len(files) == 1
    mtime = files[0].stat().st_mtime_ns
    ctx2 = evaluate(_cfg(built["root"], built["cache"]), built["runs"])
    # not retrained: the file is untouched, and the loaded classifier says it came from the cache
    assert files[0].stat().st_mtime_ns == mtime and list(built["cache"].glob("*.pt")) == files
    assert gen.get_classifier(ctx2, gen._options(ctx2))[1]["cached"]
    a = built["table"]
    b = pd.DataFrame([vars(x) for x in ctx2.rows])
    pd.testing.assert_frame_equal(a, b)                        # same rows, values, notes


def test_a_changed_setting_retrains_into_a_new_fingerprint(built, tmp_path):
    cfg = _cfg(built["root"], tmp_path / "cls2")
    ctx = EvalContext(cfg, built["runs"])
    o = gen._options(ctx)
    _, meta = gen.get_classifier(ctx, {**o, "epochs": 2})
    assert not meta["cached"] and meta["fingerprint"] not in {p.stem for p in built["cache"].glob("*.pt")}
    _, again = gen.get_classifier(ctx, {**o, "epochs": 2})
    assert again["cached"]


# ----------------------------------------------------------------------------- pieces

def test_bone_length_error_of_ground_truth_is_zero_and_of_a_stretched_copy_is_not(built):
    ctx = built["ctx"]
    t = built["table"]
    assert cell(t, gen.REAL_ROW, "Bone length error", "relative").value < 1e-3
    test = ctx.data("glocal", "test")
    pose = ctx.raw(test, np.arange(min(20, len(test))))["pose"]
    skel = Skeleton.load(built["root"] / "data/processed" / DS / "pos3d" / "skeleton.json")
    assert bone_length_error(pose, skeleton=skel).rel_error < 1e-3
    stretched = bone_length_error(pose * 1.05, skeleton=skel)
    assert stretched.rel_error == pytest.approx(0.05, abs=2e-3)


def test_real_halves_are_disjoint_balanced_and_ordered_in_time(built):
    test = built["ctx"].data("glocal", "test")
    a, b = gen.real_halves(test, 10_000)
    assert len(np.intersect1d(a, b)) == 0 and len(a) + len(b) == len(test)
    assert abs(len(a) - len(b)) <= 2
    w = test.windows
    lab = test.labels[w["seq"].to_numpy()]
    assert np.abs(np.bincount(lab[a], minlength=test.num_classes)
                  - np.bincount(lab[b], minlength=test.num_classes)).max() <= 1
    for s in np.unique(w["seq"].to_numpy()[b]):              # within a sequence, A comes first
        in_a = w["start"].to_numpy()[a][w["seq"].to_numpy()[a] == s]
        in_b = w["start"].to_numpy()[b][w["seq"].to_numpy()[b] == s]
        assert len(in_a) == 0 or in_a.max() < in_b.min()
    a3, b3 = gen.real_halves(test, 3)
    assert len(a3) == 3 and len(b3) == 3 and set(a3) <= set(a)


def test_rollout_matches_generate(built):
    ctx = built["ctx"]
    model, _ = ctx.model("erd")
    b = ctx.data("glocal", "test").batch(np.arange(4))
    S, T = model.seed_frames, b.pose.shape[1]
    pose, ctrl = model.rollout(b.pose[:, :S], None, b.labels, T)
    assert ctrl is None
    torch.testing.assert_close(pose, model.generate(b.pose[:, :S], None, b.labels, length=T), rtol=0, atol=0)


def test_bad_options_are_named(built):
    cfg = _cfg(built["root"], built["cache"])
    for bad, match in (({"epoch": 3}, "unknown option.*epoch"), ({"frame_step": 0}, "frame_step"),
                       ({"windows": 1}, "windows")):
        c = copy.deepcopy(cfg)
        c["dataset"]["evaluate"]["generative"] = bad
        with pytest.raises(ValueError, match=match):
            gen.run(EvalContext(c, built["runs"]))


# ----------------------------------------------------------------------------- jitter

def test_jitter_of_constant_velocity_motion_is_zero():
    rng = np.random.default_rng(0)
    t = np.arange(12, dtype=np.float64)[None, :, None, None]
    moving = rng.normal(size=(3, 1, 5, 3)) + rng.normal(size=(3, 1, 5, 3)) * t      # [3, 12, 5, 3]
    assert gen.jitter(moving, start=1) == pytest.approx(0.0, abs=1e-12)
    assert gen.jitter(moving, start=6) == pytest.approx(0.0, abs=1e-12)


def test_jitter_of_a_zig_zag_is_four_times_its_amplitude_over_the_joints():
    """One of 4 joints zig-zags x_t = a (-1)^t along x: every second difference is 4a in magnitude."""
    a, T, J = 0.03, 10, 4
    x = np.zeros((2, T, J, 3))
    x[:, :, 1, 0] = a * (-1.0) ** np.arange(T)
    assert gen.jitter(x, start=1) == pytest.approx(4 * a / J, rel=1e-12)
    # only the generated frames count: a zig-zag in the seed frames 0..4, straight motion from frame 5 on ...
    y = np.zeros((2, T, J, 3))
    y[:, :5, 2, 1] = a * (-1.0) ** np.arange(5)
    y[:, 4:, 2, 1] = y[:, 4:5, 2, 1] + 0.01 * np.arange(T - 4)
    assert gen.jitter(y, start=5) == pytest.approx(0.0, abs=1e-12)
    assert gen.jitter(y, start=4) > 0                       # ... frame 3 enters once frame 4 counts as generated
    # ... but the transition from the last seed frame counts: a jump at the first generated frame
    y[:, 5:, 2, 1] += 0.1
    assert gen.jitter(y, start=5) == pytest.approx(0.1 / (T - 1 - 5) / J, rel=1e-12)
    with pytest.raises(ValueError, match="frames"):
        gen.jitter(x[:, :4], start=3)


def test_jitter_rows_the_real_reference_and_zero_velocity(built):
    t, ctx = built["table"], built["ctx"]
    test = ctx.data("glocal", "test")
    a, _ = gen.real_halves(test, ctx.opts["max_windows"])
    pose = ctx.raw(test, a)["pose"]                                      # [N, 96, 21, 3] metres
    acc = pose[:, 2:] - 2 * pose[:, 1:-1] + pose[:, :-2]
    real = cell(t, gen.REAL_ROW, gen.JITTER)
    assert real.kind == "reference" and real.key == gen.JITTER_KEY == "generative/jitter"
    assert real.value == pytest.approx(np.linalg.norm(acc, axis=-1).mean(), rel=1e-9) and real.value > 0
    assert "metres per frame²" in real.note
    rel = cell(t, gen.REAL_ROW, gen.JITTER_REL)
    assert rel.value == 1.0 and rel.key == gen.JITTER_REL_KEY == "generative/jitter/relative"
    for method in METHODS | STOCHASTIC:
        assert math.isfinite(cell(t, method, gen.JITTER).value) and cell(t, method, gen.JITTER).value >= 0
        assert math.isfinite(cell(t, method, gen.JITTER_REL).value)
    # the held last seed pose: every second difference from the last seed frame on is exactly 0
    assert cell(t, "Zero-velocity", gen.JITTER).value == 0.0 and cell(t, "Zero-velocity", gen.JITTER_REL).value == 0.0


def test_training_seed_replicas_are_one_row_of_mean_and_std_over_the_seeds(built, tmp_path):
    """GloGen with a ``glogen-seed1`` replica: its two rows (GloGen, GlocalNet) become mean +- std over the two
    training seeds, each seed's value what it scores alone; the replica is no row of its own."""
    from motionsynth.training.run import run as train_run
    r = built["root"]
    train_run(compose_cfg(r, DS, "model=glogen", "run_name=glogen-seed1", "seed=1", "train.steps=2",
                          "train.eval_every=2"), progress=False)                 # as build_eval_root trains glogen
    (r / "models" / DS / "glogen_alone").symlink_to(r / "models" / DS / "glogen-seed1", target_is_directory=True)
    cfg = _cfg(r, built["cache"])
    cfg["paths"].update(reports=str(tmp_path / "reports"), samples=str(tmp_path / "samples"))
    ctx = evaluate(cfg, {"glogen": "glogen", "glogen-seed1": "glogen", "glogen_alone": "glogen", "locgen": "locgen"})
    t = pd.DataFrame([vars(x) for x in ctx.rows])
    first = built["table"]
    assert not t.run.str.contains("seed1").any()
    for method, run, alone in [("GloGen", "glogen", "glogen_alone"), ("GlocalNet", "glogen+locgen", "glogen_alone+locgen")]:
        for metric in ["FID", "Recognition accuracy", "Diversity", "Jitter"]:
            sel = t[(t.method == method) & (t.metric == gen.GROUP) & (t.column == metric)]
            both, b = sel[sel.run == run].iloc[0], sel[sel.run == alone].iloc[0].value
            a = cell(first, method, metric).value
            assert both.value == pytest.approx((a + b) / 2, rel=1e-9, abs=1e-12)
            assert both["std"] == pytest.approx(abs(a - b) / math.sqrt(2), rel=1e-6, abs=1e-12)
            assert both.seeds == 2 and "2 training seeds (runs glogen, glogen-seed1)" in both.note
        assert t[(t.method == method) & (t.column == gen.SPREAD) & (t.run == run)].value.iloc[0] == 0.0
    a, b = cell(first, "GloGen", "FID").value, t[(t.run == "glogen_alone") & (t.column == "FID")].value.iloc[0]
    assert a != b                                                                 # the seeds differ

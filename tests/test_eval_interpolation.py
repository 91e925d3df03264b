"""GlocalNet Table 1 suite (``interpolation``): LocGen against linear interpolation, on a tiny real bandai1 project."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth.evaluation import EvalContext, interpolation
from motionsynth.evaluation.interpolation import AS_GENERATED, WITH_INTERP, WITH_LOCGEN, densify, frame_errors

DS = "bandai1"
#: the Seq2Seq family: (run, label as published in GlocalNet Table 1)
SEQ2SEQ_FAMILY = {"seq2seq": "Seq2Seq", "att_seq2seq": "att. Seq2Seq", "vae_seq2seq": "Vae Seq2Seq"}


@pytest.fixture(scope="module")
def suite(tmp_path_factory, one_thread):
    r = tmp_path_factory.mktemp("interp")
    runs = build_eval_root(r, DS, {"glogen": ("glogen", "none"), "locgen": ("locgen", "none"),
                                   "zero_velocity": ("zero_velocity", "none"),
                                   **{m: (m, "none") for m in SEQ2SEQ_FAMILY}}, batches=1)
    (r / "conf").symlink_to(REPO / "conf")                     # the method labels (conf/model/*.yaml: label)
    cfg = compose_cfg(r, DS, "eval.max_windows=40", "eval.animation.sequences=2", "eval.threads=1")
    cfg["dataset"]["evaluate"] = {**cfg["dataset"]["evaluate"], "suites": ["interpolation"]}
    ctx = EvalContext(cfg, runs)
    interpolation.run(ctx)
    return ctx, pd.DataFrame([vars(x) for x in ctx.rows])


def test_linear_motion_is_interpolated_exactly_and_curved_motion_is_not():
    t = np.arange(26, dtype=np.float64)[None, :, None, None]             # 26 frames, every 5: 6 sparse poses
    rng = np.random.default_rng(0)
    p0, vel = rng.normal(size=(3, 1, 1, 4, 3)), rng.normal(size=(3, 1, 1, 4, 3))
    linear = (p0 + vel * t).reshape(3, 26, 4, 3)                          # every joint moves linearly in time
    dense = densify(None, torch.from_numpy(linear[:, ::5].copy()), 5, WITH_INTERP).numpy()
    assert dense.shape == linear.shape
    between = np.flatnonzero(np.arange(26) % 5)
    assert np.abs(frame_errors(dense, linear, 30.0, between, 0)).max() < 1e-9
    curved = linear + 0.1 * t.reshape(1, 26, 1, 1) ** 2 * np.array([0.0, 1.0, 0.0, 0.0])[None, None, :, None]
    dense = densify(None, torch.from_numpy(curved[:, ::5].copy()), 5, WITH_INTERP).numpy()
    e = frame_errors(dense, curved, 30.0, between, 0)                     # [3, 20]
    # joint 1 moves on a parabola 0.1 t^2 along all 3 axes (root 0 stays linear): the chord's gap at
    # offset j of a 5-frame gap is 0.1 j (5 - j), the same in every gap and window
    j = between % 5
    np.testing.assert_allclose(e, np.broadcast_to(np.sqrt(3) * 0.1 * j * (5 - j), e.shape), rtol=1e-9)


def test_rows_columns_and_finite_values(suite):
    ctx, rows = suite
    assert set(rows["table"]) == {"Table 1"} and set(rows["compare_to"]) == {"NTU RGB+D 3D (60 classes)"}
    assert set(rows["metric"]) == {"Euclidean distance per frame"}
    got = {(m, c) for m, c in zip(rows["method"], rows["column"])}
    baselines = ["Zero-velocity", *SEQ2SEQ_FAMILY.values()]
    assert got == {("GlocalNet", WITH_LOCGEN), ("GlocalNet", WITH_INTERP),
                   ("Ground-truth sparse poses", WITH_LOCGEN), ("Ground-truth sparse poses", WITH_INTERP),
                   *((m, c) for m in baselines for c in (WITH_LOCGEN, WITH_INTERP, AS_GENERATED))}
    assert np.isfinite(rows["value"]).all() and (rows["value"] > 0).all() and (rows["n"] > 0).all()
    assert rows["note"].str.contains("not NTU").all()
    assert rows.groupby(["method", "key"]).size().max() == 1
    gs = rows[rows["method"] == "Ground-truth sparse poses"].set_index("column")["value"]
    gl = rows[rows["method"] == "GlocalNet"].set_index("column")["value"]
    assert gs[WITH_INTERP] < gl[WITH_INTERP]          # true key poses beat GloGen's rolled-out ones


def test_ground_truth_interpolation_equals_a_direct_numpy_computation(suite):
    ctx, rows = suite
    data = ctx.data("glocal", "test")
    g = ctx.raw(data, ctx.pick(data, 40))["pose"]                         # [B, 96, 21, 3] metres
    g = g - g[:, :, :1]                                                   # root (Hips, joint 0) per frame
    sp = g[:, ::5]
    a = (np.arange(5) / 5.0)[None, None, :, None, None]
    lin = ((1 - a) * sp[:, :-1, None] + a * sp[:, 1:, None]).reshape(len(g), -1, 21, 3)
    lin = np.concatenate([lin, sp[:, -1:]], 1)
    between = np.arange(96) % 5 != 0
    d = (lin - g)[:, between].reshape(len(g), between.sum(), -1)
    expect = np.sqrt((d ** 2).sum(-1)).mean()
    row = rows[(rows["method"] == "Ground-truth sparse poses") & (rows["column"] == WITH_INTERP)]
    np.testing.assert_allclose(row["value"].item(), expect, rtol=1e-4)


def test_zero_velocity_known_answers(suite):
    ctx, rows = suite
    zv = rows[rows["method"] == "Zero-velocity"].set_index("column")["value"]
    # a frozen pose sampled every 5 frames and interpolated is the same frozen pose
    np.testing.assert_allclose(zv[WITH_INTERP], zv["as generated"], rtol=1e-6)
    assert set(rows.loc[rows["method"] == "Zero-velocity", "kind"]) == {"reference"}


def test_samples_share_the_seed_and_glogen_keyframes(suite):
    ctx, _ = suite
    gt = ctx.samples["ground truth"]
    assert gt.shape[0] == 2 and gt.shape[1:] == (96, 21, 3)
    S = ctx.sample_meta["seed_frames"]
    assert S == 21 and ctx.sample_meta["fps"] == 30 and len(ctx.sample_meta["joints"]) == 21
    a, b = ctx.samples["GlocalNet"], ctx.samples["GloGen + interpolation"]
    assert a.shape == b.shape == gt.shape
    np.testing.assert_allclose(a[:, ::5], b[:, ::5], atol=1e-5)         # same GloGen poses, LocGen keeps them
    np.testing.assert_allclose(a[:, :S:5], gt[:, :S:5], atol=1e-4)      # seed poses are ground truth
    np.testing.assert_allclose(ctx.samples["Zero-velocity"][:, :S], gt[:, :S], atol=1e-4)


def test_without_locgen_only_interpolation_is_measured(suite):
    ctx, _ = suite
    c2 = EvalContext(ctx.cfg, {k: v for k, v in ctx.runs.items() if v != "locgen"})
    interpolation.run(c2)
    cols = {r.column for r in c2.rows}
    assert WITH_LOCGEN not in cols and WITH_INTERP in cols
    assert "GlocalNet" in {r.method for r in c2.rows}


def test_seq2seq_family_rows_join_the_published_ones(suite):
    """Seq2Seq, att. Seq2Seq and Vae Seq2Seq each get both published columns (and ours), under the method
    strings of GlocalNet Table 1 in reports/published_results.csv."""
    _, rows = suite
    pub = pd.read_csv(REPO / "reports" / "published_results.csv")
    pub = pub[(pub["paper"] == "battan2021_glocalnet") & (pub["table"] == "Table 1")]
    for run, label in SEQ2SEQ_FAMILY.items():
        mine = rows[rows["method"] == label]
        assert set(mine["column"]) == {WITH_LOCGEN, WITH_INTERP, AS_GENERATED}, label
        assert set(mine["run"]) == {run} and set(mine["kind"]) == {"model"}
        assert set(pub.loc[pub["method"] == label, "column"]) == {WITH_LOCGEN, WITH_INTERP}, label
        assert set(mine["key"]) == {"table1/with_locgen", "table1/with_interpolation", "table1/as_generated"}


def test_deterministic_rows_are_one_value_and_vae_seq2seq_is_mean_and_std_over_seeds(suite):
    ctx, rows = suite
    for label in ("Seq2Seq", "att. Seq2Seq", "GlocalNet", "Zero-velocity"):
        r = rows[rows["method"] == label]
        assert (r["seeds"] == 1).all() and r["std"].isna().all() and r["note"].str.contains("deterministic").all()
    vae = rows[rows["method"] == "Vae Seq2Seq"]
    assert (vae["seeds"] == len(ctx.seeds)).all() and len(ctx.seeds) > 1
    assert (vae["std"] > 0).all() and vae["note"].str.contains("stochastic: mean \\+- std").all()


def test_vae_seq2seq_cell_is_the_mean_and_std_of_one_roll_out_per_seed(suite):
    """The ``as generated`` cell recomputed by hand: one roll-out per evaluation seed from the 21-frame seed."""
    ctx, rows = suite
    data = ctx.data("glocal", "test")
    idx = ctx.pick(data, 40)
    gt = ctx.raw(data, idx)["pose"]
    batch = data.batch(idx)
    model = ctx.model("vae_seq2seq")[0]
    per_seed = []
    for s in ctx.seeds:
        torch.manual_seed(s)
        z = model.generate(batch.pose[:, :21], labels=batch.labels, length=96)
        per_seed.append(frame_errors(ctx.physical(data, z), gt, 30.0, np.arange(21, 96), 0).mean())
    assert np.ptp(per_seed) > 0                                          # the draws differ
    row = rows[(rows["method"] == "Vae Seq2Seq") & (rows["column"] == AS_GENERATED)].iloc[0]
    np.testing.assert_allclose(row["value"], np.mean(per_seed), rtol=1e-9)
    np.testing.assert_allclose(row["std"], np.std(per_seed, ddof=1), rtol=1e-6)


def test_unknown_and_bad_options_are_named(suite):
    ctx, _ = suite
    for bad, match in (({"compare_too": "x"}, "unknown option.*compare_too"),
                       ({"stochastic_check_windows": 0}, "stochastic_check_windows")):
        cfg = {**ctx.cfg, "dataset": {**ctx.cfg["dataset"], "evaluate": {"interpolation": bad}}}
        with pytest.raises(ValueError, match=match):
            interpolation.run(EvalContext(cfg, ctx.runs))

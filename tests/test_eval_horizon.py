"""GlocalNet Table 4 suite (``horizon``) on a tiny real cmu_aclstm project: rows, known answers, samples."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth.evaluation import EvalContext, evaluate, horizon

DS = "cmu_aclstm"
HORIZONS = [80, 160, 240, 320, 400, 480, 560, 640]


@pytest.fixture(scope="module")
def suite(tmp_path_factory, one_thread):
    r = tmp_path_factory.mktemp("horizon")
    # GloGen's loss ablations (GlocalNet Table 2) and the Seq2Seq variants of GlocalNet's tables among the runs
    runs = build_eval_root(r, DS, {"glogen": ("glogen", "none"), "locgen": ("locgen", "none"),
                                   "glogen_lj": ("glogen_lj", "none"), "glogen_lmf": ("glogen_lmf", "none"),
                                   "seq2seq": ("seq2seq", "none"), "att_seq2seq": ("att_seq2seq", "none"),
                                   "vae_seq2seq": ("vae_seq2seq", "none"), "zero_velocity": ("zero_velocity", "none"),
                                   "mean_pose": ("mean_pose", "none")},
                           max_items=12, batches=1)            # 12 items: every class has a test sequence
    # a training-seed replica of Seq2Seq (another seed, 2 steps): its rows become mean +- std over the seeds
    from motionsynth.training.run import run as train_run
    train_run(compose_cfg(r, DS, "model=seq2seq", "run_name=seq2seq-seed1", "seed=1", "train.steps=2",
                          "train.eval_every=1"), progress=False)
    runs["seq2seq-seed1"] = "seq2seq"
    (r / "conf").symlink_to(REPO / "conf")                     # the method labels (conf/model/*.yaml: label)
    cfg = compose_cfg(r, DS, "eval.max_windows=100000", "eval.animation.sequences=2", "eval.threads=1")
    cfg["dataset"]["evaluate"] = {**cfg["dataset"]["evaluate"], "suites": ["horizon"]}
    ctx = evaluate(cfg, runs)
    return ctx, pd.DataFrame([vars(x) for x in ctx.rows])


def test_rows_cover_every_method_class_and_exactly_the_horizons(suite):
    ctx, rows = suite
    assert set(rows["table"]) == {"Table 4"} and set(rows["metric"]) == {"Euclidean distance per frame"}
    assert {"GloGen", "GloGen + interpolation", "GloGen (L_J)", "GloGen (L_J) + interpolation", "GloGen (L_MF)",
            "GloGen (L_MF) + interpolation", "Seq2Seq", "att. Seq2Seq", "Vae Seq2Seq", "Zero-velocity", "Mean pose",
            "Zero-velocity (world-oriented)"} == set(rows["method"])       # the replica is no row of its own
    s2s = rows[rows["method"] == "Seq2Seq"]
    assert (s2s["seeds"] == 2).all() and np.isfinite(s2s["std"]).all() and "2 training seeds" in s2s["note"].iloc[0]
    assert (rows.loc[rows["method"] == "GloGen", "seeds"] == 1).all()
    # Vae Seq2Seq draws its latent on every roll-out: measured stochastic, mean +- std over the evaluation seeds
    vae = rows[rows["method"] == "Vae Seq2Seq"]
    assert (vae["seeds"] == len(ctx.seeds)).all() and len(ctx.seeds) > 1 and (vae["std"] > 0).all()
    assert vae["note"].str.contains("stochastic").all() and (vae["run"] == "vae_seq2seq").all()
    att = rows[rows["method"] == "att. Seq2Seq"]
    assert (att["seeds"] == 1).all() and att["std"].isna().all() and (att["run"] == "att_seq2seq").all()
    assert set(rows.loc[rows["method"].isin(["Zero-velocity", "Mean pose"]), "kind"]) == {"reference"}
    data = ctx.data("glocal", "test")
    present = {str(n) for n in data.meta["label_name"].to_numpy()[np.unique(data.windows["seq"])]}
    assert present == {"indian", "martial", "salsa"}
    expect = {"indian": "CMU Indian dance", "martial": "CMU martial arts", "salsa": "CMU salsa (ours only)"}
    assert set(rows["compare_to"]) == {expect[c] for c in present}
    for _, g in rows.groupby(["method", "compare_to"]):
        assert list(g["column"]) == [f"{h}ms" for h in HORIZONS]           # exactly 80..640 ms, in order
        assert np.isfinite(g["value"]).all() and (g["value"] >= 0).all() and (g["n"] > 0).all()
    assert set(rows.loc[rows["method"].str.startswith("Zero"), "kind"]) == {"reference"}
    assert rows.groupby(["method", "key"]).size().max() == 1                 # DVC metric keys are unique
    # the DVC plot curves: one per class, one line per method
    assert {f"euclid_vs_horizon_{c}" for c in present} == set(ctx.curves)


def test_loss_ablations_are_glogen_rows_of_their_own(suite):
    """GloGen (L_J) / (L_MF) (GlocalNet Table 2) are scored as GloGen is (the LocGen chain and eq. 3), under their
    own labels, recognised by class and config; the full GloGen's rows are those of its own run."""
    ctx, rows = suite
    lj, lmf = ctx.model("glogen_lj")[0], ctx.model("glogen_lmf")[0]
    assert (lj.lambda_joint, lj.lambda_flow, lmf.lambda_joint, lmf.lambda_flow) == (1.0, 0.0, 0.0, 1.0)
    assert horizon.glogen_runs(ctx, ctx.available()) == (["glogen"], ["glogen_lj", "glogen_lmf"])
    assert horizon.variant_of(ctx, "glogen_lj") == "glogen" and horizon.variant_of(ctx, "glogen") is None
    by = rows.set_index(["method", "compare_to", "column"])
    for label, run in (("GloGen", "glogen"), ("GloGen (L_J)", "glogen_lj"), ("GloGen (L_MF)", "glogen_lmf")):
        chain, interp = rows[rows["method"] == label], rows[rows["method"] == f"{label} + interpolation"]
        assert (chain["run"] == f"{run}+locgen").all() and (interp["run"] == run).all()
        assert len(chain) == len(interp) == len(rows[rows["method"] == "Seq2Seq"])
        assert (chain["seeds"] == 1).all() and chain["note"].str.startswith(f"GlocalNet chain: {label} ").all()
        assert (chain["key"].str.startswith("euclid_")).all()
        if run != "glogen":
            assert chain["note"].str.contains("loss ablation").all()
            assert interp["note"].str.contains("lambda_flow").all()
        else:
            assert not chain["note"].str.contains("loss ablation").any()
    # differently trained models: different numbers
    a = by.xs("GloGen (L_J)", level="method")["value"]
    b = by.xs("GloGen (L_MF)", level="method")["value"]
    assert not np.allclose(a.to_numpy(), b.to_numpy())
    # animation samples: one chain per GloGen-family run
    assert {"GlocalNet", "GlocalNet (L_J)", "GlocalNet (L_MF)", "GloGen (L_J) + interpolation"} <= set(ctx.samples)


def test_zero_velocity_equals_a_direct_numpy_computation(suite):
    ctx, rows = suite
    data = ctx.data("glocal", "test")
    S = 5 * 4 + 1                                        # GloGen's t_in = 5 sparse poses every 5 frames
    raw = ctx.raw(data, np.arange(len(data)))
    pose = raw["pose"]                                   # [B, 96, 57, 3], acLSTM units
    fps = float(data.rep["fps"])
    names = dict(zip(data.meta["label"], data.meta["label_name"]))
    zv = rows[rows["method"] == "Zero-velocity"]
    for c in np.unique(raw["labels"]):
        g = pose[raw["labels"] == c]
        g = g - g[:, :, :1]                              # root (hip, joint 0) subtracted per frame
        expect = []
        for h in HORIZONS:
            t = S - 1 + h * fps / 1000.0                 # exact fractional frame, linear in between
            lo = int(math.floor(t))
            w = t - lo
            truth = (1 - w) * g[:, lo] + w * g[:, lo + 1]
            d = (truth - g[:, S - 1]).reshape(len(g), -1)
            expect.append(np.sqrt((d ** 2).sum(-1)).mean())
        got = zv[zv["compare_to"].str.contains({"indian": "Indian", "martial": "martial",
                                                 "salsa": "salsa"}[names[c]])]["value"].to_numpy()
        np.testing.assert_allclose(got, expect, rtol=1e-4)
        assert np.all(np.diff(expect) > -0.5)            # sanity: a frozen pose drifts away over time


def test_world_oriented_row_differs_only_by_orientation(suite):
    ctx, rows = suite
    a = rows[rows["method"] == "Zero-velocity"].set_index(["compare_to", "column"])["value"]
    b = rows[rows["method"] == "Zero-velocity (world-oriented)"].set_index(["compare_to", "column"])["value"]
    assert (b.index == a.index).all() and not np.allclose(a, b)
    assert (b / a).between(0.5, 2.0).all()               # same magnitude: only the heading differs


def test_samples_are_whole_windows_from_the_same_seed(suite):
    ctx, _ = suite
    gt = ctx.samples["ground truth"]
    assert gt.shape[0] == 2 and gt.shape[1:] == (96, 57, 3)
    S = ctx.sample_meta["seed_frames"]
    assert S == 21 and ctx.sample_meta["fps"] == 30 and len(ctx.sample_meta["parents"]) == 57
    assert ctx.sample_meta["space"] == "3d" and ctx.sample_meta["trajectory"] is False
    for key in ("GlocalNet", "GloGen + interpolation", "Seq2Seq", "Zero-velocity"):
        x = ctx.samples[key]
        assert x.shape == gt.shape and np.isfinite(x).all()
        np.testing.assert_allclose(x[:, 0:S:5], gt[:, 0:S:5], atol=1e-4)     # seed keyframes are ground truth
    np.testing.assert_allclose(ctx.samples["Seq2Seq"][:, :S], gt[:, :S], atol=1e-4)   # dense seed copied
    np.testing.assert_allclose(ctx.samples["Zero-velocity"][:, S:], np.repeat(gt[:, S - 1:S], 96 - S, 1),
                               atol=1e-4)


def test_bad_options_get_clear_errors(suite, tmp_path):
    ctx, _ = suite
    cfg = dict(ctx.cfg)
    cfg["dataset"] = {**cfg["dataset"], "evaluate": {"suites": [], "horizon": {"frame_mapping": "nearest"}}}
    with pytest.raises(ValueError, match="frame_mapping"):
        horizon.run(EvalContext(cfg, ctx.runs))
    cfg["dataset"]["evaluate"]["horizon"] = {"horizons_ms": [80, 4000]}
    with pytest.raises(ValueError, match="4000 ms"):
        horizon.run(EvalContext(cfg, ctx.runs))
    cfg["dataset"]["evaluate"]["horizon"] = {"stochastic_check_windows": 0}
    with pytest.raises(ValueError, match="stochastic_check_windows must be an integer >= 1"):
        horizon.run(EvalContext(cfg, ctx.runs))

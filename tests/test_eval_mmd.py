"""The mmd suite (GlocalNet Table 3) on a tiny real Human3.6M project: rows, calibration, samples, determinism."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth.evaluation import EvalContext, evaluate
from motionsynth.evaluation import mmd as suite

DS = "h36m"
#: GloGen's loss ablations (GlocalNet Table 2) are models like any other here, rows of their own
MODELS = {"glogen": "GloGen", "glogen_lj": "GloGen (L_J)", "glogen_lmf": "GloGen (L_MF)", "seq2seq": "Seq2Seq",
          "zero_velocity": "Zero-velocity"}
CALIBRATION = {"test": ["Real test clips, 2nd draw", "Real train clips", "Still real pose", "Reversed real clips",
                        "Gaussian noise"],
               "train": ["Real train clips, 2nd draw", "Real test clips", "Still real pose", "Reversed real clips",
                         "Gaussian noise"]}
SEEDED = {"Real test clips, 2nd draw", "Real train clips, 2nd draw", "Still real pose", "Gaussian noise"}
COLS = ["MMD_avg", "MMD_seq", "velocity MMD_avg", "velocity MMD_seq"]


@pytest.fixture(scope="module")
def root(tmp_path_factory, one_thread):
    r = tmp_path_factory.mktemp("mmdroot")
    # 20 items: S11 (test) holds Eating, Sitting, Walking; the train subjects Eating and Walking, not Sitting
    runs = build_eval_root(r, DS, {m: (m, "none") for m in MODELS}, max_items=20)
    (r / "conf").symlink_to(REPO / "conf")  # the models' display labels (conf/model/<m>.yaml: label)
    return r, runs


def config(r: Path, **mmd) -> dict:
    cfg = compose_cfg(r, DS, "eval.seeds=3", "eval.threads=1")
    cfg["dataset"]["evaluate"] = {"suites": ["mmd"], "mmd": {**cfg["dataset"]["evaluate"].get("mmd", {}),
                                                             "per_class": 25, **mmd}}
    return cfg


@pytest.fixture(scope="module")
def done(root):
    r, runs = root
    ctx = evaluate(config(r), runs)
    return ctx, pd.DataFrame([vars(x) for x in ctx.rows])


def value(table: pd.DataFrame, proto: str, method: str, column: str) -> float:
    sel = table[(table.protocol == suite.PROTOCOLS[proto]) & (table.method == method) & (table.column == column)]
    assert len(sel) == 1, (proto, method, column, len(sel))
    return float(sel["value"].iloc[0])


def test_rows_keys_and_protocols(done):
    ctx, t = done
    for proto in suite.PROTOCOLS:
        for method in [*MODELS.values(), *CALIBRATION[proto]]:
            for col in COLS:
                v = value(t, proto, method, col)
                assert math.isfinite(v) and 0 <= v <= 1.5, (proto, method, col, v)
    assert len(t) == 2 * (len(MODELS) + 5) * len(COLS)
    assert set(t.protocol) == {"test split (ours)", "train split (reference code)"}
    assert (t.paper == "battan2021_glocalnet").all() and (t.table == "Table 3").all() and (t.metric == "MMD").all()
    assert not t.duplicated(["method", "key"]).any()                 # one DVC metric per (method, key)
    assert set(t.key) == {f"mmd/{p}/{c}" for p in ("test", "train")
                          for c in ("mmd_avg", "mmd_seq", "velocity_mmd_avg", "velocity_mmd_seq")}
    models = t[t.run.fillna("") != ""]
    assert set(models.method) == set(MODELS.values()) and set(models.run) == set(MODELS)
    assert models["std"].isna().all() and models.note.str.startswith("deterministic").all()
    assert set(models[models.kind == "reference"].method) == {"Zero-velocity"}   # trivial: listed as a reference
    ref = t[(t.kind == "reference") & (t.run.fillna("") == "")]
    seeded = ref.method.isin(SEEDED)
    assert (ref[seeded].seeds == 3).all() and ref[seeded]["std"].notna().all()
    assert ref[~seeded]["std"].isna().all() and (ref.run == "").all()
    # 2 classes in both splits (Eating, Walking), 25 clips each; Sitting has no train windows here
    assert (t.n == 50).all() and t.condition.str.contains("Sitting").all()
    # the same S11-against-train number under both protocols
    for col in COLS:
        assert value(t, "test", "Real train clips", col) == value(t, "train", "Real test clips", col)
    # outputs written, metrics keyed by protocol
    metrics = json.loads((ctx.paths["reports"] / "metrics" / f"{DS}.json").read_text())
    assert metrics["glogen"]["mmd/train/mmd_avg"] == round(value(t, "train", "GloGen", "MMD_avg"), 6)


def test_loss_ablation_rows(done):
    """GloGen (L_J) / (L_MF): both protocols, the paper's columns and the velocity ones, their loss weights in the
    note; the full GloGen keeps its own rows and note."""
    ctx, t = done
    for run, label, weights in (("glogen_lj", "GloGen (L_J)", "lambda_joint = 1 (L_J, eq. 6), lambda_flow = 0"),
                                ("glogen_lmf", "GloGen (L_MF)", "lambda_joint = 0 (L_J, eq. 6), lambda_flow = 1")):
        rows = t[t.method == label]
        assert len(rows) == len(suite.PROTOCOLS) * len(COLS)
        assert (rows.run == run).all() and (rows.kind == "model").all()
        assert set(zip(rows.protocol, rows.column)) == {(p, c) for p in suite.PROTOCOLS.values() for c in COLS}
        assert rows.note.str.contains("loss ablation").all() and rows.note.str.contains(weights, regex=False).all()
        assert rows.note.str.contains("t_in 10, t_out 50").all()                     # the GloGen protocol applies
    full = t[t.method == "GloGen"]
    assert len(full) == len(suite.PROTOCOLS) * len(COLS) and (full.run == "glogen").all()
    assert full.note.str.contains("Our Method (GloGen)", regex=False).all()
    assert not full.note.str.contains("ablation").any()
    # three differently trained models, three sets of numbers
    assert len({tuple(t[t.method == m].sort_values("key")["value"].round(12)) for m in
                ("GloGen", "GloGen (L_J)", "GloGen (L_MF)")}) == 3


def test_compare_to_is_the_published_table_3_string():
    published = REPO.parent / "shared" / "papers" / "published_results.csv"
    if not published.exists():
        pytest.skip("../shared/papers/published_results.csv is not here")
    p = pd.read_csv(published)
    t3 = p[(p.paper == suite.PAPER) & (p.table == suite.TABLE)]
    assert set(t3.dataset) == {suite.COMPARE_TO}
    assert set(t3[t3.method == "GloGen"].column) == {"MMD_avg", "MMD_seq"}


def test_calibration_rows_rank_as_they_must(done):
    _, t = done
    for proto in suite.PROTOCOLS:
        second = CALIBRATION[proto][0]
        for col in ("MMD_avg", "MMD_seq"):
            assert value(t, proto, second, col) < value(t, proto, "Gaussian noise", col)
        for col in ("velocity MMD_avg", "velocity MMD_seq"):
            # a still pose has zero velocity: far from real motion, whatever its pose
            assert value(t, proto, "Still real pose", col) > 5 * value(t, proto, second, col)
            assert value(t, proto, "Still real pose", col) > 0.9
            # Zero-velocity generates still sequences too: the very same velocity features (the still pose's row is
            # the mean of that one value over 3 seeds, which may differ from it in the last bit)
            assert value(t, proto, "Zero-velocity", col) == pytest.approx(value(t, proto, "Still real pose", col),
                                                                         rel=1e-15)
    # the gap between subjects is larger than a second draw of the same subjects
    assert value(t, "test", "Real train clips", "MMD_avg") > value(t, "test", "Real test clips, 2nd draw", "MMD_avg")


def test_per_class_curve_and_samples(done, root):
    ctx, _ = done
    curve = pd.DataFrame(ctx.curves["mmd_per_class"])
    assert set(curve.horizon) == {"Eating", "Walking"}
    assert set(MODELS.values()) | {"Still real pose", "Gaussian noise"} <= set(curve.method)
    assert np.isfinite(curve.value).all() and not curve.duplicated(["method", "horizon"]).any()
    gt = ctx.samples["ground truth"]
    assert gt.shape == (2, 60, 15, 2)
    test = ctx.data("glocal", "test")
    meta = ctx.sample_meta
    for clip, seq, start in zip(gt, meta["sequences"], meta["start_frames"]):           # pixels, hip-centred
        row = test.meta.set_index("sequence_id").loc[seq]
        assert start >= 90 and suite.split_table(ctx)[seq] == "test"                    # frame >= 300 at 50 Hz
        assert np.allclose(clip, test.pose[row.offset + start:row.offset + start + 60], atol=1e-3)
    for m in MODELS.values():
        out = ctx.samples[m]
        assert out.shape == gt.shape and np.isfinite(out).all()
        assert np.abs(out[:, :10] - gt[:, :10]).max() < 1e-2                           # the seed, de-normalised
    assert np.abs(gt).max() < 2000 and np.abs(gt).max() > 20                           # pixels, not normalised units
    assert meta["space"] == "2d" and abs(meta["fps"] - 50 / 3) < 1e-9
    assert len(meta["parents"]) == len(meta["joints"]) == 15 and meta["joints"][0] == "RHip"
    assert meta["seed_frames"] == 10 and meta["units"] == "pixels"
    npz = np.load(ctx.paths["samples"] / f"{DS}.npz")
    assert npz["m:GloGen"].shape == (2, 60, 15, 2)


def test_rerun_gives_identical_numbers(done, root):
    r, runs = root
    _, first = done
    ctx = EvalContext(config(r), runs)
    suite.run(ctx)
    again = pd.DataFrame([vars(x) for x in ctx.rows])
    pd.testing.assert_frame_equal(first, again)


def test_reference_exact_options_run(root):
    r, runs = root
    ctx = EvalContext(config(r, per_class=10, cross="paired", negative="nan"), {"zero_velocity": "zero_velocity"})
    suite.run(ctx)
    t = pd.DataFrame([vars(x) for x in ctx.rows])
    assert np.isfinite(t.value).all() and (t.n == 20).all()
    assert t.condition.str.contains("paired").all()


@pytest.mark.parametrize("mmd, match", [({"bandwidth": 3}, "unknown key.*bandwidth"),
                                        ({"per_class": 1}, "per_class must be an integer >= 2"),
                                        ({"negative": "zero"}, "negative must be one of"),
                                        ({"min_start": -1}, "min_start must be an integer >= 0")])
def test_bad_options_fail_clearly(root, mmd, match):
    r, runs = root
    with pytest.raises(ValueError, match=match):
        suite.run(EvalContext(config(r, **mmd), runs))


def test_calibration_fakes():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 50, 15, 2))
    s = suite.still(x, np.random.default_rng(1))
    assert (s == s[:, :1]).all()                                                      # held still
    assert all(any((s[i, 0] == x[i, t]).all() for t in range(50)) for i in range(40))  # one of its own poses
    lab = np.repeat([3, 7], 20)
    x[lab == 7] += 5.0
    z = suite.noise(np.repeat(x, 10, axis=0), np.repeat(lab, 10), np.random.default_rng(2))
    assert abs(z[np.repeat(lab, 10) == 7].mean() - 5.0) < 0.05 and abs(z[np.repeat(lab, 10) == 3].std() - 1) < 0.05


def test_clips_are_drawn_as_the_reference_loader_does(root):
    """Every real clip is the 50 Hz take's frames t, t + 3, ..., t + 147 with 300 <= t <= N - 151 (the 10 poses
    before it at the same phase seed the models), checked on the takes rebuilt at 50 Hz from their 3 phases."""
    r, runs = root
    ctx = EvalContext(config(r), runs)
    o = suite.options(ctx)
    data = ctx.data("glocal", "train")
    table = suite.split_table(ctx)
    pool, k = suite.takes(data, table, suite.POOLS["train"])
    assert k == 3 and set(table[data.meta.sequence_id.to_numpy()[np.concatenate(pool.seqs.tolist())]]) == {
        "train", "val"}                                                              # every training subject's takes
    counts = {c: 40 for c in sorted(set(pool.label))}
    a = suite.draw(pool, k, counts, o, np.random.default_rng(5))
    assert a.equals(suite.draw(pool, k, counts, o, np.random.default_rng(5)))         # seeded
    assert not a.frame.equals(suite.draw(pool, k, counts, o, np.random.default_rng(6)).frame)
    assert (a.groupby("label").size() == 40).all() and (a.length == 60).all()
    z = suite.clips(data, a)
    raw = suite.raw_clips(data, a)["pose"]
    for take in pool.itertuples():
        N = take.frames
        full = np.empty((N, 15, 2), np.float32)                                      # the take at 50 Hz
        for p, seq in enumerate(take.seqs):
            o_, f = data.offsets[seq], data.frames[seq]
            full[p::k] = data.pose[o_:o_ + f]
        mine = np.flatnonzero(np.isin(a.seq, take.seqs))
        assert len(mine), "every take is visited (40 clips per class, fewer takes)"
        for i in mine:
            t = int(a.frame[i])
            assert 300 <= t <= N - 1 - 150
            assert np.array_equal(raw[i], full[t - 30:t + 150:3])                     # 10 seed + 50 real poses
    assert np.isfinite(z).all() and z.shape == (len(a), 60, 15, 2)


def test_training_seed_replicas_are_one_row_of_mean_and_std_over_the_seeds(done, root):
    """A run with a ``<run>-seed<k>`` replica (the h36m GANs' three training seeds) reports one row per
    column: the mean and std over the training seeds, each seed's value what it scores alone."""
    from motionsynth.training.run import run as train_run
    r, _ = root
    _, first = done
    train_run(compose_cfg(r, DS, "model=seq2seq", "run_name=seq2seq-seed1", "seed=1", "train.steps=2",
                          "train.eval_every=2"), progress=False)                 # as build_eval_root trains seq2seq
    alias = r / "models" / DS / "seq2seq_alone"                                   # the replica as a run of its own
    alias.symlink_to(r / "models" / DS / "seq2seq-seed1", target_is_directory=True)
    ctx = EvalContext(config(r), {"seq2seq": "seq2seq", "seq2seq-seed1": "seq2seq", "seq2seq_alone": "seq2seq"})
    suite.run(ctx)
    t = pd.DataFrame([vars(x) for x in ctx.rows])
    assert "seq2seq-seed1" not in set(t.run)                                      # no row of its own
    for proto in suite.PROTOCOLS:
        for col in COLS:
            def pick(table, run):
                sel = table[(table.protocol == suite.PROTOCOLS[proto]) & (table.run == run) & (table.column == col)]
                assert len(sel) == 1, (proto, col, run)
                return sel.iloc[0]
            both, a, b = pick(t, "seq2seq"), pick(first, "seq2seq").value, pick(t, "seq2seq_alone").value
            assert a != b
            assert both.value == pytest.approx((a + b) / 2, rel=1e-12)
            assert both["std"] == pytest.approx(abs(a - b) / math.sqrt(2), rel=1e-9)
            assert both.seeds == 2 and "2 training seeds (runs seq2seq, seq2seq-seed1)" in both.note

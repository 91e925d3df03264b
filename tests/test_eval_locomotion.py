"""The ``locomotion`` suite (VAE-LSTM paper Tables 1-2) on a tiny real project, and its array-level pieces."""

from __future__ import annotations

import copy
import math

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import REPO, build_eval_root, compose_cfg

from motionsynth.evaluation import EvalContext, evaluate
from motionsynth.evaluation import locomotion as loco

DS = "bandai2_locomotion"
FRAMES = [70, 90, 120, 160, 210]
RUNS = {"vae_lstm": ("vae_lstm", "none"), "erd": ("erd", "none"), "erd-controls_given": ("erd", "controls_given"),
        "crbm": ("crbm", "none"), "crbm-controls_given": ("crbm", "controls_given"),
        "zero_velocity": ("zero_velocity", "none")}
T1_METHODS = {"ERD", "cRBM CD-1", "VAE-LSTM", "VAE-LSTM (prior sample)", "Zero-velocity"}


@pytest.fixture(scope="module")
def built(tmp_path_factory, one_thread):
    r = tmp_path_factory.mktemp("locoroot")
    runs = build_eval_root(r, DS, RUNS)
    (r / "conf").symlink_to(REPO / "conf")          # ctx.label reads <paths.root>/conf/model/<m>.yaml
    cfg = compose_cfg(r, DS, f"paths.reports={r}/reports", f"paths.samples={r}/samples")
    cfg["dataset"]["evaluate"]["suites"] = ["locomotion"]
    cfg["dataset"]["evaluate"]["locomotion"]["stochastic_seeds"] = None   # every seed (the option: its own test)
    ctx = evaluate(cfg, runs)
    table = pd.DataFrame([vars(x) for x in ctx.rows])
    data = ctx.data("vae_lstm")
    idx = ctx.pick(data, ctx.opts["max_windows"])
    return {"root": r, "runs": runs, "cfg": cfg, "ctx": ctx, "table": table, "data": data, "idx": idx,
            "raw": ctx.raw(data, idx)}


def value(table, tab, method, column):
    hit = table[(table.table == tab) & (table.method == method) & (table.column == column)]
    assert len(hit) == 1, (tab, method, column, len(hit))
    return hit.iloc[0]


# ----------------------------------------------------------------------------- rows

def test_rows_have_the_published_keys_and_finite_values(built):
    t, n = built["table"], len(built["idx"])
    assert set(t.paper) == {"habibie2017_vae_lstm"}
    assert set(t.compare_to) == {"Edinburgh locomotion (test, 20 sequences)"}
    assert set(t[t.table == "Table 1"].metric) == {"motion prediction error"}
    assert set(t[t.table == "Table 2"].metric) == {"pose prediction error (root-relative)"}
    for tab in ("Table 1", "Table 2"):
        assert set(t[t.table == tab].method) == T1_METHODS        # ERD from erd / erd-controls_given
        for m in T1_METHODS:
            g = t[(t.table == tab) & (t.method == m)]
            assert sorted(g.column, key=lambda c: int(c[5:])) == [f"frame{f}" for f in FRAMES]
    assert np.isfinite(t.value).all() and (t.value >= 0).all()
    assert (t.n == n).all() and n == min(len(built["data"]), built["ctx"].opts["max_windows"])
    assert value(t, "Table 1", "ERD", "frame70").key == "table1_motion/frame70"
    assert value(t, "Table 2", "VAE-LSTM", "frame210").key == "table2_pose/frame210"
    assert not t.duplicated(["method", "key"]).any()               # one metric per (method, key)
    assert value(t, "Table 1", "ERD", "frame90").run == "erd"
    assert value(t, "Table 2", "ERD", "frame90").run == "erd-controls_given"
    assert value(t, "Table 1", "ERD", "frame90").condition == "60 initial frames; no control"
    assert value(t, "Table 1", "VAE-LSTM", "frame90").condition == "4 initial frames; control"
    assert value(t, "Table 1", "VAE-LSTM (prior sample)", "frame90").condition == "0 initial frames; control"
    assert value(t, "Table 2", "ERD", "frame90").condition == "4 initial frames; control"
    # every published row of ours joins a published cell on the report's key
    pub = pd.read_csv(REPO.parent / "shared" / "papers" / "published_results.csv")
    key = ["paper", "table", "dataset", "metric", "column", "method"]
    ours = t[t.method.isin(["ERD", "cRBM CD-1", "VAE-LSTM", "VAE-LSTM (prior sample)"])].drop(columns="dataset").rename(
        columns={"compare_to": "dataset"})
    joined = ours[key].merge(pub[key], on=key, how="left", indicator=True)
    assert (joined["_merge"] == "both").all()
    assert "m^2" in value(t, "Table 1", "ERD", "frame70").note and "not comparable" in value(t, "Table 1", "ERD",
                                                                                                 "frame70").note


def test_stochastic_and_deterministic_rows(built):
    t = built["table"]
    for tab in ("Table 1", "Table 2"):
        for m in ("VAE-LSTM", "VAE-LSTM (prior sample)"):
            g = t[(t.table == tab) & (t.method == m)]
            assert (g.seeds == 5).all() and np.isfinite(g["std"]).all() and (g["std"] >= 0).all()
            assert g.note.str.contains("mean \\+- std over seeds").all()
        for m in ("ERD", "Zero-velocity"):
            g = t[(t.table == tab) & (t.method == m)]
            assert (g.seeds == 1).all() and g["std"].isna().all() and g.note.str.contains("deterministic").all()
    assert set(t[t.kind == "reference"].method) == {"Zero-velocity"}


def _crbm_per_seed(built, run: str) -> np.ndarray:
    """``[seeds, frames]``: the cRBM's Table-1 (``crbm``) or Table-2 (``crbm-controls_given``) error,
    recomputed here from its roll-out under each evaluation seed."""
    ctx, raw, data, idx = built["ctx"], built["raw"], built["data"], built["idx"]
    model, train = ctx.model(run)
    batch = data.batch(idx)
    S = model.seed_frames
    out = []
    for s in ctx.seeds:
        ctx.torch_seed(s)
        z, c = model.rollout(batch.pose[:, :S], batch.controls, batch.labels, length=240)
        p = ctx.physical(train, z)
        if run == "crbm":
            ctrl = c.numpy().astype(np.float64) * train.ctrl_std + train.ctrl_mean
            root = loco.root_from_controls(raw["root"], ctrl, 60.0, S)
            out.append(loco.motion_error(p, root, raw["pose"], raw["root"], FRAMES).mean(0))
        else:
            out.append(loco.pose_error(p, raw["pose"], FRAMES, root_index=0).mean(0))
    return np.array(out)


def test_crbm_rows_in_both_tables_are_stochastic(built):
    """The cRBM (a next-frame model with the roll-out interface, not a RecurrentBaseline) gets Table-1
    rows from its plain run and Table-2 rows from its controls_given run, each the mean +- std over the
    evaluation seeds of its Gibbs-sampled roll-outs, in the paper's row order."""
    t, ctx = built["table"], built["ctx"]
    for tab, run, cond, S in (("Table 1", "crbm", "60 initial frames; no control", 60),
                              ("Table 2", "crbm-controls_given", "4 initial frames; control", 4)):
        g = t[(t.table == tab) & (t.method == "cRBM CD-1")]
        assert sorted(g.column, key=lambda c: int(c[5:])) == [f"frame{f}" for f in FRAMES]
        assert (g.run == run).all() and (g.condition == cond).all() and (g.kind == "model").all()
        assert len(ctx.seeds) == 5 and (g.seeds == 5).all() and (g["std"] > 0).all()
        assert g.note.str.contains("stochastic: mean \\+- std over seeds").all()
        per_seed = _crbm_per_seed(built, run)                     # known answer: seeded roll-outs by hand
        assert np.allclose(g.value, per_seed.mean(0), rtol=1e-9)
        assert np.allclose(g["std"], per_seed.std(0, ddof=1), rtol=1e-6)
        assert ctx.model(run)[0].seed_frames == S
        methods = list(dict.fromkeys(t[t.table == tab].method))   # the published order: ERD, ..., cRBM, VAE-LSTM
        assert methods.index("ERD") < methods.index("cRBM CD-1") < methods.index("VAE-LSTM")
    assert ctx.sample_meta["seed_frames"]["cRBM CD-1"] == 60 and ctx.samples["cRBM CD-1"].shape[1] == 240
    for curve in ("motion_error_vs_frame", "pose_error_vs_frame"):
        c = pd.DataFrame(ctx.curves[curve])
        assert len(c[c.method == "cRBM CD-1"]) == 240


def test_stochastic_seeds_option_limits_the_crbm_seeds(built):
    """``stochastic_seeds: 2``: the cRBM's rows are the mean +- std over the first two seeds; a
    deterministic baseline keeps one value."""
    cfg = copy.deepcopy(built["cfg"])
    cfg["dataset"]["evaluate"]["locomotion"]["stochastic_seeds"] = 2
    ctx = EvalContext(cfg, {r: built["runs"][r] for r in ("crbm", "crbm-controls_given", "erd")})
    loco.run(ctx)
    t = pd.DataFrame([vars(x) for x in ctx.rows])
    for tab, run in (("Table 1", "crbm"), ("Table 2", "crbm-controls_given")):
        g = t[(t.table == tab) & (t.method == "cRBM CD-1")]
        assert (g.seeds == 2).all() and g.note.str.contains("seed \\[0, 1\\]").all()
        assert np.allclose(g.value, _crbm_per_seed(built, run)[:2].mean(0), rtol=1e-9)
    erd = t[t.method == "ERD"]
    assert (erd.seeds == 1).all() and erd["std"].isna().all()


def test_zero_velocity_known_answer(built):
    """Both tables' zero-velocity rows against numpy written here from the raw test windows."""
    t, raw = built["table"], built["raw"]
    pose, root = raw["pose"], raw["root"]
    hips = 0                                                       # Hips is joint 0 of the prepared skeleton
    for f in FRAMES:                                               # Table 2: repeat frame 4, hip-relative
        rel = lambda x: x - x[:, hips:hips + 1]                    # noqa: E731
        want = (((rel(pose[:, 3]) - rel(pose[:, f - 1])) ** 2).sum(-1).mean(-1)).mean()
        assert value(t, "Table 2", "Zero-velocity", f"frame{f}").value == pytest.approx(want, rel=1e-6, abs=1e-9)

    def world(p, r):                                               # heading rotation about +Y, then the ground offset
        c, s = np.cos(r[:, None, 2]), np.sin(r[:, None, 2])
        return np.stack([p[..., 0] * c + p[..., 2] * s + r[:, None, 0], p[..., 1],
                         -p[..., 0] * s + p[..., 2] * c + r[:, None, 1]], -1)

    still = world(pose[:, 59], root[:, 59])                        # Table 1: frame 60's pose, root held there
    for f in FRAMES:
        want = ((still - world(pose[:, f - 1], root[:, f - 1])) ** 2).sum(-1).mean(-1).mean()
        assert value(t, "Table 1", "Zero-velocity", f"frame{f}").value == pytest.approx(want, rel=1e-6)
    assert value(t, "Table 1", "Zero-velocity", "frame210").value > value(t, "Table 2", "Zero-velocity",
                                                                          "frame210").value


def test_baseline_table1_is_its_own_controls_integrated_in_global_space(built):
    ctx, raw, data, idx = built["ctx"], built["raw"], built["data"], built["idx"]
    model, train = ctx.model("erd")
    batch = data.batch(idx)
    z, c = model.rollout(batch.pose[:, :60], batch.controls, batch.labels, length=240)
    assert torch.allclose(z, model.generate(batch.pose[:, :60], batch.controls, batch.labels, length=240))
    assert torch.equal(c[:, :60], batch.controls[:, :60]) and not torch.allclose(c[:, 60:], batch.controls[:, 60:])
    ctrl = c.numpy().astype(np.float64) * train.ctrl_std + train.ctrl_mean
    root = loco.root_from_controls(raw["root"], ctrl, 60.0, 60)
    assert np.allclose(root[:, :60], raw["root"][:, :60]) and not np.allclose(root[:, 100:], raw["root"][:, 100:])
    want = loco.motion_error(ctx.physical(train, z), root, raw["pose"], raw["root"], FRAMES).mean(0)
    got = [value(built["table"], "Table 1", "ERD", f"frame{f}").value for f in FRAMES]
    assert np.allclose(got, want, rtol=1e-9)


def test_translation_changes_motion_error_not_pose_error():
    rng = np.random.default_rng(0)
    gt_pose = rng.normal(size=(3, 240, 5, 3))
    gt_root = np.concatenate([np.cumsum(rng.normal(size=(3, 240, 2)) * 0.01, 1), rng.uniform(-3, 3, (3, 240, 1))], -1)
    pred = gt_pose + 0.1 * rng.normal(size=gt_pose.shape)
    shifted = gt_root + np.array([0.3, -0.4, 0.0])                 # constant translation of the trajectory
    turned = gt_root + np.array([0.0, 0.0, 0.5])                   # constant extra heading
    m0 = loco.motion_error(pred, gt_root, gt_pose, gt_root, FRAMES)
    assert not np.allclose(loco.motion_error(pred, shifted, gt_pose, gt_root, FRAMES), m0)
    assert not np.allclose(loco.motion_error(pred, turned, gt_pose, gt_root, FRAMES), m0)
    # pose error takes no trajectory: the same for any root; exact known answer for a pure translation
    p0 = loco.pose_error(pred, gt_pose, FRAMES, root_index=0)
    assert p0.shape == (3, 5) and np.all(p0 > 0)
    assert np.allclose(loco.motion_error(gt_pose, shifted, gt_pose, gt_root, FRAMES), 0.25)   # |(0.3, 0.4)|^2
    assert np.allclose(loco.motion_error(gt_pose, gt_root, gt_pose, gt_root, FRAMES), 0.0)
    assert np.allclose(loco.pose_error(gt_pose + np.array([1.0, 2.0, 3.0]), gt_pose, FRAMES, 0), 0.0)
    with pytest.raises(ValueError, match="root \\[B, T, 3\\]"):
        loco.motion_error(pred, gt_root[:, :100], gt_pose, gt_root, FRAMES)


def test_trajectory_helpers(built):
    raw, data, idx = built["raw"], built["data"], built["idx"]
    w = data.windows.iloc[idx]
    inside = (w.start.to_numpy() >= 0) & (w.start.to_numpy() + 240 <= data.frames[w.seq.to_numpy()])
    assert inside.any()
    r = loco.root_from_controls(raw["root"][inside], raw["controls"][inside], 60.0, 1)
    d = r - raw["root"][inside]
    d[..., 2] = (d[..., 2] + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(d).max() < 1e-3                                  # GT controls integrate back to the GT root
    held = loco.held_root(raw["root"], 60)
    assert np.array_equal(held[:, :60], raw["root"][:, :60]) and np.all(held[:, 60:] == held[:, 59:60])
    with pytest.raises(ValueError, match="seed_frames"):
        loco.held_root(raw["root"], 0)


def test_samples_and_curves(built):
    ctx, raw = built["ctx"], built["raw"]
    n = ctx.opts["animation"]["sequences"]
    assert set(ctx.samples) == {"ground truth"} | T1_METHODS
    for m, x in ctx.samples.items():
        assert x.shape == (n, 240, 21, 3), (m, x.shape) and np.isfinite(x).all()
    gt = ctx.samples["ground truth"]
    assert np.allclose(gt, ctx.global_positions(raw["pose"][:n], raw["root"][:n]), atol=1e-5)
    assert np.allclose(ctx.samples["ERD"][:, :60], gt[:, :60], atol=1e-3)     # seed frames and GT root
    meta = ctx.sample_meta
    assert meta["fps"] == 60 and meta["space"] == "3d" and len(meta["parents"]) == 21 == len(meta["joints"])
    assert meta["joints"][0] == "Hips" and meta["parents"][0] == -1
    assert meta["seed_frames"]["ERD"] == 60 and meta["seed_frames"]["VAE-LSTM"] == 4
    assert meta["seed_frames"]["VAE-LSTM (prior sample)"] == 0 and meta["title"]
    npz = np.load(built["root"] / "samples" / f"{DS}.npz")
    assert npz["m:VAE-LSTM"].shape == (n, 240, 21, 3)
    curves = pd.DataFrame(ctx.curves["motion_error_vs_frame"])
    erd = curves[curves.method == "ERD"]
    assert len(erd) == 240 and erd[erd.horizon == 90].value.item() == pytest.approx(
        value(built["table"], "Table 1", "ERD", "frame90").value)
    assert np.allclose(erd[erd.horizon <= 60].value, 0.0, atol=1e-6)        # the seed is copied
    assert set(pd.DataFrame(ctx.curves["pose_error_vs_frame"]).method) == T1_METHODS
    assert (built["root"] / "reports" / "plots" / DS / "pose_error_vs_frame.csv").exists()


def test_deterministic_rerun_and_integrated_vae_trajectory(built):
    """A second run gives the same numbers; ``vae_trajectory: integrate`` changes VAE-LSTM's Table 1 rows only."""
    cfg = copy.deepcopy(built["cfg"])
    cfg["dataset"]["evaluate"]["locomotion"]["vae_trajectory"] = "integrate"
    ctx = EvalContext(cfg, built["runs"])
    loco.run(ctx)
    again, first = pd.DataFrame([vars(x) for x in ctx.rows]), built["table"]
    assert list(again.key + again.method) == list(first.key + first.method)
    vae_t1 = ((first.table == "Table 1") & first.method.str.startswith("VAE-LSTM")).to_numpy()
    assert np.array_equal(again.value.to_numpy()[~vae_t1], first.value.to_numpy()[~vae_t1])
    assert np.isfinite(again.value[vae_t1]).all() and again.note[vae_t1].str.contains("controls integrated").all()


def test_bad_options_fail_before_work(built):
    for opts, msg in (({"reduction": "bogus"}, "reduction"), ({"vae_trajectory": "x"}, "vae_trajectory"),
                      ({"framez": [70]}, "unknown option"), ({"stochastic_seeds": 0}, "stochastic_seeds"),
                      ({"stochastic_check_windows": "4"}, "stochastic_check_windows")):
        cfg = copy.deepcopy(built["cfg"])
        cfg["dataset"]["evaluate"]["locomotion"] = opts
        with pytest.raises(ValueError, match=msg):
            loco.run(EvalContext(cfg, built["runs"]))
    assert math.isfinite(value(built["table"], "Table 1", "VAE-LSTM", "frame70").value)

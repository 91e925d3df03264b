"""The selection criterion (a constant pose cannot win it) and the `converged` flag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from motionsynth.training.criteria import converged, horizon_weighted_ratio, horizon_weights
from motionsynth.training.trainer import TrainConfig, lr_factor


def synthetic(n=64, T=60, J=5, seed=0):
    """Sinusoidal 'motion' [n, T, J]: random phase, amplitude and period (1.2-1.8 s at 30 fps) per
    window and joint. Returns it and its parameters."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[None, :, None]
    phase, amp = rng.uniform(0, 2 * np.pi, (n, 1, J)), rng.uniform(0.5, 1.5, (n, 1, J))
    period = rng.uniform(36, 54, (n, 1, J))
    return amp * np.sin(2 * np.pi * t / period + phase), amp, phase, period


def per_horizon(pred, x, S):
    return ((pred[:, S:] - x[:, S:]) ** 2).mean(axis=(0, 2))           # [H]


def test_a_constant_pose_wins_the_long_rollout_error_but_not_the_criterion():
    x, amp, phase, period = synthetic()
    S = 10
    mean = np.broadcast_to(x.mean(axis=(0, 1)), x.shape).copy()        # the mean pose after the seed
    mean[:, :S] = x[:, :S]
    zero = np.repeat(x[:, S - 1:S], x.shape[1], axis=1)                  # zero-velocity
    zero[:, :S] = x[:, :S]
    t = np.arange(x.shape[1])[None, :, None]
    # a model that moves on from the last seed frame, with the wrong period: its phase drifts away
    track = amp * np.sin(2 * np.pi * ((S - 1) / period + (t - (S - 1)) / (0.6 * period)) + phase)
    track[:, :S] = x[:, :S]
    e_mean, e_zero, e_track = (per_horizon(p, x, S) for p in (mean, zero, track))
    # the long roll-out MSE (val/pred_mse) prefers the constant pose to the moving model ...
    assert e_mean.mean() < e_track.mean()
    # ... the criterion does not: the constant pose is far worse than zero-velocity (1), the model better
    r_mean, r_zero, r_track = (horizon_weighted_ratio(e, e_zero) for e in (e_mean, e_zero, e_track))
    assert r_zero == pytest.approx(1.0)
    assert r_track < 1.0 < 3 * r_zero < r_mean
    # and a model that is exact for one frame then drifts away is not chosen over the moving one either
    jump = x.copy()
    jump[:, S + 1:] = mean[:, S + 1:]
    assert horizon_weighted_ratio(per_horizon(jump, x, S), e_zero) > r_track


def test_horizon_weights_favour_the_first_frames():
    w = horizon_weights(50)
    assert w.sum() == pytest.approx(1.0) and np.all(np.diff(w) < 0)
    assert w[:10].sum() > 0.5 > w[:3].sum()
    with pytest.raises(ValueError):
        horizon_weighted_ratio([1.0, 2.0], [1.0])


def history(values, steps=None):
    steps = steps or [100 * (i + 1) for i in range(len(values))]
    return [{"step": s, "val/rel_zv": v} for s, v in zip(steps, values)]


@pytest.mark.parametrize("values,expected", [
    ([1.0, 0.8, 0.7, 0.65, 0.64, 0.639, 0.6389, 0.6388, 0.63879, 0.63878], True),   # flat over the last 20 %
    ([1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.45, 0.4, 0.35, 0.3], False),                  # still falling fast
    ([1.0, 0.9, 0.8, 0.79, 0.791, 0.792, 0.793, 0.794, 0.795, 0.7905], True),        # overfits after its best
    ([1.0, 0.9, 0.8, 0.8, 0.8, 0.8, 0.8, 0.8, 0.8, 0.7925], True),                  # 0.94 % better: < 1 %
    ([1.0, 0.9, 0.8, 0.8, 0.8, 0.8, 0.8, 0.8, 0.8, 0.7915], False),                 # 1.06 % better: not
])
def test_converged_follows_its_definition(values, expected):
    h = history(values)                       # steps 100 .. 1000: the last 20 % are steps 900 and 1000
    before = min(r["val/rel_zv"] for r in h if r["step"] <= 800)
    assert ((before - min(values)) < 0.01 * before) is expected
    assert converged(h, "val/rel_zv") is expected


def test_converged_edge_cases():
    assert converged(history([0.8, 0.79]), "val/rel_zv", tail=0.2) is False      # 1.25 % better at the end
    assert converged([{"step": 100, "val/rel_zv": 1.0}], "val/rel_zv") is False   # nothing before the last 20 %
    assert converged([], "val/rel_zv") is False
    assert converged(history([0.5, math.nan, 0.49]), "val/rel_zv") is False        # 2 % better at the end
    assert converged(history([1.0, 0.99, 0.985]), "val/rel_zv", rel_tol=0.02) is True


def test_lr_schedule_warms_up_then_decays():
    cfg = TrainConfig(lr=1e-3, lr_schedule="cosine", warmup_steps=10, min_lr_ratio=0.1)
    f = [lr_factor(s, 110, cfg) for s in range(110)]
    assert f[0] == pytest.approx(0.1) and f[9] == pytest.approx(1.0)
    assert all(a >= b for a, b in zip(f[10:], f[11:])) and f[-1] == pytest.approx(0.1, abs=1e-3)
    assert lr_factor(50, 110, TrainConfig(warmup_steps=0)) == 1.0                 # constant


def test_budget_resolution_dataset_then_variant_then_command_line():
    from motionsynth.training.run import train_config
    model = {"train": {"lr": 1e-3, "batch_size": 32},
             "schedule": {"default": {"steps": 100, "eval_every": 10, "patience": 3,
                                      "datasets": {"d": {"steps": 400, "eval_every": 40,
                                                         "variants": {"given": {"steps": 200}}}}}}}

    def cfg(ds, variant, train=None):
        return {"model": model, "profile_name": "default", "dataset": {"name": ds},
                "variant_name": variant, "train": dict(train or {}), "seed": 0}

    assert (train_config(cfg("other", None)).steps, train_config(cfg("other", "given")).steps) == (100, 100)
    assert train_config(cfg("d", None)).steps == 400 and train_config(cfg("d", None)).eval_every == 40
    given = train_config(cfg("d", "given"))
    assert (given.steps, given.eval_every, given.patience) == (200, 40, 3)   # the variant's entry adds to the dataset's
    assert train_config(cfg("d", "given", {"steps": 7, "lr": None})).steps == 7   # the command line wins

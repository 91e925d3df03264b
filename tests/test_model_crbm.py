"""cRBM (Taylor et al. 2006): shapes, the CD-k gradient against its closed form, learning, determinism, bad config."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from conftest import synthetic, train_steps
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from motionsynth.models.base import Batch, DataSpec
from motionsynth.models.crbm import CRBM

REPO = Path(__file__).resolve().parents[1]
LOCO = DataSpec(joints=21, dims=3, num_classes=4, controls=3, fps=60.0, window=240)
GLOCAL = DataSpec(joints=15, dims=2, num_classes=10, controls=0, fps=16.7, window=60)


@pytest.mark.parametrize("spec,mode", [(LOCO, "predict"), (LOCO, "given"), (GLOCAL, "predict")],
                         ids=["loco-predict", "loco-given", "glocal"])
def test_shapes(spec, mode):
    torch.manual_seed(0)
    m = CRBM(spec, hidden_size=12, order=3, cd_k=2, gibbs_steps=3, control_mode=mode, seed_frames=8)
    b = synthetic(spec)
    loss, logs = m.train().loss(b)
    assert loss.dim() == 0 and torch.isfinite(loss) and {"recon_mse", "pose_mse"} <= set(logs)
    loss.backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in m.parameters())
    m.eval()
    out = m.generate(b.pose[:, :8], b.controls, b.labels, length=20, num_samples=2)
    assert out.shape == (6, 20, spec.joints, spec.dims)
    assert torch.equal(out[::2, :8], b.pose[:, :8]) and torch.equal(out[1::2, :8], b.pose[:, :8])
    pose, ctrl = m.rollout(b.pose[:, :8], b.controls, b.labels, length=20)
    assert pose.shape == (3, 20, spec.joints, spec.dims)
    assert (ctrl is None) == (spec.controls == 0)
    if ctrl is not None:
        assert ctrl.shape == (3, 20, 3)
    assert m.predict(b).shape == b.pose.shape
    # a seed shorter than the order is padded; no seed starts from the mean pose
    assert m.generate(b.pose[:, :1], b.controls, b.labels, length=6).shape == (3, 6, spec.joints, spec.dims)
    assert m.generate(None, b.controls, b.labels, length=6).shape == (3, 6, spec.joints, spec.dims)


def test_past_frames_are_the_previous_order_frames_newest_first():
    m = CRBM(GLOCAL, hidden_size=4, order=3)
    y = torch.arange(2 * 7 * 2, dtype=torch.float32).view(2, 7, 2)
    past = m._past(y)
    assert past.shape == (2, 4, 6)
    for t in range(3, 7):
        assert torch.equal(past[:, t - 3], torch.cat([y[:, t - 1], y[:, t - 2], y[:, t - 3]], -1))


@pytest.mark.parametrize("k", [1, 15])
def test_cd_gradient_equals_the_closed_form_update(k):
    """loss.backward() gives exactly <dF/dθ>_data - <dF/dθ>_recon for every parameter (the CD-k update
    of Taylor et al., eqs. 4-5), computed here directly from the same chain end."""
    spec = DataSpec(joints=2, dims=2, num_classes=3, controls=3, fps=60.0, window=12)
    torch.manual_seed(0)
    m = CRBM(spec, hidden_size=5, order=2, cd_k=k, control_mode="given", init_std=0.3).double().train()
    b = synthetic(spec, B=4, T=12)
    b = Batch(b.pose.double(), b.controls.double(), b.labels)
    torch.manual_seed(7)
    loss, _ = m.loss(b)
    loss.backward()
    torch.manual_seed(7)                       # the same chain: _windows draws nothing, gibbs the same bits
    v0, u = m._windows(b)
    vk = m.gibbs(v0, u, k)
    v0, vk, u = (t.reshape(-1, t.shape[-1]) for t in (v0, vk, u))
    n = v0.shape[0]
    with torch.no_grad():
        bv, ch = m.biases(u)
        s0, sk = torch.sigmoid(ch + v0 @ m.W.t()), torch.sigmoid(ch + vk @ m.W.t())
        want = {
            "W": -(s0.t() @ v0 - sk.t() @ vk) / n,          # dF/dW = -sigma(c^ + W v) v^T
            "b_v": (vk - v0).sum(0) / n,                    # dF/db = -(v - b^)
            "b_h": (sk - s0).sum(0) / n,                    # dF/dc = -sigma
            "A": (vk - v0).t() @ u / n,                     # b^ = b + A u
            "B": (sk - s0).t() @ u / n,                     # c^ = c + B u
        }
    for name, g in want.items():
        assert torch.allclose(getattr(m, name).grad, g, atol=1e-12), name
    assert not torch.equal(vk, v0)


def test_whitened_conditioning_is_a_reparametrisation_folded_into_the_weights():
    """``whiten``: ``A``, ``B`` act on ``(u - cond_mean) cond_proj``. The biases, the CD gradient's chain
    and a roll-out equal those of the raw model with ``A' = A P^T``, ``b' = b - m A'^T`` (likewise ``B``,
    ``c``); without ``whiten`` the buffers are not read."""
    spec = DataSpec(joints=2, dims=2, num_classes=3, controls=3, fps=60.0, window=12)
    torch.manual_seed(0)
    w = CRBM(spec, hidden_size=5, order=2, control_mode="given", init_std=0.3, whiten=1e-3).double()
    C = w.cond_dim
    P = torch.randn(C, C, dtype=torch.float64)
    P = P @ P.T / C + torch.eye(C, dtype=torch.float64)
    w.cond_proj.copy_(P)
    w.cond_mean.copy_(torch.randn(C))
    raw = CRBM(spec, hidden_size=5, order=2, control_mode="given", whiten=None).double()
    with torch.no_grad():
        raw.W.copy_(w.W)
        raw.A.copy_(w.A @ P.T)
        raw.B.copy_(w.B @ P.T)
        raw.b_v.copy_(w.b_v - w.cond_mean @ raw.A.t())
        raw.b_h.copy_(w.b_h - w.cond_mean @ raw.B.t())
    b = synthetic(spec, B=4, T=12)
    b = Batch(b.pose.double(), b.controls.double(), b.labels)
    _, u = w._windows(b)
    explicit = (u - w.cond_mean) @ P                     # the whitened conditioning, unfolded
    bv, ch = w.biases(u)
    assert torch.allclose(bv, w.b_v + explicit @ w.A.t(), atol=1e-10)
    assert torch.allclose(ch, w.b_h + explicit @ w.B.t(), atol=1e-10)
    for x, y in zip(w.biases(u), raw.biases(u)):
        assert torch.allclose(x, y, atol=1e-10)
    torch.manual_seed(5)
    a = w.eval().generate(b.pose[:, :4], b.controls, b.labels, length=12)
    torch.manual_seed(5)
    assert torch.allclose(a, raw.eval().generate(b.pose[:, :4], b.controls, b.labels, length=12), atol=1e-8)
    raw.cond_proj.copy_(P)                               # no whiten: the buffers are not read
    assert torch.equal(raw.biases(u)[0], raw.b_v + u @ raw.A.t())


def test_more_gibbs_steps_change_the_chain():
    torch.manual_seed(0)
    m = CRBM(GLOCAL, hidden_size=8, order=2, init_std=0.2)
    b = synthetic(GLOCAL, T=10)
    v0, u = m._windows(b)
    torch.manual_seed(1)
    v1 = m.gibbs(v0, u, 1)
    torch.manual_seed(1)
    v15 = m.gibbs(v0, u, 15)
    assert not torch.allclose(v1, v15)


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    from motionsynth.training.data import real_batch

    batch, spec = real_batch("bandai2_locomotion", "vae_lstm", 8, tmp_path_factory.mktemp("loco"))
    T = 40
    return Batch(batch.pose[:, :T].contiguous(), batch.controls[:, :T].contiguous(), batch.labels), spec


def _one_step_error(m: CRBM, b: Batch) -> float:
    """Mean squared error of the next frame generated from ground-truth pasts (one step of generation
    per window position, all positions at once)."""
    v0, u = m._windows(b)
    torch.manual_seed(3)
    pred = m.gibbs(u[..., :m.state_dim], u, m.gibbs_steps, mean_last=True)   # from the previous frame
    return float((pred - v0).pow(2).mean())


@pytest.mark.parametrize("k", [1, 15])
def test_training_on_real_windows_lowers_reconstruction_and_prediction_error(real, k):
    batch, spec = real
    torch.manual_seed(0)
    m = CRBM(spec, hidden_size=32, order=3, cd_k=k, gibbs_steps=10, seed_frames=20)
    before_pred = _one_step_error(m.eval(), batch)
    recon = [logs["recon_mse"] for _, logs in train_steps(m, batch, torch.optim.Adam(m.parameters(), lr=1e-2), 150)]
    after_pred = _one_step_error(m.eval(), batch)
    assert sum(recon[-10:]) / 10 < 0.5 * sum(recon[:10]) / 10
    assert after_pred < 0.5 * before_pred


def test_deterministic_rerun():
    def once():
        torch.manual_seed(0)
        m = CRBM(LOCO, hidden_size=8, order=3, cd_k=3, gibbs_steps=4, seed_frames=5)
        b = synthetic(LOCO, T=20)
        losses = [loss for loss, _ in train_steps(m, b, torch.optim.SGD(m.parameters(), lr=1e-2, momentum=0.9), 5)]
        torch.manual_seed(1)
        return losses, m.eval().generate(b.pose[:, :5], b.controls, b.labels, length=12, num_samples=2)

    (l1, g1), (l2, g2) = once(), once()
    assert l1 == l2 and torch.equal(g1, g2)
    assert not torch.equal(g1[0::2], g1[1::2])            # two samples of one input differ


@pytest.mark.parametrize("field,value", [("cd_k", 0), ("cd_k", -1), ("hidden_size", 0), ("order", 0),
                                         ("gibbs_steps", 0), ("control_mode", "both"), ("whiten", 0),
                                         ("whiten", 1.5), ("whiten", True), ("whiten", "yes")])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        CRBM(LOCO, **{field: value})


@pytest.mark.parametrize("name,cd_k", [("crbm", 1), ("crbm_cd15", 15)])
def test_configs_compose(name, cd_k):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["dataset=bandai2_locomotion", f"model={name}"])
    m = OmegaConf.to_container(cfg.model, resolve=True)
    assert m["name"] == name and m["_target_"] == "motionsynth.models.crbm.CRBM"
    for size in ("smoke", "default", "paper"):
        assert m["sizes"][size]["cd_k"] == cd_k
        CRBM(LOCO, **m["sizes"][size])

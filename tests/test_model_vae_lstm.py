"""VAE-LSTM (Habibie et al. 2017): shapes, the exact pieces (polyphase upsampling, eq. 9 roll-out),
generation protocols, overfitting one real batch, determinism, hyperparameter validation."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from conftest import overfit
from conftest import REPO
from omegaconf import OmegaConf

from motionsynth.models.base import Batch
from motionsynth.models.vae_lstm import VAELSTM, UpConv
from motionsynth.training.data import real_batch

SIZES = OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "model" / "vae_lstm.yaml"))["sizes"]
SMOKE = SIZES["smoke"]


pytestmark = pytest.mark.usefixtures("one_thread")  # see conftest.one_thread


@pytest.fixture(scope="module")
def real(tmp_path_factory) -> tuple[Batch, object]:
    return real_batch("bandai2_locomotion", "vae_lstm", 8, tmp_path_factory.mktemp("bandai2"))


def model(spec, **over) -> VAELSTM:
    torch.manual_seed(0)
    return VAELSTM(spec, **{**SMOKE, **over})


def test_real_batch_matches_the_paper_layout(real):
    batch, spec = real
    assert (spec.joints, spec.dims, spec.controls, spec.window) == (21, 3, 3, 240)  # 63 + 3 = 66 DoF
    assert batch.pose.shape == (8, 240, 21, 3) and batch.controls.shape == (8, 240, 3)


def test_shapes_of_loss_generate_predict(real):
    batch, spec = real
    m = model(spec)
    loss, logs = m.loss(batch)
    assert loss.dim() == 0 and torch.isfinite(loss)
    assert set(logs) == {"nll", "kl", "mse", "kl_per_window", "kl_weight", "l1"}
    loss.backward()
    assert all(p.grad is not None for p in m.parameters())
    m.eval()
    assert m.predict(batch).shape == batch.pose.shape
    B = batch.size
    assert m.generate(None, batch.controls, length=240, num_samples=3).shape == (3 * B, 240, 21, 3)
    assert m.generate(batch.pose[:, :0], batch.controls).shape == (B, 240, 21, 3)
    assert m.generate(batch.pose[:, :10], batch.controls, num_samples=2).shape == (2 * B, 240, 21, 3)
    long = batch.controls.repeat(1, 2, 1)                                  # any multiple of 4 frames
    assert m.generate(None, long, length=480).shape == (B, 480, 21, 3)
    assert m.generate(None, batch.controls[:, :100], length=100).shape == (B, 100, 21, 3)


def test_paper_sizes(real):
    _, spec = real
    m = VAELSTM(spec, **SIZES["paper"])
    assert [c.weight.shape for c in m.ctrl_encoder.convs] == [(64, 3, 25), (128, 64, 25)]
    assert [c.weight.shape for c in m.inference.convs] == [(64, 63, 25), (256, 64, 25)]
    assert m.cell.state.weight.shape == (3 * 128, 128) and m.cell.ctrl.weight.shape == (3 * 128, 128)
    assert [u.conv.weight.shape for u in m.ups] == [(128, 128, 25), (128, 128, 25)]
    assert m.factor == 4 and m.seed_frames == 4


@pytest.mark.parametrize("kernel", [1, 3, 9, 11, 25])
def test_polyphase_upconv_equals_upsample_then_conv(kernel):
    torch.manual_seed(0)
    up = UpConv(5, 7, kernel)
    x = torch.randn(3, 11, 5, requires_grad=True)
    y, ref = up(x), up.reference(x)
    assert y.shape == (3, 22, 7)
    torch.testing.assert_close(y, ref, atol=1e-5, rtol=1e-5)
    g1 = torch.autograd.grad(y.square().sum(), [x, up.conv.weight])
    g2 = torch.autograd.grad(ref.square().sum(), [x, up.conv.weight])
    for a, b in zip(g1, g2):
        torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


def test_test_time_rollout_is_the_training_cell_fed_back(real):
    """Eq. 9: the fast roll-out equals the training-case cell applied to its own cell state."""
    batch, spec = real
    m = model(spec)
    g = m.encode_controls(batch.controls)
    z1 = torch.randn(batch.size, m.hidden)
    with torch.no_grad():
        fast = m.cell.rollout(z1, g)
        c, slow = z1, []
        for t in range(g.shape[1]):
            c = m.cell(c, g[:, t])
            slow.append(c)
    torch.testing.assert_close(fast, torch.stack(slow, 1), atol=1e-5, rtol=1e-5)
    one = g[:1].detach().clone()                         # a single character: g is left untouched
    torch.testing.assert_close(m.cell.rollout(z1[:1], one), fast[:1], atol=1e-5, rtol=1e-5)
    assert torch.equal(one, g[:1])


def test_posterior_uses_only_the_first_four_frames(real):
    batch, spec = real
    m = model(spec).eval()
    altered = batch.pose.clone()
    altered[:, 4:] += 1.0
    torch.manual_seed(1)
    a = m.generate(batch.pose, batch.controls)
    torch.manual_seed(1)
    b = m.generate(altered, batch.controls)
    torch.manual_seed(1)
    c = m.generate(batch.pose[:, :4], batch.controls)
    assert torch.equal(a, b) and torch.equal(a, c)
    torch.manual_seed(1)
    prior = m.generate(None, batch.controls)
    assert not torch.allclose(a, prior)
    two = m.generate(None, batch.controls[:2], num_samples=3)           # samples differ, item-major order
    assert not torch.allclose(two[0], two[1])


def test_generation_rejects_bad_inputs(real):
    batch, spec = real
    m = model(spec).eval()
    with pytest.raises(ValueError, match="multiple of the pooling factor 4"):
        m.generate(None, batch.controls[:, :238], length=238)
    with pytest.raises(ValueError, match="controls"):
        m.generate(None, None)
    with pytest.raises(ValueError, match="length=200"):
        m.generate(None, batch.controls, length=200)
    with pytest.raises(ValueError, match="needs 4 seed frames"):
        m.generate(batch.pose[:, :3], batch.controls)
    with pytest.raises(ValueError, match="controls"):
        m.loss(Batch(batch.pose))


def test_predict_protocols(real):
    batch, spec = real
    for s in (0, 4, 60):
        m = model(spec, seed_frames=s).eval()
        assert m.seed_frames == s and m.predict(batch).shape == batch.pose.shape


def test_training_unrolls_the_cell_as_generation_does(real):
    """train_mode rollout: the reconstruction is the decoder of the eq. 9 test-case roll-out from z_1 ~
    q(z_1 | first 4 frames); with z_1 = its mean the training output equals generate()'s from 4 frames."""
    batch, spec = real
    m = model(spec, dropout=0.0).eval()
    mu, _ = m.first_posterior(m.flat(batch.pose))
    with torch.no_grad():
        train_path = m.decode(m.cell.unroll(mu, m.encode_controls(batch.controls)))
        gen_path = m.decode(m.cell.rollout(mu, m.encode_controls(batch.controls)))
    torch.testing.assert_close(train_path, gen_path, atol=1e-5, rtol=1e-5)


def test_kl_warm_up_and_free_bits(real):
    batch, spec = real
    m = model(spec, kl_warmup=0.5, free_bits=2.0).train()
    m.set_progress(0, 100)
    assert m.kl_weight() == 0.0
    m.set_progress(25, 100)
    assert m.kl_weight() == pytest.approx(0.5)
    m.set_progress(80, 100)
    assert m.kl_weight() == 1.0
    assert m.eval().kl_weight() == 1.0                  # validation: the full ELBO
    torch.manual_seed(0)
    loss_fb, logs = m.train().loss(batch)
    torch.manual_seed(0)
    loss_plain, _ = model(spec, kl_warmup=0.5, free_bits=0.0).train().loss(batch)
    assert loss_fb.item() >= loss_plain.item()          # below the floor every dimension costs free_bits


def test_a_few_seconds_of_training_give_a_latent_that_changes_the_motion(real):
    """The issue's check: different latents -> different characters, and the posterior differs from the prior."""
    batch, spec = real
    torch.manual_seed(0)
    m = model(spec, dropout=0.0)
    opt = torch.optim.Adam(m.parameters(), lr=3e-3)
    for step in range(60):
        m.set_progress(step, 60)
        loss, logs = m.loss(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert logs["kl_per_window"] > 0.5                   # the posterior moved away from the prior
    m.eval()
    torch.manual_seed(1)
    samples = m.generate(None, batch.controls[:2], num_samples=4)      # [8, 240, J, 3]: 4 latents per path
    per_path = samples.reshape(2, 4, *samples.shape[1:])
    spread = per_path.std(dim=1)[:, 4:].mean().item()   # across the latents, after the first 4 frames
    assert spread > 0.05, spread                          # normalised units: a visible difference
    torch.manual_seed(1)
    post = m.generate(batch.pose[:, :4], batch.controls)
    torch.manual_seed(1)
    prior = m.generate(None, batch.controls)
    assert (post - prior).abs().mean().item() > 0.05


def test_the_aggregate_prior_is_the_gaussian_of_the_posteriors_and_generation_samples_it(real):
    """``prior: aggregate``: mean and covariance of the mixture of the windows' posteriors (eval mode), and
    generation without seed frames draws ``z_1 = prior_mean + prior_scale eps``; ``standard`` ignores them."""
    batch, spec = real
    m = model(spec, prior="aggregate").train()
    m.fit_prior(batch.pose)
    assert m.training                                    # fitted in eval mode, the mode restored
    m.eval()
    with torch.no_grad():
        mu, logvar = m.first_posterior(m.flat(batch.pose), 4)
    mu, var = mu.double(), logvar.double().exp()
    assert torch.allclose(m.prior_mean.double(), mu.mean(0), atol=1e-6)
    L = m.prior_scale.double()
    assert torch.equal(L, L.tril())
    assert torch.allclose(L @ L.T, torch.cov(mu.T, correction=0) + torch.diag(var.mean(0)), atol=1e-5)
    assert not torch.allclose(L, torch.eye(len(L), dtype=L.dtype), atol=1e-3)

    torch.manual_seed(3)
    eps = torch.randn(2, m.hidden)
    torch.manual_seed(3)
    drawn = m.generate(None, batch.controls[:2])
    z1 = m.prior_mean + eps @ m.prior_scale.T
    with torch.no_grad():
        g = m.encode_controls(batch.controls[:2])
        expected = m.unflat(m.decode(m.cell.rollout(z1, m.with_latent(g, z1))))
    assert torch.allclose(drawn, expected, atol=1e-5)

    m.prior = "standard"                                 # the paper's N(0, I): the buffers are not read
    torch.manual_seed(3)
    with torch.no_grad():
        expected = m.unflat(m.decode(m.cell.rollout(eps, m.with_latent(g, eps))))
    assert torch.allclose(m.generate(None, batch.controls[:2]), expected, atol=1e-5)


def test_overfits_one_real_batch(real):
    batch, spec = real
    m = model(spec, dropout=0.0, l1=0.0)
    first, last = overfit(m, batch)
    assert last <= 0.1 * first, (first, last)


def test_deterministic_given_the_seed(real):
    batch, spec = real

    def train() -> list[float]:
        m = model(spec)                                  # dropout and sampling on: the RNG is exercised
        opt = torch.optim.Adam(m.parameters(), lr=5e-4)
        out = []
        for _ in range(3):
            loss, _ = m.loss(batch)
            opt.zero_grad()
            loss.backward()
            opt.step()
            out.append(loss.item())
        m.eval()
        torch.manual_seed(7)
        return out + m.predict(batch).flatten()[:50].tolist()

    assert train() == train()


@pytest.mark.parametrize("over, msg", [
    ({"dropout": 1.0}, "dropout"),
    ({"dropout": -0.1}, "dropout"),
    ({"kernel": 8}, "odd"),
    ({"kernel": 0}, "kernel"),
    ({"hidden": 0}, "hidden"),
    ({"ctrl_channels": [8, -1]}, "ctrl_channels"),
    ({"inf_channels": [8]}, "same number"),
    ({"l1": -1.0}, "l1"),
    ({"recon_var": 0.0}, "recon_var"),
    ({"seed_frames": 2}, "seed_frames"),
    ({"seed_frames": 240}, "seed_frames"),
    ({"train_mode": "other"}, "train_mode"),
    ({"kl_warmup": 1.5}, "kl_warmup"),
    ({"free_bits": -1.0}, "free_bits"),
    ({"prior": "learnt"}, "prior"),
])
def test_invalid_hyperparameters_raise(real, over, msg):
    _, spec = real
    with pytest.raises(ValueError, match=msg):
        VAELSTM(spec, **{**SMOKE, **over})


def test_invalid_spec_raises(real):
    _, spec = real
    with pytest.raises(ValueError, match="spec.controls == 3"):
        VAELSTM(dataclasses.replace(spec, controls=0), **SMOKE)
    with pytest.raises(ValueError, match="window"):
        VAELSTM(dataclasses.replace(spec, window=250), **SMOKE)

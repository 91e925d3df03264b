"""att. Seq2Seq and Vae Seq2Seq (GlocalNet Table 1 rows): shapes, attention, latent, learning, determinism, bad config."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
import torch
from conftest import synthetic, train_steps
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from motionsynth.models.att_seq2seq import AttSeq2Seq
from motionsynth.models.base import Batch, DataSpec
from motionsynth.models.vae_seq2seq import VAESeq2Seq

REPO = Path(__file__).resolve().parents[1]
LOCO = DataSpec(joints=21, dims=3, num_classes=4, controls=3, fps=60.0, window=240)
GLOCAL = DataSpec(joints=15, dims=2, num_classes=10, controls=0, fps=16.7, window=60)
SMALL = {"att_seq2seq": (AttSeq2Seq, dict(hidden_size=16, attention_size=8)),
         "vae_seq2seq": (VAESeq2Seq, dict(hidden_size=16, latent_size=4))}


@pytest.mark.parametrize("name", list(SMALL))
@pytest.mark.parametrize("spec,mode", [(LOCO, "predict"), (LOCO, "given"), (GLOCAL, "predict")],
                         ids=["loco-predict", "loco-given", "glocal"])
def test_shapes(name, spec, mode):
    cls, kw = SMALL[name]
    torch.manual_seed(0)
    m = cls(spec, control_mode=mode, seed_frames=8, **kw)
    b = synthetic(spec)
    loss, logs = m.train().loss(b)
    assert loss.dim() == 0 and torch.isfinite(loss) and "pose_mse" in logs
    loss.backward()
    assert all(p.grad is not None for p in m.parameters())
    m.eval()
    out = m.generate(b.pose[:, :8], b.controls, b.labels, length=20, num_samples=2)
    assert out.shape == (6, 20, spec.joints, spec.dims) and torch.equal(out[::2, :8], b.pose[:, :8])
    pose, ctrl = m.rollout(b.pose[:, :8], b.controls, b.labels, length=20)
    assert pose.shape == (3, 20, spec.joints, spec.dims) and (ctrl is None) == (spec.controls == 0)
    assert m.predict(b).shape == b.pose.shape


@pytest.mark.parametrize("name", list(SMALL))
def test_untrained_model_is_zero_velocity(name):
    """The residual output layer starts at zero, as Seq2Seq's: every generated frame repeats the last seed frame."""
    cls, kw = SMALL[name]
    torch.manual_seed(0)
    m = cls(GLOCAL, seed_frames=6, **kw).eval()
    b = synthetic(GLOCAL, T=16)
    out = m.generate(b.pose[:, :6], labels=b.labels, length=16)
    assert torch.allclose(out[:, 6:], b.pose[:, 5:6].expand(-1, 10, -1, -1), atol=1e-6)


def test_attention_weights_per_output_step():
    torch.manual_seed(0)
    m = AttSeq2Seq(GLOCAL, hidden_size=16, attention_size=8, seed_frames=6).eval()
    b = synthetic(GLOCAL, T=16)
    m.generate(b.pose[:, :6], labels=b.labels, length=16)
    w = m.last_attention
    # every one of the 15 output steps (6 over the seed, 9 decoding) attends over the 6 encoder states
    assert w.shape == (3, 15, 6) and torch.allclose(w.sum(-1), torch.ones(3, 15), atol=1e-6)
    # with a trained-looking (non-zero) query map the weights differ between decoding steps
    torch.nn.init.normal_(m.att_query.weight, std=2.0)
    m.generate(b.pose[:, :6], labels=b.labels, length=16)
    assert not torch.allclose(m.last_attention[:, 6], m.last_attention[:, -1])


def test_vae_samples_differ_and_prior_mode_ignores_the_seed_encoding():
    torch.manual_seed(0)
    m = VAESeq2Seq(GLOCAL, hidden_size=16, latent_size=4, seed_frames=6).eval()
    for p in m.decoder.parameters():              # as after training: a non-zero output layer
        torch.nn.init.normal_(p, std=0.1)
    b = synthetic(GLOCAL, B=2, T=16)
    out = m.generate(b.pose[:, :6], labels=b.labels, length=16, num_samples=3)
    assert not torch.allclose(out[0], out[1]) and not torch.allclose(out[1], out[2])
    assert torch.equal(out[:, :6], b.pose[:, :6].repeat_interleave(3, 0))
    m.sample_from = "prior"
    torch.manual_seed(5)
    p1 = m.generate(b.pose[:, :6], labels=b.labels, length=16)
    seed2 = b.pose[:, :6].clone()
    seed2[:, 0] += 1.0                            # frame 0 reaches the decoder only through the latent
    torch.manual_seed(5)
    p2 = m.generate(seed2, labels=b.labels, length=16)
    assert torch.allclose(p1[:, 6:], p2[:, 6:])


def test_vae_kl_warmup_and_loss_terms():
    m = VAESeq2Seq(GLOCAL, hidden_size=8, latent_size=4, beta=0.5, kl_warmup=0.2, seed_frames=6)
    m.set_progress(0, 100)
    assert m.kl_weight() == 0.0
    m.set_progress(10, 100)
    assert m.kl_weight() == pytest.approx(0.25)
    m.set_progress(50, 100)
    assert m.kl_weight() == pytest.approx(0.5)
    loss, logs = m.train().loss(synthetic(GLOCAL, T=16))
    assert {"mse", "kl", "kl_weight"} <= set(logs) and logs["kl"] >= 0
    assert float(loss.detach()) == pytest.approx(logs["mse"] + 0.5 * logs["kl"] / m.state_dim, rel=1e-5)


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    from motionsynth.training.data import real_batch

    batch, spec = real_batch("cmu_aclstm", "glocal", 8, tmp_path_factory.mktemp("cmu"))
    return batch, spec


@pytest.mark.parametrize("name", list(SMALL))
def test_training_on_real_windows_lowers_the_loss(real, name):
    batch, spec = real
    cls, kw = SMALL[name]
    torch.manual_seed(0)
    m = cls(spec, seed_frames=10, **{**kw, "hidden_size": 32})
    losses = [logs["pose_mse"] for _, logs in train_steps(m, batch, torch.optim.Adam(m.parameters(), lr=3e-3), 40)]
    assert sum(losses[-5:]) / 5 < 0.8 * sum(losses[:5]) / 5


@pytest.mark.parametrize("name", list(SMALL))
def test_deterministic_rerun(name):
    cls, kw = SMALL[name]

    def once():
        torch.manual_seed(0)
        m = cls(LOCO, seed_frames=8, **kw)
        b = synthetic(LOCO, T=20)
        losses = [loss for loss, _ in train_steps(m, b, torch.optim.Adam(m.parameters(), lr=1e-2), 4)]
        torch.manual_seed(1)
        return losses, m.eval().generate(b.pose[:, :8], b.controls, b.labels, length=14)

    (l1, g1), (l2, g2) = once(), once()
    assert l1 == l2 and torch.equal(g1, g2)


@pytest.mark.parametrize("cls,field,value", [
    (AttSeq2Seq, "attention_size", 0), (AttSeq2Seq, "scheduled_sampling", True),
    (VAESeq2Seq, "latent_size", 0), (VAESeq2Seq, "beta", -1.0), (VAESeq2Seq, "kl_warmup", 1.5),
    (VAESeq2Seq, "sample_from", "mode"), (VAESeq2Seq, "scheduled_sampling", True)])
def test_bad_config_names_the_field(cls, field, value):
    with pytest.raises(ValueError, match=field):
        cls(GLOCAL, hidden_size=8, **{field: value})


@pytest.mark.parametrize("name,target,extra", [
    ("att_seq2seq", "motionsynth.models.att_seq2seq.AttSeq2Seq", "attention_size"),
    ("vae_seq2seq", "motionsynth.models.vae_seq2seq.VAESeq2Seq", "latent_size")])
def test_configs_compose_on_seq2seq(name, target, extra):
    """The variants take Seq2Seq's sizes and optimiser, and its budgets unless they set their own
    (att. Seq2Seq: 2.3x Seq2Seq's cost per step, its own shorter schedule)."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["dataset=bandai1", f"model={name}"])
        base = compose("config", overrides=["dataset=bandai1", "model=seq2seq"])
    m, s = (OmegaConf.to_container(c.model, resolve=True) for c in (cfg, base))
    assert m["name"] == name and m["_target_"] == target
    assert m["train"] == s["train"]
    own = yaml.safe_load((REPO / "conf" / "model" / f"{name}.yaml").read_text())
    assert ("schedule" in own) or m["schedule"] == s["schedule"]
    cls = AttSeq2Seq if name == "att_seq2seq" else VAESeq2Seq
    for size in ("smoke", "default", "paper"):
        assert m["sizes"][size]["hidden_size"] == s["sizes"][size]["hidden_size"] and extra in m["sizes"][size]
    cls(GLOCAL, **m["sizes"]["smoke"])

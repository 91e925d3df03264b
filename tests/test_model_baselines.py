"""The baselines: ERD, LSTM-3LR, Seq2Seq, acLSTM, scheduled sampling, zero-velocity."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from conftest import synthetic
from omegaconf import OmegaConf

from motionsynth.models.aclstm import ACLSTM
from motionsynth.models.base import Batch, DataSpec
from motionsynth.models.erd import ERD
from motionsynth.models.lstm3lr import LSTM3LR
from motionsynth.models.recurrent import RecurrentBaseline, gemm_nt
from motionsynth.models.seq2seq import Seq2Seq
from motionsynth.models.zero_velocity import ZeroVelocity

REPO = Path(__file__).resolve().parents[1]
LOCO = DataSpec(joints=21, dims=3, num_classes=4, controls=3, fps=60.0, window=240)
GLOCAL = DataSpec(joints=15, dims=2, num_classes=10, controls=0, fps=16.7, window=60)
SMALL = {
    "erd": (ERD, dict(hidden_size=16, encoder_sizes=[16, 16], decoder_hidden=8)),
    "lstm3lr": (LSTM3LR, dict(hidden_size=16)),
    "seq2seq": (Seq2Seq, dict(hidden_size=16)),
    "aclstm": (ACLSTM, dict(hidden_size=16)),
    "scheduled_sampling": (LSTM3LR, dict(hidden_size=16, scheduled_sampling=True, ss_k=2)),
}


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    from motionsynth.training.data import real_batch

    batch, spec = real_batch("bandai2_locomotion", "vae_lstm", 8, tmp_path_factory.mktemp("loco"))
    T = 40  # shortened windows: the overfit tests stay fast
    return Batch(batch.pose[:, :T].contiguous(), batch.controls[:, :T].contiguous(), batch.labels), spec


# ----------------------------------------------------------------------------- shapes
@pytest.mark.parametrize("name", list(SMALL))
@pytest.mark.parametrize("spec,mode", [(LOCO, "predict"), (LOCO, "given"), (GLOCAL, "predict")],
                         ids=["loco-predict", "loco-given", "glocal"])
def test_shapes(name, spec, mode):
    cls, kw = SMALL[name]
    torch.manual_seed(0)
    m = cls(spec, control_mode=mode, seed_frames=8, **kw)
    assert m.family is None and type(m).family is None and m.uses_controls and m.uses_labels
    b = synthetic(spec)
    m.train()
    loss, logs = m.loss(b)
    assert loss.dim() == 0 and math.isfinite(loss.item()) and "pose_mse" in logs
    assert ("ctrl_mse" in logs) == (spec.controls > 0 and mode == "predict")
    loss.backward()
    assert all(p.grad is not None for p in m.parameters())
    m.eval()
    pred = m.predict(b)
    assert pred.shape == b.pose.shape and torch.isfinite(pred).all()
    assert torch.equal(pred[:, :8], b.pose[:, :8])
    out = m.generate(b.pose[:, :5], b.controls, b.labels, length=20, num_samples=2)
    assert out.shape == (6, 20, spec.joints, spec.dims)
    assert torch.equal(out[::2, :5], b.pose[:, :5]) and torch.equal(out[::2], out[1::2])
    if spec.num_classes:  # per-frame labels (transitions)
        per_frame = b.labels[:, None].expand(-1, 20).clone()
        per_frame[:, 10:] = (per_frame[:, 10:] + 1) % spec.num_classes
        assert m.generate(b.pose[:, :5], b.controls, per_frame, length=20).shape == (3, 20, spec.joints, spec.dims)
    if spec.controls and mode == "given":
        with pytest.raises(ValueError, match="controls"):
            m.generate(b.pose[:, :5], None, b.labels, length=20)


def test_given_controls_drive_the_prediction():
    torch.manual_seed(0)
    m = LSTM3LR(LOCO, control_mode="given", seed_frames=5, hidden_size=16).eval()
    b = synthetic(LOCO)
    other = Batch(b.pose, b.controls.flip(1), b.labels)
    assert not torch.equal(m.predict(b)[:, 5:], m.predict(other)[:, 5:])
    assert m.core.rnn.input_size == LOCO.pose_features + 3 + 4
    p = LSTM3LR(LOCO, control_mode="predict", hidden_size=16)
    assert p.core.rnn.input_size == LOCO.pose_features + 3 + 4 and p.state_dim == LOCO.pose_features + 3


def test_seed_frames_default_per_window():
    assert LSTM3LR(LOCO, hidden_size=4).seed_frames == 60        # the VAE-LSTM paper's baseline protocol
    assert LSTM3LR(GLOCAL, hidden_size=4).seed_frames == 10      # GlocalNet: 10 observed + 50 predicted
    assert ZeroVelocity(LOCO).seed_frames == 60 and ZeroVelocity(GLOCAL, seed_frames=7).seed_frames == 7


# ----------------------------------------------------------------------------- learning on real data
@pytest.mark.parametrize("name,kw", [
    ("erd", dict(hidden_size=48, encoder_sizes=[48, 48], decoder_hidden=32)),
    ("lstm3lr", dict(hidden_size=48)),
    ("seq2seq", dict(hidden_size=48, train_source_len=10, train_target_len=10)),
    ("aclstm", dict(hidden_size=48)),
])
def test_overfits_one_real_batch(real, name, kw):
    batch, spec = real
    torch.manual_seed(0)
    m = SMALL[name][0](spec, **kw)
    opt = torch.optim.Adam(m.parameters(), lr=3e-3)
    m.train()
    first = None
    for _ in range(120):
        loss, _ = m.loss(batch)
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    m.eval()
    with torch.no_grad():
        last = float(m.loss(batch)[0])
    assert last <= 0.1 * first, f"{name}: loss {first:.4f} -> {last:.4f}"


def test_zero_velocity_repeats_the_last_seed_pose(real):
    batch, spec = real
    m = ZeroVelocity(spec, seed_frames=12)
    pred = m.predict(batch)
    assert pred.shape == batch.pose.shape
    assert torch.equal(pred[:, :12], batch.pose[:, :12])
    assert torch.equal(pred[:, 12:], batch.pose[:, 11:12].expand_as(pred[:, 12:]))
    loss, logs = m.loss(batch)
    assert loss.item() == pytest.approx(float(((pred[:, 12:] - batch.pose[:, 12:]) ** 2).mean()))
    loss.backward()
    assert m.dummy.grad is not None and float(m.dummy.grad) == 0.0
    assert m.generate(None, length=5).shape == (1, 5, spec.joints, spec.dims)
    assert torch.equal(m.generate(batch.pose[:, :3], length=7, num_samples=2)[1::2], m.generate(batch.pose[:, :3], length=7))


def test_zero_velocity_trains_for_zero_steps():
    cfg = OmegaConf.load(REPO / "conf" / "model" / "zero_velocity.yaml")
    assert cfg.train.steps == 0


# ----------------------------------------------------------------------------- schedules
def test_scheduled_sampling_probability_anneals_over_epochs():
    m = LSTM3LR(LOCO, hidden_size=8, scheduled_sampling=True, ss_k=10, ss_unit="epoch")
    probs = []
    for epoch in range(0, 121, 10):
        m.set_epoch(epoch)
        probs.append(m.teacher_forcing_prob())
    assert probs[0] == pytest.approx(10 / 11) and probs[0] > 0.9
    assert probs[-1] < 1e-3
    assert all(a > b for a, b in zip(probs, probs[1:]))
    assert LSTM3LR(LOCO, hidden_size=8).teacher_forcing_prob() == 1.0  # off: teacher forcing


def test_scheduled_sampling_step_counter():
    torch.manual_seed(0)
    m = LSTM3LR(GLOCAL, hidden_size=8, scheduled_sampling=True, ss_k=100)
    b = synthetic(GLOCAL, T=12)
    assert m.teacher_forcing_prob() == pytest.approx(100 / 101)
    m.train()
    for _ in range(3):
        _, logs = m.loss(b)
    assert int(m.ss_step) == 3 and "ss_step" in m.state_dict()
    assert logs["teacher_forcing_prob"] == pytest.approx(100 / (100 + math.exp(0.02)))
    m.eval()
    m.loss(b)
    assert int(m.ss_step) == 3  # evaluation does not advance the schedule
    m.ss_step.fill_(5000)
    assert m.teacher_forcing_prob() < 1e-18


@pytest.mark.parametrize("detach", [True, False])
def test_scheduled_sampling_detach_feeds_the_prediction_back_as_a_constant(detach):
    """``ss_detach``: the loss of a step fed its own previous prediction reaches the decoder bias only
    through that step's output (gradient = batch size per feature); without it, also through the
    fed-back prediction."""
    torch.manual_seed(0)
    m = LSTM3LR(GLOCAL, hidden_size=8, scheduled_sampling=True, ss_detach=detach)
    B, N = 3, 4
    inp = torch.randn(B, N, m.state_dim)
    cond = torch.zeros(B, N, m.cond_dim)
    mask = torch.tensor([[True, False, False, True]] * B)
    out = m._rollout(inp, cond, mask)
    out[:, 2].sum().backward()
    bias = m.decoder[-1].bias.grad
    assert torch.allclose(bias, torch.full_like(bias, float(B))) == detach
    with pytest.raises(ValueError, match="ss_detach"):
        LSTM3LR(GLOCAL, hidden_size=8, ss_detach=1)


def test_noise_curriculum_levels():
    m = ERD(LOCO, hidden_size=8, encoder_sizes=[8], decoder_hidden=4, input_noise=[0.0, 0.1, 0.3])
    stds = []
    for step in range(0, 12, 2):          # a budget of 12 steps: each level for a third of it
        m.set_progress(step, 12)
        stds.append(m.noise_std())
    assert stds == [0.0, 0.0, 0.1, 0.1, 0.3, 0.3]


def test_aclstm_mask_alternates():
    m = ACLSTM(GLOCAL, hidden_size=8, ground_truth_len=3, condition_len=2)
    assert m._base_mask(11, "cpu").tolist() == [1, 1, 1, 0, 0, 1, 1, 1, 0, 0, 1]
    assert ACLSTM(GLOCAL, hidden_size=8, condition_len=0)._base_mask(11, "cpu") is None


# ----------------------------------------------------------------------------- exactness and determinism
@pytest.mark.parametrize("name", ["aclstm", "seq2seq", "scheduled_sampling"])
def test_step_implementations_agree(name):
    """The deferred weight gradients equal plain autograd (LSTMCell stack / nn.LSTM steps)."""
    cls, kw = SMALL[name]
    b = synthetic(LOCO, B=2, T=26)
    b = Batch(b.pose.double(), b.controls.double(), b.labels)
    res = {}
    for impl in ("deferred", "cell", "module"):
        torch.manual_seed(1)
        m = cls(LOCO, step_impl=impl, seed_frames=17, **{**kw, "hidden_size": 6}).double().train()
        loss, _ = m.loss(b)
        loss.backward()
        res[impl] = (loss.detach(), [p.grad for p in m.parameters()])
    for impl in ("cell", "module"):
        assert torch.allclose(res[impl][0], res["deferred"][0], atol=1e-12)
        for a, c in zip(res[impl][1], res["deferred"][1]):
            assert torch.allclose(a, c, atol=1e-10)


@pytest.mark.parametrize("name", ["aclstm", "seq2seq"])
def test_float32_gemm_path_agrees(name):
    """In float32 the step GEMMs and the weight-gradient GEMM go through oneDNN where the
    build has it (:func:`gemm_nt`): same loss and gradients as the LSTMCell stack, to float32
    summation order."""
    cls, kw = SMALL[name]
    b = synthetic(LOCO, B=4, T=26)
    res = {}
    for impl in ("deferred", "cell"):
        torch.manual_seed(1)
        m = cls(LOCO, step_impl=impl, seed_frames=17, **{**kw, "hidden_size": 48}).train()
        loss, _ = m.loss(b)
        loss.backward()
        res[impl] = (loss.detach(), [p.grad for p in m.parameters()])
    assert torch.allclose(res["cell"][0], res["deferred"][0], rtol=1e-5)
    for a, c in zip(res["cell"][1], res["deferred"][1]):
        assert torch.allclose(a, c, rtol=1e-3, atol=1e-5 * float(a.abs().max()))


def test_gemm_nt_matches_addmm():
    g = torch.Generator().manual_seed(0)
    x, w, bias = torch.randn(32, 300, generator=g), torch.randn(200, 300, generator=g), torch.randn(200, generator=g)
    assert torch.allclose(gemm_nt(x, w, bias), torch.addmm(bias, x, w.t()), atol=1e-4)
    assert torch.allclose(gemm_nt(x, w), x @ w.t(), atol=1e-4)
    assert torch.equal(gemm_nt(x.double(), w.double()), x.double() @ w.double().t())  # other dtypes: plain mm


@pytest.mark.parametrize("name", ["erd", "seq2seq", "aclstm", "scheduled_sampling"])
def test_deterministic(name):
    cls, kw = SMALL[name]
    b = synthetic(LOCO, T=30)
    losses = []
    for _ in range(2):
        torch.manual_seed(0)
        extra = {"seq2seq": dict(seed_frames=8, train_target_len=10), "erd": dict(input_noise=0.1)}.get(name, {})
        m = cls(LOCO, **extra, **kw)
        opt = torch.optim.Adam(m.parameters(), 1e-3)
        m.train()
        for _ in range(3):
            loss, _ = m.loss(b)
            opt.zero_grad()
            loss.backward()
            opt.step()
        losses.append(m.loss(b)[0].item())
    assert losses[0] == losses[1]


# ----------------------------------------------------------------------------- configs and validation
@pytest.mark.parametrize("name", ["erd", "lstm3lr", "seq2seq", "aclstm", "scheduled_sampling", "zero_velocity"])
def test_configs_build(name):
    from hydra.utils import get_class

    cfg = OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "model" / f"{name}.yaml"), resolve=True)
    assert cfg["name"] == name and set(cfg["sizes"]) == {"smoke", "default", "paper"}
    assert {"optimizer", "lr", "weight_decay", "batch_size"} <= set(cfg["train"])
    cls = get_class(cfg["_target_"])
    for size in ("smoke", "default"):
        m = cls(LOCO, **cfg["sizes"][size])
        assert m.family is None
    if name == "scheduled_sampling":
        assert m.scheduled_sampling


@pytest.mark.parametrize("cls,kw,match", [
    (LSTM3LR, dict(hidden_size=-4), "hidden_size"),
    (LSTM3LR, dict(hidden_size=8, num_layers=0), "num_layers"),
    (ERD, dict(hidden_size=8, encoder_sizes=[8, -1]), "encoder_sizes"),
    (ERD, dict(hidden_size=8, decoder_hidden=0), "decoder_sizes"),
    (LSTM3LR, dict(hidden_size=8, control_mode="steer"), "control_mode"),
    (Seq2Seq, dict(hidden_size=8, train_source_len=0), "train_source_len"),
    (ACLSTM, dict(hidden_size=8, ground_truth_len=0), "ground_truth_len"),
    (ACLSTM, dict(hidden_size=8, condition_len=-1), "condition_len"),
    (LSTM3LR, dict(hidden_size=8, seed_frames=-2), "seed_frames"),
    (LSTM3LR, dict(hidden_size=8, family="dense"), "family"),
    (LSTM3LR, dict(hidden_size=8, ss_k=0.5), "ss_k"),
    (LSTM3LR, dict(hidden_size=8, ss_unit="batch"), "ss_unit"),
    (LSTM3LR, dict(hidden_size=8, input_noise=-0.1), "input_noise"),
    (LSTM3LR, dict(hidden_size=8, step_impl="fast"), "step_impl"),
    (ZeroVelocity, dict(seed_frames=0), "seed_frames"),
    (ACLSTM, dict(hidden_size=8, residual=1), "residual"),
])
def test_invalid_hyperparameters(cls, kw, match):
    with pytest.raises(ValueError, match=match):
        cls(LOCO, **kw)


def test_invalid_inputs():
    m = Seq2Seq(LOCO, hidden_size=8, train_source_len=25)
    with pytest.raises(ValueError, match="cannot hold"):
        m.loss(synthetic(LOCO, T=20))
    with pytest.raises(ValueError, match="labels"):
        LSTM3LR(LOCO, hidden_size=8).generate(torch.zeros(1, 3, 21, 3), torch.zeros(1, 9, 3), None, length=9)
    assert issubclass(ERD, RecurrentBaseline)


def test_horizon_power_weights_each_predicted_step_by_h_to_the_minus_p():
    """The loss with ``horizon_power`` p is sum_h h^-p e_h / sum_h h^-p over the per-step MSEs e_h,
    recovered from the causal decoder as h L_h - (h-1) L_{h-1} (L_h: plain loss over the first h steps)."""
    b = synthetic(LOCO, T=20)
    torch.manual_seed(0)
    m = Seq2Seq(LOCO, hidden_size=16, seed_frames=8, train_target_len=12)
    with torch.no_grad():
        for p in m.parameters():                              # the output layer starts at zero: move it
            p.normal_(0, 0.1)
    m.eval()
    plain = []
    for h in range(1, 13):
        m.train_target_len = h
        plain.append(m.loss(b)[0].item())
    e = [plain[0]] + [h * plain[h - 1] - (h - 1) * plain[h - 2] for h in range(2, 13)]
    assert min(e) >= 0 and max(e) > 1.5 * min(e)          # the steps differ, so the weighting matters
    m.train_target_len = 12
    for p in (0.0, 0.5, 1.0):
        m.horizon_power = p
        w = [h ** -p for h in range(1, 13)]
        want = sum(wi * ei for wi, ei in zip(w, e)) / sum(w)
        assert m.loss(b)[0].item() == pytest.approx(want, rel=1e-4)
    with pytest.raises(ValueError, match="horizon_power"):
        Seq2Seq(LOCO, hidden_size=8, horizon_power=-1)


@pytest.mark.parametrize("name", ["erd", "lstm3lr", "aclstm", "scheduled_sampling"])
def test_residual_output_starts_at_zero_velocity(real, name):
    """``residual: true`` (a config choice for the baselines that predict poses): the decoder's output is
    added to the frame fed in, and its last layer starts at zero, so the untrained model rolls out the
    zero-velocity baseline; without it the untrained model predicts the decoder's (random) output."""
    batch, spec = real
    cls, kw = SMALL[name]
    zv = ZeroVelocity(spec, seed_frames=12).predict(batch)
    torch.manual_seed(0)
    res = cls(spec, **kw, seed_frames=12, residual=True).eval()
    assert res.residual and not cls.residual
    assert torch.allclose(res.predict(batch), zv, atol=1e-5)
    torch.manual_seed(0)
    plain = cls(spec, **kw, seed_frames=12).eval()
    assert not plain.residual
    assert (plain.predict(batch)[:, 12:] - zv[:, 12:]).abs().max() > 1e-2
    assert Seq2Seq(spec, hidden_size=8, residual=False).residual is False and Seq2Seq(spec, hidden_size=8).residual

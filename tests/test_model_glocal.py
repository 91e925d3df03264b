"""GlocalNet GloGen + LocGen (Battan et al. 2021): shapes, class prior, pace control, overfit, determinism."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from conftest import overfit
import yaml

from motionsynth.models.base import Batch, DataSpec
from motionsynth.models.glogen import GloGen
from motionsynth.models.locgen import LocGen, glocal_generate, interpolate

REPO = Path(__file__).resolve().parents[1]
SPEC = DataSpec(joints=21, dims=3, num_classes=17, window=96, every=5)   # bandai1 glocal windows
SMALL = dict(hidden=16, dropout=0.0)


pytestmark = pytest.mark.usefixtures("one_thread")  # see conftest.one_thread


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    from motionsynth.training.data import real_batch

    return real_batch("bandai1", "glocal", 8, tmp_path_factory.mktemp("bandai1"))


def synthetic(B: int = 3, spec: DataSpec = SPEC) -> Batch:
    g = torch.Generator().manual_seed(0)
    return Batch(torch.randn(B, spec.window, spec.joints, spec.dims, generator=g),
                 labels=torch.arange(B) % max(spec.num_classes, 1) if spec.num_classes else None, every=spec.every)


def randomise_output(model) -> None:
    """The output layer starts at zero (residual = zero velocity / interpolation); give it weights."""
    torch.manual_seed(1)
    torch.nn.init.normal_(model.net.out.weight, std=0.3)


# ---------------------------------------------------------------------------------------- GloGen
def test_glogen_shapes_and_protocol():
    torch.manual_seed(0)
    m = GloGen(SPEC, t_in=5, **SMALL)
    assert (m.t, m.t_out, m.seed_frames, m.family, m.uses_labels) == (5, 15, 5, "glocal", True)
    b = synthetic()
    loss, logs = m.loss(b)
    assert loss.dim() == 0 and torch.isfinite(loss) and set(logs) == {"L_J", "L_MF"}
    loss.backward()
    m.eval()
    pred, tgt = m.predict(b), m.target(b)
    assert pred.shape == tgt.shape == (3, 20, 21, 3)
    assert torch.equal(tgt, b.pose[:, ::5])
    assert torch.equal(pred[:, :5], tgt[:, :5])                 # the seed is copied
    seed = b.pose[:, ::5][:, :5]
    out = m.generate(seed, labels=b.labels, length=23, num_samples=2)
    assert out.shape == (6, 23, 21, 3) and torch.equal(out[::2, :5], seed)
    assert m.generate(None, labels=b.labels, length=12).shape == (3, 12, 21, 3)


def test_glogen_class_prior_and_transitions():
    torch.manual_seed(0)
    m = GloGen(SPEC, t_in=5, **SMALL).eval()
    randomise_output(m)
    seed = synthetic(1).pose[:, ::5][:, :5]
    a = m.generate(seed, labels=torch.tensor([2]), length=20)
    b = m.generate(seed, labels=torch.tensor([9]), length=20)
    assert not torch.allclose(a[:, 5:], b[:, 5:])                # the class prior changes the output
    # switch from class 2 to class 9 at pose 10 (Fig. 1b): chunks starting at 5 use 2, at 10 and 15 use 9
    per_step = torch.tensor([[2] * 10 + [9] * 10])
    ab = m.generate(seed, labels=per_step, length=20)
    assert ab.shape == (1, 20, 21, 3)
    assert torch.equal(ab[:, :10], a[:, :10]) and not torch.allclose(ab[:, 10:], a[:, 10:])
    assert torch.equal(ab[:, 10:15], m.generate(a[:, 5:10], labels=torch.tensor([9]), length=10)[:, 5:])


def test_glogen_unlabelled_and_h36m_setting():
    spec = DataSpec(joints=15, dims=2, num_classes=0, window=60, every=1)
    m = GloGen(spec, t_in=10, t_out=50, **SMALL)
    b = synthetic(2, spec)
    loss, _ = m.loss(b)
    assert torch.isfinite(loss)
    assert m.predict(b).shape == m.target(b).shape == (2, 60, 15, 2)


@pytest.mark.parametrize("kw, match", [
    (dict(hidden=33), "even"),
    (dict(t_in=0), "t_in"),
    (dict(t_in=11), "2 \\* t_in"),
    (dict(t_in=5, t_out=7), "multiple"),
    (dict(t_in=5, t_out=20), "exceeds"),
    (dict(dropout=1.0), "dropout"),
    (dict(lambda_flow=-1.0), "lambda_flow"),
    (dict(lambda_joint=0.0, lambda_flow=0.0), "nothing to learn"),
    (dict(pair_stride=0), "pair_stride"),
])
def test_glogen_invalid_hparams(kw, match):
    with pytest.raises(ValueError, match=match):
        GloGen(SPEC, **kw)


def test_glogen_invalid_calls():
    m = GloGen(SPEC, t_in=5, **SMALL)
    seed = torch.zeros(2, 5, 21, 3)
    with pytest.raises(ValueError, match="labels"):
        m.generate(seed, labels=None, length=10)
    with pytest.raises(ValueError, match="t_in"):
        m.generate(seed[:, :3], labels=torch.zeros(2, dtype=torch.long), length=10)
    with pytest.raises(ValueError, match="labels must lie"):
        m.generate(seed, labels=torch.tensor([0, 17]), length=10)


# ---------------------------------------------------------------------------------------- LocGen
def test_interpolation_eq3():
    sp = torch.tensor([[[0.0], [4.0], [8.0]]])                    # [1, 3, 1]
    dense, mask = interpolate(sp, 3)                              # M = 3 in-betweens per gap
    assert dense[0, :, 0].tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 8]  # from X_i towards X_{i+1}
    assert mask.tolist() == [False, True, True, True, False, True, True, True, False]


def test_locgen_shapes_pace_and_keyframes():
    torch.manual_seed(0)
    m = LocGen(SPEC, **SMALL)
    assert (m.seed_frames, m.family, m.uses_labels) == (0, "glocal", False)
    b = synthetic()
    loss, logs = m.loss(b)
    assert loss.dim() == 0 and torch.isfinite(loss) and set(logs) == {"L_J", "L_MF"}
    loss.backward()
    m.eval()
    randomise_output(m)
    pred = m.predict(b)
    assert pred.shape == b.pose.shape
    assert torch.equal(pred[:, ::5], b.pose[:, ::5])              # keyframes are kept exactly (eq. 4)
    sparse = b.pose[:, ::5]                                       # 20 sparse poses
    for M in (0, 1, 4, 9):                                        # pace control
        out = m.generate(sparse, M=M)
        assert out.shape == (3, 19 * (M + 1) + 1, 21, 3)
        assert torch.equal(out[:, ::M + 1], sparse)
    assert m.generate(sparse, M=2, length=30).shape == (3, 30, 21, 3)
    assert m.generate(sparse, length=50, num_samples=2).shape == (6, 50, 21, 3)
    assert not torch.allclose(pred, interpolate(m.flat(sparse), 4)[0].reshape(pred.shape))
    with pytest.raises(ValueError, match="sparse poses"):
        m.generate(sparse, M=1, length=100)
    with pytest.raises(ValueError, match="M must"):
        m.generate(sparse, M=-1)


def test_locgen_extra_strides_and_every_one():
    m = LocGen(SPEC, extra_strides=[2, 3], **SMALL)
    loss, _ = m.loss(synthetic())
    loss.backward()
    assert m.net.out.weight.grad.abs().sum() > 0
    spec1 = DataSpec(joints=15, dims=2, window=60, every=1)        # no in-betweens: output = input
    m1 = LocGen(spec1, **SMALL)
    b1 = synthetic(2, spec1)
    loss, _ = m1.loss(b1)
    loss.backward()                                               # graph stays connected
    assert loss.item() == 0.0 and torch.equal(m1.predict(b1), b1.pose)


def test_locgen_is_validated_on_its_in_betweens_only():
    """LocGen's selection criterion scores the frames it generates: not the keyframes it copies,
    not a tail past the last keyframe (issue "Models that learn", item 6)."""
    m = LocGen(DataSpec(joints=15, dims=2, window=23, every=5), **SMALL)
    scored = m.scored_frames(23)
    assert scored.tolist() == [t % 5 != 0 and t <= 20 for t in range(23)]
    assert int(scored.sum()) == 16


@pytest.mark.parametrize("kw, match", [
    (dict(hidden=7), "even"),
    (dict(dropout=-0.1), "dropout"),
    (dict(extra_strides=[1]), "extra_strides"),
    (dict(lambda_joint=-2.0), "lambda_joint"),
    (dict(residual="yes"), "residual"),
])
def test_locgen_invalid_hparams(kw, match):
    with pytest.raises(ValueError, match=match):
        LocGen(SPEC, **kw)


def test_glocal_generate_chain():
    torch.manual_seed(0)
    g, l_ = GloGen(SPEC, t_in=5, **SMALL).eval(), LocGen(SPEC, **SMALL).eval()
    seed = synthetic(2).pose[:, ::5][:, :5]
    dense = glocal_generate(g, l_, seed, torch.tensor([1, 3]), n_sparse=13, M=4)
    assert dense.shape == (2, 61, 21, 3)
    assert torch.equal(dense[:, :25:5], seed)
    trans = glocal_generate(g, l_, seed, torch.tensor([[1] * 8 + [3] * 5] * 2), n_sparse=13, M=2)
    assert trans.shape == (2, 37, 21, 3)


# ------------------------------------------------------------------------ configs, real data
@pytest.mark.parametrize("name, cls", [("glogen", GloGen), ("locgen", LocGen)])
def test_config_sizes_build(name, cls):
    cfg = yaml.safe_load((REPO / "conf" / "model" / f"{name}.yaml").read_text())
    assert cfg["_target_"] == f"motionsynth.models.{name}.{cls.__name__}"
    assert cfg["train"]["optimizer"] == "adamw" and cfg["train"]["lr"] == 0.002
    for spec in (SPEC, DataSpec(joints=15, dims=2, num_classes=10, window=60, every=1)):
        for size in ("smoke", "default", "paper"):
            cls(spec, **cfg["sizes"][size])


@pytest.mark.parametrize("cls, kw", [(GloGen, dict(t_in=5, pair_stride=1)), (LocGen, {})])
def test_overfit_one_real_batch(real, cls, kw):
    batch, spec = real
    assert batch.every == 5 and batch.labels is not None
    torch.manual_seed(0)
    m = cls(spec, hidden=64, dropout=0.0, **kw)
    first, last = overfit(m, batch)
    assert last <= 0.1 * first, (first, last)


def reference_loss(m: GloGen, batch: Batch) -> torch.Tensor:
    """GloGen's training loss written plainly (eqs. 1-2, 5-8): the chunk pairs cut by a Python loop, the
    bi-LSTMs called as plain modules (PyTorch's default CPU kernel, oneDNN where built in), dropout drawn in
    the model's order, the losses as explicit sums."""
    sp = batch.pose[:, ::batch.every].flatten(2)                                    # [B, n, F]
    t, B = m.t, sp.shape[0]
    starts = range(0, sp.shape[1] - 2 * t + 1, m.pair_stride)
    x_in = torch.stack([sp[:, i:i + t] for i in starts], 1).reshape(-1, t, sp.shape[2])          # [B * P, t, F]
    x_out = torch.stack([sp[:, i + t:i + 2 * t] for i in starts], 1).reshape(-1, t, sp.shape[2])
    onehot = torch.nn.functional.one_hot(batch.labels.repeat_interleave(len(starts)), m.num_classes).float()
    states, (h, c) = m.net.encoder(torch.cat([x_in, onehot[:, None].expand(-1, t, -1)], -1))     # eq. 1
    y, _ = m.net.decoder(m.net.drop(states), (h, c))                                            # eq. 2
    pred = m.net.out(m.net.drop(y)) + x_in[:, -1:]                                              # residual
    l_j = ((pred - x_out) ** 2).sum() / pred.numel()                                            # eq. 6
    v_hat, v = pred[:, 1:] - pred[:, :-1], x_out[:, 1:] - x_out[:, :-1]                         # eqs. 7-8
    l_mf = ((v_hat - v) ** 2).sum() / v.numel()
    return m.lambda_joint * l_j + m.lambda_flow * l_mf                                          # eq. 5


@pytest.mark.parametrize("lambdas", [(1.0, 1.0), (1.0, 0.0), (0.0, 1.0)])     # GlocalNet Table 2's three losses
def test_training_loss_and_gradients_equal_a_plain_reference(real, lambdas):
    """The training step's LSTMs run on PyTorch's native CPU kernel (glogen.native_cpu_rnn, for speed): the
    loss and every gradient equal those of the plain reference computation on a fixed batch (train mode,
    dropout 0.25 drawn from the same seed), and the global oneDNN switch is left as it was."""
    batch, spec = real
    torch.manual_seed(0)
    m = GloGen(spec, t_in=5, hidden=200, dropout=0.25, pair_stride=2, lambda_joint=lambdas[0],
               lambda_flow=lambdas[1]).train()
    randomise_output(m)                                  # a zero output layer would leave the LSTMs' gradients 0
    results = []
    for fn in (lambda: m.loss(batch)[0], lambda: reference_loss(m, batch)):
        m.zero_grad()
        torch.manual_seed(7)
        flag = torch.backends.mkldnn.enabled
        loss = fn()
        loss.backward()
        assert torch.backends.mkldnn.enabled == flag
        results.append((loss.item(), {k: p.grad.clone() for k, p in m.named_parameters()}))
    (ours, g_ours), (ref, g_ref) = results
    assert ours == pytest.approx(ref, rel=1e-6, abs=1e-9) and ours > 0
    for k in g_ref:
        assert g_ref[k].abs().max() > 0, k
        torch.testing.assert_close(g_ours[k], g_ref[k], rtol=1e-5, atol=1e-7, msg=k)



def test_single_threaded_training_runs_the_native_lstm_kernel(real):
    """On one thread (this module's fixture) the training step's LSTMs skip oneDNN, which the reference's
    plain module calls use (so the equality above compares two kernels); inference keeps the default."""
    from motionsynth.models.glogen import NATIVE_RNN_MAX_THREADS

    if not (torch.backends.mkldnn.is_available() and torch.backends.mkldnn.enabled):
        pytest.skip("PyTorch without oneDNN: one kernel only")
    assert torch.get_num_threads() <= NATIVE_RNN_MAX_THREADS
    batch, spec = real
    m = GloGen(spec, t_in=5, hidden=16, dropout=0.25).train()

    def ops(fn) -> set[str]:
        with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
            fn()
        return {e.key for e in prof.key_averages()}

    assert not any("mkldnn_rnn" in k for k in ops(lambda: m.loss(batch)[0].backward()))
    assert any("mkldnn_rnn" in k for k in ops(lambda: reference_loss(m, batch).backward()))
    m.eval()
    assert any("mkldnn_rnn" in k for k in ops(lambda: m.predict(batch)))


@pytest.mark.parametrize("cls", [GloGen, LocGen])
def test_determinism(real, cls):
    batch, spec = real

    def run() -> float:
        torch.manual_seed(123)
        m = cls(spec, hidden=16, dropout=0.25)                    # dropout: exercises the RNG
        opt = torch.optim.AdamW(m.parameters(), lr=2e-3)
        for _ in range(3):
            loss, _ = m.loss(batch)
            opt.zero_grad()
            loss.backward()
            opt.step()
        return m.loss(batch)[0].item()

    assert run() == run()

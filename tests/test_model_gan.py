"""The GAN family (GlocalNet Table 3): SA-GCN's graph and shapes, and adversarial training in the shared
trainer (both players step, deterministic reruns, resume, divergence stops cleanly)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import build_eval_root, compose_cfg

from motionsynth.models.base import DataSpec
from motionsynth.models.sagcn import SAGCN, graph_product, skeleton_adjacency, sparse_graph
from motionsynth.training.checkpoint import load
from motionsynth.training.run import build, run
from motionsynth.training.trainer import Trainer, TrainingDiverged

DS = "h36m"
#: bench2d's 15 joints (RHip, RKnee, RFoot, LHip, LKnee, LFoot, Spine, Thorax, Head, LShoulder, LElbow,
#: LWrist, RShoulder, RElbow, RWrist): parents, the hip and neck removed (data/processed/h36m/bench2d/skeleton.json)
PARENTS = (-1, 0, 1, -1, 3, 4, -1, 6, 7, 7, 9, 10, 7, 12, 13)
#: the bones of the SA-GCN reference's 15 x 15 matrix (train.py), same joint order, self-loops aside
REFERENCE_EDGES = {(0, 1), (0, 3), (0, 6), (1, 2), (3, 4), (3, 6), (4, 5), (6, 7), (7, 8), (7, 9), (7, 12),
                   (9, 10), (10, 11), (12, 13), (13, 14)}
SMOKE = dict(noise_dim=8, label_dim=4, rnn_input=12, hidden=16, heads=2, top_k=3, width=32,
             gcn_channels=[4, 4, 4, 8, 8], node_mixing=False, d_width=32, f_width=32, d_bottleneck=8,
             frame_samples=5, val_per_class=4)


def spec(classes: int = 3) -> DataSpec:
    return DataSpec(joints=15, dims=2, num_classes=classes, window=60, every=1, parents=PARENTS)


@pytest.fixture(scope="module")
def root(tmp_path_factory, one_thread) -> Path:
    """A tiny real Human3.6M 2-D project (20 items: S11 and training subjects, 3 classes)."""
    r = tmp_path_factory.mktemp("ganroot")
    build_eval_root(r, DS, {}, max_items=20)
    return r


def test_skeleton_graph_is_the_references():
    A = skeleton_adjacency(PARENTS, 15)
    assert torch.equal(A, A.T) and torch.equal(A.diagonal(), torch.ones(15))
    assert {(i, j) for i in range(15) for j in range(i + 1, 15) if A[i, j]} == REFERENCE_EDGES
    with pytest.raises(ValueError, match="skeleton"):
        skeleton_adjacency(None, 15)


def test_graph_product_equals_the_dense_row_normalised_graph():
    """The factored product against the [T*J, T*J] matrix built literally from its definition."""
    g = torch.Generator().manual_seed(0)
    N, C, T, J, k = 2, 3, 7, 15, 3
    scores = torch.randn(N, T, T, generator=g).masked_fill(torch.ones(T, T).triu(1).bool(), float("-inf"))
    W = sparse_graph(scores.softmax(-1), k)
    assert ((W > 0).sum(-1) <= k).all()
    A = skeleton_adjacency(PARENTS, J)
    h = torch.randn(N, C, T, J, generator=g, dtype=torch.float32)
    eye_t, eye_j = torch.eye(T), torch.eye(J)
    same_joint = torch.kron(1 - eye_t, eye_j)                    # (t, j) ~ (t', j), t != t'
    bones = torch.kron(eye_t, A)                                  # (t, j) ~ (t, j') along a bone
    tile = W.repeat_interleave(J, 1).repeat_interleave(J, 2)      # W[t, t'] on every (t, j), (t', j') pair
    A_hat = tile * (same_joint + bones) + 0.1 * torch.eye(T * J) + 0.1 * bones
    dense = (A_hat / A_hat.sum(-1, keepdim=True)) @ h.reshape(N, C, T * J).transpose(1, 2)   # [N, TJ, C]
    fact = graph_product(h, W, A).reshape(N, C, T * J).transpose(1, 2)
    torch.testing.assert_close(fact, dense, rtol=1e-5, atol=1e-6)


def test_sampling_in_chunks_equals_one_pass_bit_for_bit(monkeypatch):
    """Without a gradient the graph layers run GRAPH_CHUNK clips at a time (for the cache); every clip's
    arithmetic must be that of one pass over the whole batch, so results do not depend on the chunking."""
    import motionsynth.models.sagcn as sagcn
    m = SAGCN(spec(), **SMOKE).eval()
    labels = torch.arange(2 * sagcn.GRAPH_CHUNK + 7) % 3
    with torch.no_grad():
        torch.manual_seed(1)
        chunked = m.sample(labels, 30)
        monkeypatch.setattr(sagcn, "GRAPH_CHUNK", 10 ** 9)
        torch.manual_seed(1)
        whole = m.sample(labels, 30)
    assert chunked.shape == (len(labels), 30, 15, 2)
    assert torch.equal(chunked, whole)


def test_shapes_generation_and_sampling():
    torch.manual_seed(0)
    m = SAGCN(spec(), **SMOKE).eval()
    labels = torch.tensor([0, 2])
    assert m.sample(labels, 50).shape == (2, 50, 15, 2)
    assert m.sample(labels, 23).shape == (2, 23, 15, 2)           # without node mixing any length
    seed = torch.randn(2, 10, 15, 2)
    out = m.generate(seed, labels=labels, length=60, num_samples=3)
    assert out.shape == (6, 60, 15, 2)
    assert torch.equal(out[:, :10], seed.repeat_interleave(3, 0))
    assert not torch.allclose(out[0, 10:], out[1, 10:])            # samples of one label differ: noise
    mixed = SAGCN(spec(), **{**SMOKE, "node_mixing": True})
    with pytest.raises(ValueError, match="exactly 50"):
        mixed.sample(labels, 23)


@pytest.mark.parametrize("bad,match", [({"top_k": 0}, "top_k"), ({"gcn_channels": [4, 4]}, "gcn_channels"),
                                       ({"real_label": 0.3}, "real_label"), ({"clip": 80}, "windows have 60")])
def test_bad_hyperparameters_fail_clearly(bad, match):
    with pytest.raises(ValueError, match=match):
        SAGCN(spec(), **{**SMOKE, **bad})


def _trainer(root: Path, tmp: Path, *overrides: str, model: str = "sagcn") -> Trainer:
    cfg = compose_cfg(root, DS, f"model={model}", f"paths.models={tmp}", *overrides)
    model, train, val, tcfg = build(cfg)
    return Trainer(model, train, val, tcfg, tmp / "run", "fp", progress=False)


def test_one_adversarial_step_changes_both_players(root, tmp_path):
    tr = _trainer(root, tmp_path)
    before = {n: p.detach().clone() for n, p in tr.model.named_parameters()}
    torch.manual_seed(0)
    logs = tr._adversarial_step(tr.train_data.batch(np.arange(8)), 0, 0)
    assert {"d_loss", "g_loss", "logit_absmax"} <= set(logs) and all(math.isfinite(v) for v in logs.values())
    changed = {n for n, p in tr.model.named_parameters() if not torch.equal(before[n], p)}
    assert any(n.startswith("generator.") for n in changed)
    assert any(n.startswith("discriminators.sequence.") for n in changed)
    assert any(n.startswith("discriminators.frame.") for n in changed)
    assert set(tr.optims) == {"generator", "discriminator"}
    assert tr.optims["generator"].param_groups[0]["betas"] == (0.5, 0.999)


def test_class_head_trains_both_players_on_the_clips_class(root, tmp_path):
    """The 2020 reference's auxiliary classifier: D_V's class logits, their cross-entropy in both losses."""
    tr = _trainer(root, tmp_path, "+model_args.class_head=true")
    head = tr.model.discriminators["sequence"].classify
    assert head is not None and head.out_features == tr.model.num_classes
    before = {n: p.detach().clone() for n, p in tr.model.named_parameters()}
    torch.manual_seed(0)
    logs = tr._adversarial_step(tr.train_data.batch(np.arange(8)), 0, 0)
    assert {"class_real", "class_fake"} <= set(logs)
    # an untrained head is near chance: its cross-entropy about log(C)
    assert logs["class_real"] == pytest.approx(math.log(tr.model.num_classes), rel=0.5)
    changed = {n for n, p in tr.model.named_parameters() if not torch.equal(before[n], p)}
    assert "discriminators.sequence.classify.weight" in changed
    assert _trainer(root, tmp_path).model.discriminators["sequence"].classify is None   # off by default
    with pytest.raises(ValueError, match="class_head must be true or false"):
        SAGCN(spec(), **{**SMOKE, "class_head": "yes"})


def test_validation_selects_on_an_mmd_of_the_validation_split(root, tmp_path):
    tr = _trainer(root, tmp_path)
    out = tr.evaluate(tr.val_data)
    assert set(out) == {"val/mmd_avg", "val/mmd_seq", "val/mmd_vel_seq", "val/mmd_motion"}
    assert out["val/mmd_motion"] == pytest.approx(out["val/mmd_seq"] + out["val/mmd_vel_seq"])
    assert out == tr.evaluate(tr.val_data)                      # fixed noise: the same every round
    assert tr.cfg.monitor == "val/mmd_motion"


def test_generator_average_follows_the_trained_generator_and_samples_in_eval_mode(root, tmp_path):
    """The generator average (models/adversarial.py): no player trains it, the trainer folds the generator's
    weights in after every step by the documented recursion, and eval mode samples from it."""
    tr = _trainer(root, tmp_path, "+model_args.average_decay=0.5")
    m = tr.model
    avg, gen = m.generator_average, m.generator
    assert not any(p.requires_grad for p in avg.parameters())
    trained = {id(p) for ps in tr.optims.values() for grp in ps.param_groups for p in grp["params"]}
    assert not any(id(p) in trained for p in avg.parameters())
    expect = [p.detach().clone() for p in gen.parameters()]             # the average starts as the generator
    torch.manual_seed(0)
    for g in range(3):
        tr._adversarial_step(tr.train_data.batch(np.arange(8)), 0, g)
        beta = min(0.5, (1 + g) / (10 + g))                             # 0.1, 0.18, 0.25: the early ramp
        expect = [beta * a + (1 - beta) * w.detach() for a, w in zip(expect, gen.parameters())]
    assert int(m.average_updates) == 3
    assert all(torch.allclose(a, e, atol=1e-7) for a, e in zip(avg.parameters(), expect))
    assert not all(torch.equal(a, w) for a, w in zip(avg.parameters(), gen.parameters()))
    labels = torch.tensor([0, 1])
    m.eval()
    torch.manual_seed(1)
    x = m.sample(labels, 50)
    torch.manual_seed(1)
    assert torch.equal(x, avg(m.one_hot(labels), 50))                  # eval mode: the average samples
    m.train()
    torch.manual_seed(1)
    y = m.sample(labels, 50)
    torch.manual_seed(1)
    assert torch.equal(y, gen(m.one_hot(labels), 50))                  # training: the generator plays
    assert any(k.startswith("generator_average.") for k in m.state_dict())   # kept in every checkpoint
    off = _trainer(root, tmp_path, "+model_args.average_decay=0.0").model    # decay 0 keeps none
    assert not hasattr(off, "generator_average") and not any("average" in k for k in off.state_dict())
    with pytest.raises(ValueError, match="average_decay must be a number in"):
        SAGCN(spec(), **{**SMOKE, "average_decay": 1.0})


def test_rerun_is_bitwise_identical_and_resume_equals_uninterrupted(root, tmp_path, monkeypatch):
    args = ("train.steps=6", "train.eval_every=2", "train.patience=100")
    a = run(compose_cfg(root, DS, "model=sagcn", f"paths.models={tmp_path}/a", *args), progress=False)
    b = run(compose_cfg(root, DS, "model=sagcn", f"paths.models={tmp_path}/b", *args), progress=False)
    assert {k: v for k, v in a.items() if k != "seconds"} == {k: v for k, v in b.items() if k != "seconds"}
    wa, wb = (load(tmp_path / x / DS / "sagcn/last.pt") for x in ("a", "b"))
    assert all(torch.equal(wa["model"][k], wb["model"][k]) for k in wa["model"])
    assert set(wa["optim"]) == {"generator", "discriminator"}

    real_round = Trainer.train_round

    def interrupted(self, round_):
        if round_ == 2:
            raise KeyboardInterrupt                        # stands in for a kill after round 1's last.pt
        return real_round(self, round_)

    cfg = compose_cfg(root, DS, "model=sagcn", f"paths.models={tmp_path}/c", *args)
    monkeypatch.setattr(Trainer, "train_round", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(cfg, progress=False)
    assert load(tmp_path / "c" / DS / "sagcn/last.pt")["epoch"] == 1
    monkeypatch.setattr(Trainer, "train_round", real_round)
    run(cfg, progress=False)
    wc = load(tmp_path / "c" / DS / "sagcn/last.pt")
    assert all(torch.equal(wa["model"][k], wc["model"][k]) for k in wa["model"])
    assert wc["history"] == wa["history"]


def test_a_nan_loss_stops_training_and_keeps_the_last_good_checkpoint(root, tmp_path, monkeypatch):
    step = {"n": 0}
    real_step = SAGCN.adversarial_step

    def poisoned(self, batch, update):
        step["n"] += 1
        if step["n"] <= 4:
            return real_step(self, batch, update)
        return real_step(self, batch, lambda player, loss: update(player, loss * float("nan")))

    monkeypatch.setattr(SAGCN, "adversarial_step", poisoned)
    out = tmp_path / DS / "sagcn"
    with pytest.raises(TrainingDiverged, match=r"diverged at step 4 \(round 2\).*discriminator loss is nan"):
        run(compose_cfg(root, DS, "model=sagcn", f"paths.models={tmp_path}", "train.steps=8", "train.eval_every=2",
                        "train.patience=100"), progress=False)
    last = load(out / "last.pt")
    assert last["epoch"] == 1 and len(last["history"]) == 2
    assert all(torch.isfinite(v).all() for v in last["model"].values())
    assert all(math.isfinite(v) for h in last["history"] for k, v in h.items() if k.startswith("val/"))
    assert (out / "best.pt").exists() and not (out / "summary.json").exists()


def test_exploding_discriminator_logits_stop_training(root, tmp_path, monkeypatch):
    real_step = SAGCN.adversarial_step
    monkeypatch.setattr(SAGCN, "adversarial_step",
                        lambda self, batch, update: {**real_step(self, batch, update), "logit_absmax": 1e9})
    with pytest.raises(TrainingDiverged, match=r"logit reached 1e\+09"):
        run(compose_cfg(root, DS, "model=sagcn", f"paths.models={tmp_path}", "train.steps=4", "train.eval_every=2"),
            progress=False)


def test_diverged_stage_prints_one_line_and_exits_3(root, tmp_path):
    import subprocess
    import sys

    from conftest import REPO

    r = subprocess.run([sys.executable, str(REPO / "pipelines/train.py"), f"paths.root={root}", f"dataset={DS}",
                        "profile=smoke", "tracking.enabled=false", "model=sagcn", f"paths.models={tmp_path}",
                        f"hydra.run.dir={tmp_path}/hydra", "train.steps=4", "train.eval_every=2", "train.max_logit=1e-9"],
                       cwd=REPO, capture_output=True, text=True, env={**__import__("os").environ, "PROGRESS": "0"})
    assert r.returncode == 3, r.stderr[-2000:]
    lines = [x for x in r.stderr.splitlines() if x.startswith("train: ")]
    assert len(lines) == 1 and "diverged at step 0" in lines[0] and "Traceback" not in r.stderr


# ----------------------------------------------------------------------------- SkeletonGAN, c-SkeletonGAN, SkeletonVAE

def smoke_sizes(name: str) -> dict:
    from omegaconf import OmegaConf

    from conftest import REPO

    cfg = OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "model" / f"{name}.yaml"), resolve=True)
    sizes = dict(cfg["sizes"]["smoke"])
    for base in [d for d in cfg.get("defaults", []) if d != "_self_"]:
        sizes = {**smoke_sizes(base), **sizes}
    return sizes


@pytest.mark.parametrize("name,cls", [("skeleton_gan", "SkeletonGAN"), ("cskeleton_gan", "CSkeletonGAN"),
                                      ("skeleton_vae", "SkeletonVAE"), ("sagcn", "SAGCN")])
def test_every_clip_generator_samples_clips_of_its_class(name, cls):
    import importlib

    torch.manual_seed(0)
    module = importlib.import_module(f"motionsynth.models.{name}")
    m = getattr(module, cls)(spec(), **smoke_sizes(name)).eval()
    labels = torch.tensor([0, 1, 2])
    out = m.generate(torch.zeros(3, 10, 15, 2), labels=labels, length=60, num_samples=2)
    assert out.shape == (6, 60, 15, 2) and torch.isfinite(out).all()
    assert not torch.allclose(out[0, 10:], out[1, 10:])            # two samples of one class differ
    assert m.predict(__import__("motionsynth.models.base", fromlist=["Batch"]).Batch(
        torch.randn(3, 60, 15, 2), labels=labels)).shape == (3, 60, 15, 2)


def test_skeleton_gan_trains_its_pose_decoder_first_then_the_latent_walk(root, tmp_path):
    tr = _trainer(root, tmp_path, model="cskeleton_gan")
    assert set(tr.optims) == {"generator", "decoder", "critic", "discriminator"}
    assert tr.optims["decoder"].param_groups[0]["lr"] == 1e-3 and tr.optims["generator"].param_groups[0]["lr"] == 1e-4
    batch = tr.train_data.batch(np.arange(8))
    for step, moved in ((0, {"decoder", "pose_critic"}), (2, {"walk", "critic", "classifier"})):
        tr.model.train()
        tr.model.set_progress(step, 4)
        before = {n: p.detach().clone() for n, p in tr.model.named_parameters()}
        logs = tr._adversarial_step(batch, 0, step)
        assert logs["stage"] == (1.0 if step < 2 else 2.0)
        changed = {n.split(".")[0] for n, p in tr.model.named_parameters() if not torch.equal(before[n], p)}
        assert changed == moved, (step, changed)
    assert "g_classify" in logs and "g_shift" in logs


def test_skeleton_vae_learns_to_reconstruct(root, tmp_path):
    tr = _trainer(root, tmp_path, "train.lr=3e-3", model="skeleton_vae")
    batch = tr.train_data.batch(np.arange(16))
    torch.manual_seed(0)
    tr.model.train()
    tr.model.set_progress(1, 1)
    losses = []
    for _ in range(60):
        loss, logs = tr.model.loss(batch)
        tr.optim.zero_grad()
        loss.backward()
        tr.optim.step()
        losses.append(logs["reconstruction"])
    assert np.mean(losses[-5:]) < 0.7 * np.mean(losses[:5])


def test_pose_stage_rounds_are_never_selected(root, tmp_path):
    """SkeletonGAN's pose-stage rounds (an untrained latent walk) are logged but neither kept as best.pt
    nor counted by patience (smoke: pretrain_steps 2, rounds of 2 steps: round 0 is the pose stage)."""
    s = run(compose_cfg(root, DS, "model=skeleton_gan", f"paths.models={tmp_path}", "train.steps=6",
                        "train.eval_every=2", "train.patience=100"), progress=False)
    hist = load(tmp_path / DS / "skeleton_gan/last.pt")["history"]
    assert [h.get("selectable", 1) for h in hist] == [0.0, 1, 1]
    assert s["best_step"] in (4, 6)


def test_latent_walk_is_the_references_cumulative_sum_and_off_in_the_default_size(root):
    """``latent_walk: true`` (the reference): frame t's latent is s_0 + the sum of the GRU's outputs up to t;
    ``false`` (ours, the default size): the GRU's output itself. Checked on the latent attention's input."""
    seen = {}
    for walk in (True, False):
        m = SAGCN(spec(), **{**SMOKE, "latent_walk": walk})
        m.generator.attn_latent.register_forward_hook(lambda mod, i, o, w=walk: seen.__setitem__(w, i[0]))
        torch.manual_seed(0)
        m.sample(torch.tensor([0, 1]), 50)
    H = SMOKE["hidden"]
    walk, plain = seen[True][..., :H], seen[False][..., :H]
    steps = walk.diff(dim=1)                                       # the increments are GRU outputs: |.| < 1
    assert steps.abs().max() < 1 and walk[:, 0].min() >= -1 and plain.abs().max() < 1
    assert walk.abs().amax(1).mean() > plain.abs().amax(1).mean()  # the sum wanders beyond one step's range
    assert compose_cfg(root, DS, "model=sagcn")["model"]["sizes"]["default"]["latent_walk"] is False
    assert compose_cfg(root, DS, "model=sagcn")["model"]["sizes"]["paper"]["latent_walk"] is True
    with pytest.raises(ValueError, match="latent_walk must be true or false"):
        SAGCN(spec(), **{**SMOKE, "latent_walk": 1})

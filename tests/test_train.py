"""The shared trainer: determinism, kill -9 and resume, config validation, MLflow logging."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import REPO, archive_path, dataset_cfg
from hydra import compose, initialize_config_dir

from motionsynth.data.ingest import ingest
from motionsynth.data.prepare import prepare
from motionsynth.data.splits import split_dataset
from motionsynth.training.checkpoint import load
from motionsynth.training.run import dataset_hash, load_trained, run

DS = "bandai2_locomotion"


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """A project root holding the prepared, split smoke data of bandai2_locomotion."""
    r = tmp_path_factory.mktemp("root")
    cfg = dataset_cfg(DS)
    ingest(cfg, archive_path(DS), r / "data/interim" / DS, max_items=16, progress=False)
    prepare(r / "data/interim" / DS, r / "data/processed" / DS, cfg["prepare"]["representations"])
    split_dataset(r / "data/processed" / DS, r / "data/splits" / DS, cfg["split"], seed=0)
    return r


def config(root: Path, *overrides: str) -> dict:
    from omegaconf import OmegaConf

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"paths.root={root}", f"dataset={DS}", "profile=smoke",
                                           "tracking.enabled=false", *overrides])
    return OmegaConf.to_container(cfg, resolve=True)


def weights(path: Path) -> dict[str, torch.Tensor]:
    return load(path)["model"]


def test_rerun_is_bitwise_identical(root, tmp_path):
    a = run(config(root, "model=vae_lstm", f"paths.models={tmp_path}/a"), progress=False)
    b = run(config(root, "model=vae_lstm", f"paths.models={tmp_path}/b"), progress=False)
    assert {k: v for k, v in a.items() if k != "seconds"} == {k: v for k, v in b.items() if k != "seconds"}
    wa, wb = weights(tmp_path / "a" / DS / "vae_lstm/last.pt"), weights(tmp_path / "b" / DS / "vae_lstm/last.pt")
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_best_pt_carries_the_aggregate_prior_of_its_own_weights(root, tmp_path):
    """VAE-LSTM's generation prior (``prior: aggregate``) is refitted after every round, so the checkpoint
    that selection keeps holds the statistics of its own weights on the train split, not N(0, I)."""
    run(config(root, "model=vae_lstm", f"paths.models={tmp_path}"), progress=False)
    model, train = load_trained(tmp_path / DS / "vae_lstm")
    assert model.prior == "aggregate"
    mean, scale = model.prior_mean.clone(), model.prior_scale.clone()
    assert not torch.allclose(scale, torch.eye(len(scale)), atol=1e-3)
    model.fit_statistics(train)
    assert torch.allclose(model.prior_mean, mean, atol=1e-5) and torch.allclose(model.prior_scale, scale, atol=1e-5)


def test_crbm_trains_on_the_whitening_of_the_train_split_from_its_first_step(root, tmp_path):
    """The cRBM's ``whiten``: the trainer fits it before the first optimiser step (every step's loss sees
    it), it is never refitted, and ``best.pt`` holds the ZCA whitening of the train split's conditioning:
    ``P C P = C (C + floor I)^-1``, with ``C`` its covariance over whole windows and the floor ``whiten``
    times C's largest eigenvalue."""
    from motionsynth.training.run import build
    from motionsynth.training.trainer import Trainer

    cfg = config(root, "model=crbm", "train.steps=6", "train.eval_every=3", f"paths.models={tmp_path}")
    model, train, val, tcfg = build(cfg)
    assert model.whiten == 1e-3 and int(model.cond_fitted) == 0
    seen, loss = [], model.loss
    model.loss = lambda batch: (seen.append((model.training, int(model.cond_fitted))), loss(batch))[1]
    Trainer(model, train, val, tcfg, tmp_path / "run", "fp", progress=False).fit()
    assert [f for training, f in seen if training] == [1] * 6 and {f for _, f in seen} == {1}
    best = load(tmp_path / "run" / "best.pt")["model"]
    model.eval()
    with torch.no_grad():
        conds = [model._windows(train.batch(i))[1] for i in train.batch_indices(64, False, 0)]
    u = torch.cat([c.reshape(-1, model.cond_dim) for c in conds]).double()
    mean = u.mean(0)
    C = torch.cov(u.T, correction=0)
    floor = 1e-3 * float(torch.linalg.eigvalsh(C).max())
    P = best["cond_proj"].double()
    assert int(best["cond_fitted"]) == 1 and torch.allclose(best["cond_mean"].double(), mean, atol=1e-5)
    assert torch.allclose(P, P.T, atol=1e-6)
    want = C @ torch.linalg.inv(C + floor * torch.eye(len(C), dtype=C.dtype))
    assert torch.allclose(P @ C @ P, want, atol=1e-4)
    model.fit_statistics(val)                            # fitted once: another split changes nothing
    assert torch.equal(model.cond_proj, best["cond_proj"]) and torch.equal(model.cond_mean, best["cond_mean"])


@pytest.mark.parametrize("model_name", ["crbm", "mean_pose"])
def test_an_empty_train_split_is_refused_before_its_statistics_are_fitted(root, tmp_path, model_name):
    """A model with ``fit_statistics`` (the cRBM's whitening, the mean pose) on a train split with no windows
    gets the trainer's one-line "empty data" error, not a failure from inside its statistics."""
    from motionsynth.training.run import build
    from motionsynth.training.trainer import Trainer

    cfg = config(root, f"model={model_name}", "train.steps=6", "train.eval_every=3", f"paths.models={tmp_path}")
    model, train, val, tcfg = build(cfg)
    train.windows = train.windows.iloc[:0]
    with pytest.raises(ValueError, match=r"^empty data: 0 train and \d+ val windows$"):
        Trainer(model, train, val, tcfg, tmp_path / "run", "fp", progress=False).fit()


def test_the_weight_average_is_validated_and_kept_while_training_runs_on_the_trained_weights(root, tmp_path):
    """``train.average_decay``: the optimiser's path is that of a run without it (``last.pt``'s weights and
    training losses bit for bit), the average follows ``a <- beta a + (1 - beta) w`` with ``beta = min(decay,
    (1 + n) / (10 + n))`` step by step, validation scores the average and ``best.pt`` holds it."""
    from motionsynth.training.run import build
    from motionsynth.training.trainer import Trainer

    args = ["model=lstm3lr", "train.steps=12", "train.eval_every=4", "train.patience=100", f"paths.models={tmp_path}"]
    model, train, val, tcfg = build(config(root, *args))
    plain = Trainer(model, train, val, tcfg, tmp_path / "plain", "fp", progress=False).fit()

    model, train, val, tcfg = build(config(root, *args, "train.average_decay=0.9"))
    params = [p for p in model.parameters() if p.requires_grad]
    after = [[p.detach().clone() for p in params]]                 # the weights before the first step ...
    trainer = Trainer(model, train, val, tcfg, tmp_path / "avg", "fp", progress=False,
                      on_step=lambda r, g, loss: after.append([p.detach().clone() for p in params]))  # ... after each
    averaged = trainer.fit()
    assert [h["train/loss"] for h in averaged["history"]] == [h["train/loss"] for h in plain["history"]]
    trained, reference = weights(tmp_path / "avg/last.pt"), weights(tmp_path / "plain/last.pt")
    assert all(torch.equal(trained[k], reference[k]) for k in reference)

    names = [n for n, p in model.named_parameters() if p.requires_grad]
    a = after[0]
    expected = {}
    for n, w in enumerate(after[1:]):
        beta = min(0.9, (1 + n) / (10 + n))
        a = [beta * x + (1 - beta) * y for x, y in zip(a, w)]
        expected[n + 1] = a
    best = load(tmp_path / "avg/best.pt")
    step = averaged["history"][best["epoch"]]["step"]
    assert all(torch.allclose(best["model"][k], v, rtol=1e-5, atol=1e-7) for k, v in zip(names, expected[step]))
    assert not all(torch.allclose(best["model"][k], v) for k, v in zip(names, after[step]))
    model.load_state_dict(best["model"])                          # validation scored the average
    score = trainer.evaluate(val)[tcfg.monitor]
    assert score == averaged["history"][best["epoch"]][tcfg.monitor]
    assert averaged["history"][-1][tcfg.monitor] != plain["history"][-1][tcfg.monitor]


def test_a_resumed_run_goes_on_with_its_weight_average(root, tmp_path):
    """``last.pt`` carries the average and its update count: a run stopped after its first round and resumed
    ends with the checkpoints (trained weights, average, selected round) of an uninterrupted one, bit for bit."""
    from motionsynth.training.run import build
    from motionsynth.training.trainer import Trainer

    args = ["model=lstm3lr", "train.steps=12", "train.eval_every=4", "train.patience=100",
            "train.average_decay=0.9", f"paths.models={tmp_path}"]
    model, train, val, tcfg = build(config(root, *args))
    Trainer(model, train, val, tcfg, tmp_path / "whole", "fp", progress=False).fit()

    def stop(r, metrics):
        if r == 1:
            raise KeyboardInterrupt

    model, train, val, tcfg = build(config(root, *args))
    with pytest.raises(KeyboardInterrupt):
        Trainer(model, train, val, tcfg, tmp_path / "cut", "fp", progress=False, on_epoch=stop).fit()
    assert load(tmp_path / "cut/last.pt")["epoch"] == 0
    model, train, val, tcfg = build(config(root, *args))
    again = Trainer(model, train, val, tcfg, tmp_path / "cut", "fp", progress=False)
    assert again.try_resume()
    again.fit()
    assert load(tmp_path / "cut/last.pt")["average_updates"] == 12
    for name in ("last.pt", "best.pt"):
        whole, cut = load(tmp_path / "whole" / name), load(tmp_path / "cut" / name)
        assert whole["epoch"] == cut["epoch"] and whole["average_updates"] == cut["average_updates"]
        assert all(torch.equal(whole["model"][k], cut["model"][k]) for k in whole["model"])
        assert all(torch.equal(x, y) for x, y in zip(whole["average"], cut["average"]))


def test_kill_9_then_resume_equals_uninterrupted(root, tmp_path):
    args = ["model=vae_lstm", "train.steps=72", "train.eval_every=6", "train.patience=100"]
    run(config(root, *args, f"paths.models={tmp_path}/ref"), progress=False)

    cmd = [sys.executable, str(REPO / "pipelines/train.py"), f"paths.root={root}", f"dataset={DS}",
           "profile=smoke", "tracking.enabled=false", f"paths.models={tmp_path}/killed",
           f"hydra.run.dir={tmp_path}/hydra", *args]
    env = {**os.environ, "PROGRESS": "0"}
    last = tmp_path / "killed" / DS / "vae_lstm" / "last.pt"
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if last.exists():
            try:
                if 2 <= load(last)["epoch"] < 11:
                    break
            except Exception:  # noqa: BLE001 - the file is being replaced; retry
                pass
        time.sleep(0.02)
    assert proc.poll() is None, "training ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    killed_at = load(last)["epoch"]
    killed_seconds = load(last)["seconds"]
    assert killed_at < 11 and killed_seconds > 0
    r = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    log = r.stdout + r.stderr
    assert "resumed from" in log and f"at round {killed_at + 1}" in log
    ref, res = weights(tmp_path / "ref" / DS / "vae_lstm/last.pt"), weights(last)
    assert all(torch.equal(ref[k], res[k]) for k in ref)
    assert load(last)["history"] == load(tmp_path / "ref" / DS / "vae_lstm/last.pt")["history"]
    # the run's training seconds go on from the killed process's (dvc repro -f of a finished stage kept ~0)
    assert load(last)["seconds"] > killed_seconds


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device (found on the project's GPU run)")
def test_a_finished_gpu_run_resumes_its_checkpoint(root, tmp_path):
    """A checkpoint is loaded onto the training device: its CPU RNG state then sits on the GPU, and
    ``torch.set_rng_state`` refused it ('RNG state must be a torch.ByteTensor') on every resume."""
    cfg = config(root, "model=vae_lstm", "train.steps=12", "train.eval_every=6", "train.device=cuda",
                 f"paths.models={tmp_path}")
    first = run(cfg, progress=False)
    again = run(cfg, progress=False)
    assert again["best_step"] == first["best_step"] and again["val/loss"] == first["val/loss"]


@pytest.mark.parametrize("override,match", [
    ("train.lr=-0.001", "train.lr must be a positive number"),
    ("train.batch_size=0", "train.batch_size must be a positive integer"),
    ("train.device=tpu", "train.device"),
    ("+train.nonsense=1", "unknown train options"),
])
def test_garbage_config_fails_before_any_work(root, tmp_path, override, match):
    with pytest.raises(ValueError, match=match):
        run(config(root, "model=vae_lstm", override, f"paths.models={tmp_path}"), progress=False)
    assert not (tmp_path / DS).exists()  # nothing was written


def test_unknown_model_name_is_a_clear_error(root):
    with pytest.raises(Exception, match="model/nope"):
        config(root, "model=nope")


@pytest.mark.parametrize("model,override,match", [
    ("crbm", "+model_args.cdk=2", r"CRBM takes no hyperparameter\(s\) \['cdk'\]"),
    ("att_seq2seq", "+model_args.atention_size=8", "atention_size"),
    ("att_seq2seq", "+model_args.attention_size=0", "attention_size must be an integer >= 1, got 0"),
    ("vae_seq2seq", "+model_args.beta=-1", "beta must be a number >= 0"),
    ("glogen_lj", "+model_args.lambda_flowz=0", "lambda_flowz"),
])
def test_hyperparameters_a_model_cannot_take_fail_before_data_is_read(tmp_path, model, override, match):
    """The root has no data at all: the error is the config's, not a missing file's."""
    cfg = config(tmp_path / "empty", f"model={model}", override, f"paths.models={tmp_path}/m")
    with pytest.raises(ValueError, match=match) as err:
        run(cfg, progress=False)
    assert f"conf/model/{model}.yaml" in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "m").exists()


def test_unknown_model_on_the_command_line_is_one_line_before_hydra(tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "pipelines/train.py"), f"dataset={DS}", "model=erd,nope",
                        f"hydra.run.dir={tmp_path}"], cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]
    assert r.stderr.startswith("train: model=nope: no conf/model/nope.yaml; one of ") and "erd" in r.stderr


def test_a_config_variant_takes_its_base_models_dataset_protocol(tmp_path):
    """glogen_lj (overrides_as: glogen) gets h36m's GloGen protocol (t_in 10, t_out 50) and its own lambdas."""
    from motionsynth.training.run import hparams

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["dataset=h36m", "model=glogen_lj", "tracking.enabled=false"])
    from omegaconf import OmegaConf

    hp = hparams(OmegaConf.to_container(cfg, resolve=True))
    assert (hp["t_in"], hp["t_out"], hp["lambda_joint"], hp["lambda_flow"]) == (10, 50, 1.0, 0.0)


def test_a_reference_stage_is_marked_as_such_not_converged(root, tmp_path):
    s = run(config(root, "model=zero_velocity", f"paths.models={tmp_path}"), progress=False)
    assert s["reference"] is True and s["converged"] is None and s["best_step"] is None and s["budget_steps"] == 0
    t = run(config(root, "model=erd", "train.steps=4", "train.eval_every=2", f"paths.models={tmp_path}"),
            progress=False)
    assert t["reference"] is False and isinstance(t["converged"], bool) and t["best_step"] in (2, 4)


def test_mlflow_run_has_params_tags_metrics_and_artifacts(root, tmp_path, monkeypatch):
    db = tmp_path / "mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{db}")
    cfg = config(root, "model=vae_lstm", "tracking.enabled=true", f"paths.models={tmp_path}/m")
    summary = run(cfg, progress=False)
    con = sqlite3.connect(db)
    (run_id,) = con.execute("select run_uuid from runs where name='train:vae_lstm@bandai2_locomotion'").fetchone()
    tags = dict(con.execute("select key, value from tags where run_uuid=?", (run_id,)).fetchall())
    assert tags["model"] == "vae_lstm" and tags["dataset"] == DS and "git_commit" in tags and "dataset_hash" in tags
    params = dict(con.execute("select key, value from params where run_uuid=?", (run_id,)).fetchall())
    assert params["model.name"] == "vae_lstm" and "train.patience" in params
    steps = con.execute("select count(distinct step) from metrics where run_uuid=? and key='val/pred_mse'",
                        (run_id,)).fetchone()[0]
    assert steps == summary["epochs_run"] == 2
    art = Path(con.execute("select artifact_uri from runs where run_uuid=?", (run_id,)).fetchone()[0]
               .replace("file://", ""))
    assert {"config.yaml", "best.pt", "sample.png"} <= {p.name for p in art.iterdir()}


LOCK = """schema: '2.0'
stages:
  prepare@toy:
    cmd: python pipelines/prepare.py dataset=toy
    outs:
    - path: data/processed/toy
      md5: aaa.dir
  split@toy:
    cmd: python pipelines/split.py dataset=toy
    outs:
    - path: data/splits/toy
      md5: bbb.dir
"""


def test_dataset_hash_rereads_a_lock_another_stage_is_rewriting(tmp_path):
    """`make run` runs stages side by side: DVC may be rewriting dvc.lock (truncated, then written) just
    as a training stage reads it for its MLflow tag. An empty or cut-off read is read again; a lock that
    stays unreadable gives "unknown", never an exception (it once failed a stage)."""
    import threading

    lock = tmp_path / "dvc.lock"
    lock.write_text(LOCK)
    assert dataset_hash(tmp_path, "toy") == "aaa.dir+bbb.dir"
    for partial in ("", LOCK[:LOCK.index("  split@toy")], LOCK[:LOCK.index("      md5: aaa")] + "      md5: [\n"):
        lock.write_text(partial)
        timer = threading.Timer(0.15, lock.write_text, args=(LOCK,))
        timer.start()
        try:
            assert dataset_hash(tmp_path, "toy", attempts=50, wait_s=0.02) == "aaa.dir+bbb.dir"
        finally:
            timer.join()
    lock.write_text("")
    assert dataset_hash(tmp_path, "toy", attempts=3, wait_s=0.01) == "unknown"
    assert dataset_hash(tmp_path / "nowhere", "toy") == "unknown"

"""The DVC train stages (params.yaml `train_runs`) agree with the configs they name."""

from __future__ import annotations

import pytest
import yaml
from conftest import REPO
from hydra import compose, initialize_config_dir

from motionsynth.training.run import run_name

PARAMS = yaml.safe_load((REPO / "params.yaml").read_text())
RUNS = PARAMS["train_runs"]


@pytest.mark.parametrize("key", sorted(RUNS))
def test_train_run_entry_matches_its_configs(key):
    e = RUNS[key]
    assert e["dataset"] in PARAMS["datasets"]
    for f in (f"conf/model/{e['model']}.yaml", f"conf/variant/{e['variant']}.yaml",
              f"src/motionsynth/models/{e['src']}.py", f"src/motionsynth/models/{e['shared']}.py"):
        assert (REPO / f).is_file(), f
    assert key == f"{e['dataset']}-{e['name']}"
    model = yaml.safe_load((REPO / "conf" / "model" / f"{e['model']}.yaml").read_text())
    base = yaml.safe_load((REPO / "conf" / "model" / f"{e['base']}.yaml").read_text())
    assert e["base"] == e["model"] or e["base"] in model.get("defaults", [])   # the config it extends (a DVC param)
    model.setdefault("_target_", base["_target_"])                          # a config variant: its base's class
    variant = yaml.safe_load((REPO / "conf" / "variant" / f"{e['variant']}.yaml").read_text())
    # the stage passes run_name explicitly; it must equal what a plain command line would name the run
    # (a training-seed replica: that name + "-seed<k>", the evaluation's replica convention)
    plain = run_name({"run_name": None, "variant_name": variant["variant_name"], "model": model})
    assert e["name"] == (plain if e["seed"] == 0 else f"{plain}-seed{e['seed']}")
    assert f"models.{e['src']}." in model["_target_"]


def test_a_variant_composes_into_the_model_arguments():
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=["dataset=bandai2_locomotion", "model=erd", "variant=controls_given"])
    assert cfg.model_args.control_mode == "given" and cfg.variant_name == "controls_given"
    assert run_name({"run_name": cfg.run_name, "variant_name": cfg.variant_name,
                     "model": {"name": cfg.model.name}}) == "erd-controls_given"


def test_every_model_is_trained_on_the_datasets_the_issue_names():
    pairs = {(e["dataset"], e["model"]) for e in RUNS.values()}
    baselines = ["erd", "lstm3lr", "seq2seq", "aclstm", "scheduled_sampling", "zero_velocity"]
    assert {("bandai2_locomotion", m) for m in ["vae_lstm", *baselines]} <= pairs
    for ds in ("h36m", "cmu_aclstm", "bandai1"):
        assert {(ds, m) for m in ["glogen", *baselines]} <= pairs
    for ds in ("h36m", "cmu_aclstm", "bandai1", "bandai2_locomotion"):       # the mean-pose reference row
        assert (ds, "mean_pose") in pairs
    seeds = {(e["dataset"], e["model"]): sorted(x["seed"] for x in RUNS.values()
                                              if (x["dataset"], x["model"]) == (e["dataset"], e["model"]))
             for e in RUNS.values()}
    assert seeds[("cmu_aclstm", "glogen")] == seeds[("cmu_aclstm", "seq2seq")] == [0, 1, 2]
    given = {e["model"] for e in RUNS.values() if e["variant"] == "controls_given"}
    assert given == {"erd", "lstm3lr", "seq2seq", "aclstm", "scheduled_sampling", "crbm", "crbm_cd15"}
    # the papers' other methods (issue 13): cRBM in VAE-LSTM Tables 1-2, the Seq2Seq variants in GlocalNet
    # Tables 1 and 4, GloGen's loss ablation (Table 2) on H3.6M-2D and CMU
    assert {("bandai2_locomotion", m) for m in ("crbm", "crbm_cd15")} <= pairs
    assert {(ds, m) for ds in ("bandai1", "cmu_aclstm") for m in ("att_seq2seq", "vae_seq2seq")} <= pairs
    assert {(ds, m) for ds in ("h36m", "cmu_aclstm") for m in ("glogen_lj", "glogen_lmf")} <= pairs

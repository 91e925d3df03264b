"""The DVC train stages (params.yaml `train_runs`) agree with the configs they name."""

from __future__ import annotations

import ast

import pytest
import yaml
from conftest import REPO
from hydra import compose, initialize_config_dir

from motionsynth.training.run import run_name

PARAMS = yaml.safe_load((REPO / "params.yaml").read_text())
RUNS = PARAMS["train_runs"]
LIB = REPO / "src" / "motionsynth"
#: every train stage depends on these already (dvc.yaml), or they hold no model code (one-line checks)
INFRASTRUCTURE = {"models/base", "checks"}


def module_closure(module: str) -> set[str]:
    """``module`` ("models/erd") and every module of the library it imports, relative imports followed
    transitively (also those inside functions), as paths under src/motionsynth without ".py"."""
    seen, todo = set(), [module]
    while todo:
        m = todo.pop()
        if m in seen or not (LIB / f"{m}.py").is_file():
            continue
        seen.add(m)
        package = m.split("/")[:-1]
        for node in ast.walk(ast.parse((LIB / f"{m}.py").read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                parts = package[:len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
                todo.append("/".join(parts))
    return seen


def test_module_closure_follows_imports_inside_functions():
    assert module_closure("models/mean_pose") == {"models/mean_pose", "models/zero_velocity", "models/recurrent",
                                                  "models/base"}
    assert "metrics/mmd" in module_closure("models/cskeleton_gan")      # ClipGenerator.validate's import


@pytest.mark.parametrize("key", sorted(RUNS))
def test_train_run_entry_matches_its_configs(key):
    e = RUNS[key]
    assert e["dataset"] in PARAMS["datasets"]
    for f in (f"conf/model/{e['model']}.yaml", f"conf/variant/{e['variant']}.yaml"):
        assert (REPO / f).is_file(), f
    # the stage's module deps are exactly the library modules the model imports (transitively)
    declared = {f"models/{e[k]}" for k in ("src", "shared", "family")} | {e["extra"]}
    assert module_closure(f"models/{e['src']}") - INFRASTRUCTURE == declared - INFRASTRUCTURE, key
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
    # part 2 (issue 14): the action GANs of GlocalNet Table 3, on its H3.6M-2D benchmark
    assert {("h36m", m) for m in ("sagcn", "skeleton_gan", "cskeleton_gan", "skeleton_vae")} <= pairs


def test_the_evaluate_stage_depends_on_exactly_the_evaluation_modules_it_runs():
    """dvc.yaml's evaluate deps name the evaluation package's modules that the stage imports (the package,
    and every suite a dataset config names, transitively), not the report stage's modules."""
    stage = yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"]["evaluate"]["do"]
    declared = {d[len("src/motionsynth/"):-len(".py")] for d in stage["deps"]
                if d.startswith("src/motionsynth/evaluation/")}
    suites = set()
    for f in (REPO / "conf" / "dataset").glob("*.yaml"):
        suites |= set((yaml.safe_load(f.read_text()).get("evaluate") or {}).get("suites") or [])
    closure = set().union(*(module_closure(f"evaluation/{m}") for m in {"__init__", *suites}))
    assert declared == {m for m in closure if m.startswith("evaluation/")}
    assert "src/motionsynth/evaluation" not in stage["deps"] and "evaluation/report" not in declared

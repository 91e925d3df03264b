"""DVC stage `train@<dataset>-<run>`: prepared windows -> models/<dataset>/<run>/ (+ MLflow run).

    python pipelines/train.py dataset=bandai2_locomotion model=vae_lstm [train.lr=1e-3 ...]
    python pipelines/train.py dataset=bandai2_locomotion model=erd variant=controls_given
    python pipelines/train.py -m dataset=h36m model=glogen,seq2seq train.lr=1e-3,2e-3 [hydra/launcher=joblib]
    torchrun --nproc_per_node=2 pipelines/train.py dataset=h36m model=glogen

A multirun job is an MLflow child run of the sweep's parent run and keeps its checkpoints in
models/sweeps/ (motionsynth.sweeps); it returns `optimized_metric` (else `train.monitor`) to
the sweeper (hparams_search=...).
"""

import shutil
from pathlib import Path

import hydra
from _common import check_choices, log, one_line_errors, progress, rank_zero_hydra_argv, write_json
from omegaconf import DictConfig, OmegaConf

from motionsynth.sweeps import job_context
from motionsynth.training.distributed import is_main
from motionsynth.training.run import CURVE, run, run_name


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> float:
    if cfg.get("model") is None:
        raise SystemExit("choose a model: python pipelines/train.py model=<name> (one of conf/model/*.yaml)")
    resolved = OmegaConf.to_container(cfg, resolve=True)
    job = job_context(resolved)
    summary = run(resolved, progress=progress(cfg), job=job)
    name = run_name(resolved)
    metric = cfg.get("optimized_metric") or summary["monitor"]
    if is_main():  # under torchrun: rank 0 only
        if not job.sweep:  # a sweep job's summary stays in its own folder, not in the DVC metrics / plots
            write_json(f"{cfg.paths.reports}/metrics/train/{cfg.dataset.name}/{name}.json", summary)
            curve = Path(cfg.paths.reports) / "plots" / "train" / cfg.dataset.name / f"{name}.csv"
            curve.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(Path(cfg.paths.models) / cfg.dataset.name / name / CURVE, curve)
        log.info("train %s on %s: %d epochs, best %s = %.5f", name, cfg.dataset.name,
                 summary["epochs_run"], metric, summary.get(metric, float("nan")))
    return float(summary.get(metric, float("nan")))


if __name__ == "__main__":
    check_choices()         # model=nosuch: one line, before Hydra composes
    rank_zero_hydra_argv()  # torchrun: ranks > 0 write no Hydra output folders
    main()

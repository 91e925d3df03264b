"""Shared wiring for the thin Hydra entry points (logging, paths, tracking, metrics files)."""

from __future__ import annotations

import functools
import json
import logging
import os
import sys
from pathlib import Path
from typing import Any, Callable

from omegaconf import DictConfig, OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))  # runnable without install
# Jobs that Hydra's launchers start in other processes (submitit locally or on SLURM, which
# unpickle the task function; joblib's workers) import this module again: they find it and the
# library through PYTHONPATH, which those processes inherit.
os.environ["PYTHONPATH"] = os.pathsep.join(
    dict.fromkeys([str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1] / "src"),
                   *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]))

from motionsynth.threads import OMP_SPIN_DEFAULT, OMP_SPIN_ENV  # noqa: E402  (imports no torch)

# Idle OpenMP threads spin briefly, then sleep, so stages that share the cores (sweeps, `dvc exp run -j`,
# a busy workstation) do not burn each other's cycles (motionsynth.threads). Set before torch starts.
os.environ.setdefault(OMP_SPIN_ENV, OMP_SPIN_DEFAULT)

from motionsynth import allocator  # noqa: E402

# A training step's buffers are reused, not returned to the kernel and faulted back in (motionsynth.allocator).
allocator.tune()

from motionsynth import tracking  # noqa: E402
from motionsynth.data.types import USER_ERRORS  # noqa: E402

log = logging.getLogger("motionsynth")
#: exit code of a stage stopped by bad input, missing data or a config that does not fit its data
USER_ERROR_EXIT = 2
#: exit code of a training stage stopped on divergence (a non-finite loss, exploding GAN logits)
DIVERGED_EXIT = 3


def one_line_errors(main: Callable) -> Callable:
    """Wrap a stage's entry point (under ``@hydra.main``): bad input, missing data or a config that
    does not fit its data (:data:`motionsynth.data.types.USER_ERRORS`) print ONE line,
    ``<stage>: <message>``, on stderr and exit with :data:`USER_ERROR_EXIT`; so does a training run
    stopped on divergence (``FloatingPointError``: the trainer's non-finite loss, exploding GAN logits;
    exit :data:`DIVERGED_EXIT`; its checkpoints are those of the last good round). Anything else is a
    bug and keeps its traceback; so does every error of a multirun job (the launcher records it)."""

    @functools.wraps(main)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        try:
            return main(*args, **kwargs)
        except (*USER_ERRORS, FloatingPointError) as e:
            if _multirun():
                raise
            print(f"{Path(sys.argv[0]).stem}: {' '.join(str(e).split())}", file=sys.stderr, flush=True)
            raise SystemExit(DIVERGED_EXIT if isinstance(e, FloatingPointError) else USER_ERROR_EXIT) from None

    return wrapped


def check_choices(argv: list[str] | None = None, conf: Path = Path(__file__).resolve().parents[1] / "conf") -> None:
    """Refuse, in one line and before Hydra composes anything, a command-line choice of a config group
    that has no file (``model=nosuch``: Hydra's own message spans a dozen lines). Multirun lists
    (``model=a,b``) are checked value by value; ``+group=``/``~group`` and dotted keys are Hydra's. Groups
    of a ``--config-dir``/``-cd`` count too."""
    args = list(sys.argv[1:] if argv is None else argv)
    dirs = [conf] + [Path(b) for a, b in zip(args, args[1:]) if a in ("--config-dir", "-cd")] + \
        [Path(a.split("=", 1)[1]) for a in args if a.startswith("--config-dir=")]
    for arg in args:
        key, sep, value = arg.partition("=")
        if not sep or not key.isidentifier() or not (conf / key).is_dir() or value in ("", "null"):
            continue
        known = sorted({p.stem for d in dirs for p in (d / key).glob("*.yaml")})
        for v in value.split(","):
            if v not in known:
                print(f"{Path(sys.argv[0]).stem}: {key}={v}: no conf/{key}/{v}.yaml; one of {', '.join(known)}",
                      file=sys.stderr, flush=True)
                raise SystemExit(USER_ERROR_EXIT)


def _multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def progress(cfg: DictConfig | dict) -> bool:
    """Progress bars on an interactive terminal only (not in CI logs); PROGRESS=0 turns them off."""
    return bool(cfg.get("progress", True)) and os.environ.get("PROGRESS", "1") != "0" and sys.stderr.isatty()


def write_json(path: str | Path, obj: Any) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=1, default=str) + "\n")


_recorder: tracking.StageRecorder | None = None


def start(cfg: DictConfig) -> None:
    """Call first in every data stage: starts the MLflow recorder on the other core."""
    global _recorder
    if cfg.tracking.enabled:
        _recorder = tracking.StageRecorder(cfg.paths.root, f"{cfg.tracking.experiment_prefix}/{cfg.dataset.name}")


def track(cfg: DictConfig, stage: str, params: dict, metrics: dict, artifacts: list = ()) -> None:
    """Log this stage's run to MLflow: params, numeric metrics and artifacts."""
    if not cfg.tracking.enabled:
        return
    rec = _recorder or tracking.StageRecorder(cfg.paths.root, f"{cfg.tracking.experiment_prefix}/{cfg.dataset.name}")
    ds = cfg.dataset.name
    rec.submit(f"{stage}:{ds}", params, metrics,
               {"stage": stage, "dataset": ds, "profile": str(cfg.profile_name)}, list(artifacts))


def resolved(cfg: DictConfig, key: str) -> dict:
    return OmegaConf.to_container(cfg[key], resolve=True)  # type: ignore[return-value]


#: Hydra overrides for the ranks != 0 of a torchrun job: no .hydra/ copy, log to stdout only, no run folder
NON_ZERO_RANK_HYDRA = ("hydra.output_subdir=null", "hydra/job_logging=stdout", "hydra.run.dir=.")


def rank_zero_hydra_argv() -> None:
    """Under ``torchrun``, leave Hydra's output folders to rank 0: call before ``main()``.

    A worker whose ``RANK`` is set and not ``"0"`` gets :data:`NON_ZERO_RANK_HYDRA` appended
    to ``sys.argv`` (Hydra applies overrides in order, so they win over the command line's);
    rank 0 and single processes (``RANK`` unset) are left as they are."""
    rank = os.environ.get("RANK")
    if rank is not None and rank != "0":
        sys.argv += [o for o in NON_ZERO_RANK_HYDRA if o not in sys.argv]

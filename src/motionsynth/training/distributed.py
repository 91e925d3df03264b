"""Multi-process data-parallel training (DDP) launched by ``torchrun``.

    torchrun --standalone --nproc_per_node=2 pipelines/train.py dataset=bandai1 model=erd

``torchrun`` (``python -m torch.distributed.run``) starts one worker process per rank
and gives each ``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``, ``MASTER_ADDR`` and
``MASTER_PORT``. A process is *launched* when ``WORLD_SIZE > 1`` and ``RANK`` and
``LOCAL_RANK`` are set; :func:`init` then joins the process group: backend ``gloo``
on the CPU, ``nccl`` on CUDA, where rank ``r`` uses ``cuda:LOCAL_RANK``.

Everything here is a no-op in a single process (no launcher, or ``WORLD_SIZE=1``):
:func:`init` returns ``False``, :func:`rank` is 0, :func:`world` 1, :func:`is_main`
true, and :func:`barrier` / :func:`cleanup` do nothing, so the single-process trainer
runs exactly the code it ran before DDP existed.

The trainer (:class:`~motionsynth.training.trainer.Trainer`) calls :func:`init` itself;
:func:`cleanup` runs at interpreter exit (``atexit``) and may be called earlier.
"""

from __future__ import annotations

import atexit
import os

import torch
import torch.distributed as dist

_ATEXIT = {"registered": False}


def _env_int(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        return default


def _export_slurm_env() -> None:
    """SLURM tasks of a submitit job (``hydra/launcher=slurm`` with ``tasks_per_node`` or
    ``nodes`` > 1) get torchrun's variables (``RANK``, ``LOCAL_RANK``, ``WORLD_SIZE``,
    ``MASTER_ADDR``, ``MASTER_PORT``) from submitit's own helper. Untested here (no cluster)."""
    if "RANK" in os.environ or "SLURM_PROCID" not in os.environ or _env_int("SLURM_NTASKS", 1) <= 1:
        return
    try:
        from submitit.helpers import TorchDistributedEnvironment

        TorchDistributedEnvironment().export()
    except Exception as e:  # noqa: BLE001 - not a submitit job: each task trains on its own, say so
        import logging

        logging.getLogger(__name__).warning("SLURM job with %s tasks but no torch.distributed environment: %s",
                                            os.environ.get("SLURM_NTASKS"), e)


def launched() -> bool:
    """Whether a launcher (``torchrun``, or submitit on SLURM) started this process as one of
    ``WORLD_SIZE > 1`` ranks."""
    _export_slurm_env()
    return _env_int("WORLD_SIZE", 1) > 1 and "RANK" in os.environ and "LOCAL_RANK" in os.environ


def initialized() -> bool:
    """Whether this process has joined a process group (:func:`init`)."""
    return dist.is_available() and dist.is_initialized()


def world() -> int:
    """Number of ranks: the group's size, ``WORLD_SIZE`` under a launcher before :func:`init`, else 1."""
    if initialized():
        return dist.get_world_size()
    return _env_int("WORLD_SIZE", 1) if launched() else 1


def rank() -> int:
    """This process's global rank (0 in a single process); agrees with ``tracking.is_rank_zero``."""
    if initialized():
        return dist.get_rank()
    return _env_int("RANK", 0) if launched() else 0


def local_rank() -> int:
    """This process's rank on its node (``LOCAL_RANK``): its CUDA device index. 0 in a single process."""
    return _env_int("LOCAL_RANK", 0) if launched() else 0


def is_main() -> bool:
    """Rank 0: the one process that writes checkpoints, metrics files and logs."""
    return rank() == 0


def device_for(device: str | torch.device) -> torch.device:
    """``device`` for this rank: CUDA ranks each take ``cuda:LOCAL_RANK``; the CPU stays the CPU."""
    device = torch.device(device)
    if launched() and device.type == "cuda":
        return torch.device("cuda", local_rank())
    return device


def backend_for(device: str | torch.device) -> str:
    """``nccl`` for CUDA tensors, ``gloo`` for CPU tensors."""
    return "nccl" if torch.device(device).type == "cuda" else "gloo"


def init(device: str | torch.device = "cpu") -> bool:
    """Join the process group when launched by ``torchrun``; returns whether this run is distributed.

    ``device`` is the training device (``cpu``, ``cuda`` or ``cuda:N``); on CUDA the
    rank's device becomes ``cuda:LOCAL_RANK`` (also made the current CUDA device, as
    NCCL requires). Idempotent; ``False`` without doing anything in a single process.
    """
    if not launched():
        return False
    if not dist.is_available():
        raise RuntimeError("launched with WORLD_SIZE > 1, but this torch build has no torch.distributed")
    if initialized():
        return True
    device = device_for(device)
    if device.type == "cuda":
        torch.cuda.set_device(device)
    dist.init_process_group(backend=backend_for(device))
    if not _ATEXIT["registered"]:
        atexit.register(cleanup)
        _ATEXIT["registered"] = True
    return True


def barrier() -> None:
    """Wait until every rank gets here (no-op in a single process)."""
    if not initialized():
        return
    if dist.get_backend() == "nccl":
        dist.barrier(device_ids=[torch.cuda.current_device()])
    else:
        dist.barrier()


def cleanup() -> None:
    """Leave and destroy the process group (no-op when there is none)."""
    if initialized():
        dist.destroy_process_group()

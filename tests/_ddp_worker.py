"""Worker of ``tests/test_ddp.py``: one training run of the real :class:`Trainer`, launched by
``torchrun`` (one process per rank) with the path of a JSON spec:

* ``cfg``: the resolved pipeline config (data paths, model, ``train``);
* ``out``: the trainer's output folder; ``{rank}`` in it is replaced by the rank, so that
  what each rank writes lands in its own folder;
* ``steps``: a file that ``on_step`` (rank 0 only) appends ``[epoch, step, loss]`` lines to;
* ``result``: where rank 0 writes the history and whether it resumed;
* ``crash_after_epoch``: rank 0 dies (``os._exit``, no clean-up, like a ``kill -9``) right
  after that epoch's checkpoint, taking the job down.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import torch  # noqa: E402

from motionsynth.training import distributed  # noqa: E402
from motionsynth.training.run import build  # noqa: E402
from motionsynth.training.trainer import Trainer  # noqa: E402


def main(spec_path: str) -> None:
    spec = json.loads(Path(spec_path).read_text())
    torch.set_num_threads(1)
    model, train, val, tcfg = build(spec["cfg"])
    steps = Path(spec["steps"])

    def on_step(epoch: int, step: int, loss: float) -> None:
        with steps.open("a") as f:
            f.write(json.dumps([epoch, step, loss, distributed.rank()]) + "\n")

    def on_epoch(epoch: int, metrics: dict) -> None:
        if epoch == spec.get("crash_after_epoch"):
            os._exit(3)

    out = Path(spec["out"].format(rank=distributed.rank()))
    trainer = Trainer(model, train, val, tcfg, out, "ddp-test", on_epoch=on_epoch, on_step=on_step, progress=False)
    resumed = trainer.try_resume()
    result = trainer.fit()
    if distributed.is_main():
        Path(spec["result"]).write_text(json.dumps({"history": result["history"], "resumed": resumed,
                                                    "world": trainer.world, "distributed": trainer.distributed}))
    distributed.cleanup()


if __name__ == "__main__":
    main(sys.argv[1])

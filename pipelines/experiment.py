"""DVC stage `experiment`: the model params.yaml composes -> models/experiment/<dataset>/<model>/.

    dvc exp run -S model=vae_lstm -S train.epochs=5        # DVC composes params.yaml from conf/
    dvc exp run --queue -S model=glogen -S train.lr=1e-3   # ... then: dvc exp run --run-all -j 2

Reads params.yaml, the config DVC composed with Hydra (hydra.enabled), rather than composing
again: the `-S` overrides live only there (motionsynth.training.experiment).
"""

import logging
import sys
from pathlib import Path

import yaml
from _common import one_line_errors, progress, write_json

from motionsynth.training.experiment import run_experiment

ROOT = Path(__file__).resolve().parents[1]


@one_line_errors
def main() -> None:
    logging.basicConfig(level=logging.INFO, format="[%(asctime)s][%(name)s][%(levelname)s] - %(message)s")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    record = run_experiment(params, ROOT / "conf", progress=progress(params))
    write_json(Path(params["paths"]["reports"]) / "metrics" / "experiment.json", record)


if __name__ == "__main__":
    sys.exit(main())

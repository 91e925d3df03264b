"""params.yaml is composed from conf/ (DVC's Hydra composition, ``hydra.enabled`` in .dvc/config).

``dvc exp run [-S key=value ...]`` rewrites params.yaml from ``conf/config.yaml`` plus the
overrides before it runs; ``dvc repro`` reads it as it is. conf/ is the one source of truth:
after editing conf/, run ``python -m motionsynth.params`` (a test checks that the committed
params.yaml equals the composition). Uses DVC's own composition function, so the file is
byte-for-byte what ``dvc exp run`` writes.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def compose(root: str | Path = ROOT, overrides: list[str] | None = None) -> str:
    """The text DVC writes to params.yaml for ``overrides`` (``dvc exp run -S ...``)."""
    from dvc.utils.hydra import compose_and_dump

    root = Path(root).resolve()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "params.yaml"
        compose_and_dump(out, str(root / "conf"), None, "config", str(root), list(overrides or []))
        return out.read_text()


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    target = ROOT / "params.yaml"
    target.write_text(compose(ROOT, argv))
    print(f"wrote {target}")


if __name__ == "__main__":
    main()

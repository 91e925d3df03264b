"""The README and the Makefile agree (what the README promises, a make target runs)."""

from __future__ import annotations

import re

from conftest import REPO


def _target(name: str) -> str:
    """The recipe lines of Makefile target ``name``."""
    text = (REPO / "Makefile").read_text()
    m = re.search(rf"^{name}:.*\n((?:\t.*\n)+)", text, flags=re.M)
    assert m, f"no target {name!r} in the Makefile"
    return m.group(1)


def test_make_bench_runs_every_benchmark_the_readme_lists():
    readme = (REPO / "README.md").read_text()
    section = readme.split("## Benchmarks", 1)[1].split("\n## ", 1)[0]
    listed = set(re.findall(r"`(bench/[\w.]+\.py)`", section))
    run = set(re.findall(r"(bench/[\w.]+\.py)", _target("bench")))
    assert listed and listed == run, f"README lists {sorted(listed)}, make bench runs {sorted(run)}"
    assert all((REPO / b).exists() for b in run)

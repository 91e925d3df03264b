"""Markdown tables of the report (``reports/README.md``, ``reports/tables/*.md``)."""

from __future__ import annotations

from typing import Any, Iterable, Sequence


def md_escape(s: Any) -> str:
    """A cell's text: ``|`` escaped, newlines as spaces."""
    return str(s).replace("|", "\\|").replace("\n", " ")


def md_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(md_escape(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(md_escape(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)

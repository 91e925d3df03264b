"""The ``report`` stage: evaluation results + published numbers -> ``reports/README.md``, tables, plots.

Not an evaluation suite (no ``run(ctx)``; ``context.NOT_SUITES`` lists it). Inputs, all written
by ``evaluate@<ds>`` (:mod:`.context`) and ``animate@<ds>``, under ``reports/``:

* ``eval/<ds>/results.csv`` (one row per table cell: the :class:`~.context.Row` fields) and
  ``eval/<ds>/timings.json``; a dataset without it is reported as **not evaluated**;
* ``plots/<ds>/<curve>.csv`` (``method, horizon, value``);
* ``animations/<ds>/index.json`` + ``seq<i>.gif`` / ``.mp4`` (the ``animate`` stage);
* ``published_results.csv``: every published table cell (a byte copy of
  ``../shared/papers/published_results.csv``, so a clone works without ``../shared``).

Outputs: ``README.md`` (status, verdicts, every table, plots, animations), ``tables/<id>.md``
(one per configured table), ``figures/eval/*.png``; the same files are logged to MLflow (one run
``report:all`` in ``<prefix>/report``) with one metric per claim and side (1 holds, 0 does not).

Tables (``conf/report/default.yaml: tables``)
---------------------------------------------
Each table mirrors a paper table: our rows of ``(paper, table)`` are grouped in *blocks*
``(dataset, compare_to, metric, protocol)``; the published rows join a block on
``(paper, table, compare_to, metric)`` and a cell on ``(column, method)``. Rows: every method of
either side (published order first), each with an ``ours`` line (``mean ± std`` over seeds;
``n × seeds`` in its own column) and a ``paper`` line; a side without the method shows ``—``.
Calibration / reference rows (``kind="reference"``) follow in a separate table under the block.
Published blocks without any counterpart of ours (e.g. CMU walking) are shown on their own, and a
table whose datasets have no results says **not evaluated** above the published numbers.

A table no suite writes (``ours_from``; GlocalNet Table 2, GloGen's loss ablation, published on NTU
RGB+D 2-D, which we do not have) gathers our rows from other tables (:func:`gather`: the rows of the
listed ``(paper, table)`` pairs of the listed methods, renamed as the paper writes them, plus named
reference rows; no number is changed), shows the published blocks apart under the table's
``published_label`` (why they are not comparable), and ends with the **orderings** of the listed
methods per block and column (:func:`orderings`, columns matching ``order_columns``): the one
comparison that carries over between two datasets. A listed method without rows on an evaluated
dataset is named as **not evaluated**.

Claims (``conf/report/default.yaml: claims``)
---------------------------------------------
Each claim is data (the method, the columns, a test) and :func:`evaluate_claim` judges it from
the numbers, on our rows and on the published rows alike, block by block; nothing about the
outcome is written by hand. Tests: ``lowest`` (the method is below every baseline at each
column), ``growth`` (its rise from column ``from`` to ``to`` is below every baseline's),
``below_references`` (below each named calibration row), ``column_less`` (column ``better`` below
column ``worse`` for each method). Baselines are the block's other methods (ours: ``kind="model"``
only), minus the claim's ``exclude`` patterns, or the rows the claim names in ``baselines`` (those
it lacks are named as not evaluated against). ``method`` may list several methods: each one the
block holds is judged, and the block's verdict is the worst of theirs. ``table`` may list several
tables; ``metrics`` restricts the blocks judged to those metrics, and ``columns`` to the blocks
holding one of them (each block judged at those it holds). A claim on a table configured with
``ours_from`` is judged on the gathered rows; ``paper_note`` says why the paper's side has no
number (e.g. a claim the paper makes from qualitative results only). A verdict is ``holds`` /
``does not hold`` with the
deciding numbers, ``not evaluated`` when the block or a needed cell is missing (NaN included), and
``within noise`` where the deciding gap is smaller than twice the larger standard deviation of the two
rows compared (over training seeds for models trained with several seeds, over evaluation seeds for
stochastic rows), so that neither "holds" nor "does not hold" rests on noise.
"""

from __future__ import annotations

import json
import logging
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from .context import COLUMNS, slug
from .markdown import md_table
from .training import section as training_section

log = logging.getLogger(__name__)

JOIN = ["paper", "table", "compare_to", "metric", "column", "method"]
BLOCK = ["dataset", "compare_to", "metric", "protocol"]
DASH = "—"
HOLDS, FAILS, NA, NOISE = "holds", "does not hold", "not evaluated", "within noise"


# ============================================================================ inputs

def read_published(path: Path) -> pd.DataFrame:
    """``published_results.csv`` with its ``dataset`` column renamed ``compare_to`` (the join key)."""
    if not Path(path).exists():
        raise FileNotFoundError(f"published results {path} not found (a copy of ../shared/papers/published_results.csv)")
    pub = pd.read_csv(path, dtype=str, keep_default_na=False)
    need = {"paper", "table", "dataset", "metric", "column", "method", "condition", "value"}
    if need - set(pub.columns):
        raise ValueError(f"{path}: missing columns {sorted(need - set(pub.columns))}")
    pub = pub.rename(columns={"dataset": "compare_to"})
    pub["value"] = pd.to_numeric(pub["value"], errors="coerce")
    pub["order"] = np.arange(len(pub))
    return pub


def read_results(reports: Path, datasets: Sequence[str]) -> tuple[pd.DataFrame, dict[str, str]]:
    """All datasets' ``results.csv`` concatenated, and each dataset's status (``evaluated`` or why not)."""
    frames, status = [], {}
    for ds in datasets:
        path = Path(reports) / "eval" / ds / "results.csv"
        if not path.exists():
            status[ds] = f"not evaluated ({path.relative_to(reports)} missing: `dvc repro evaluate@{ds}`)"
            continue
        df = pd.read_csv(path, dtype={c: str for c in ("paper", "table", "compare_to", "metric", "column", "method",
                                                       "condition", "key", "protocol", "dataset", "run", "kind",
                                                       "note")}, keep_default_na=False)
        missing = set(COLUMNS) - set(df.columns)
        if missing:
            raise ValueError(f"{path}: missing columns {sorted(missing)} (written by an older evaluate stage?)")
        for c in ("value", "std", "n", "seeds"):
            df[c] = pd.to_numeric(df[c].replace("", np.nan), errors="coerce")
        df["dataset"] = df["dataset"].replace("", ds)
        df["order"] = np.arange(len(df))
        status[ds] = "evaluated" if len(df) else "evaluated, but no result rows"
        frames.append(df)
    ours = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[*COLUMNS, "order"])
    return ours, status


# ============================================================================ formatting

def fmt(v: float, digits: int = 3) -> str:
    """``digits`` significant digits, plain notation for 1e-3 <= |v| < 1e5."""
    if v is None or not np.isfinite(v):
        return DASH if v is None else "NaN"
    if v == 0:
        return "0"
    mag = math.floor(math.log10(abs(v)))
    if mag < -3 or mag >= 5:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{max(digits - 1 - mag, 0)}f}"


def cell(value: float | None, std: float = math.nan, digits: int = 3) -> str:
    """``mean ± std`` (std only when finite); ``—`` for no value, ``NaN`` for a failed measurement."""
    if value is None:
        return DASH
    if not np.isfinite(value):
        return "NaN"
    s = fmt(value, digits)
    if std is not None and np.isfinite(std):
        s += f" ± {fmt(std, 2)}"
    return s


# ============================================================================ blocks

@dataclass
class Cell:
    value: float
    std: float = math.nan
    n: float = math.nan
    seeds: float = math.nan


@dataclass
class Block:
    """One comparable group of cells: our rows of one (dataset, compare_to, metric, protocol), or
    the published rows of one (compare_to, metric). ``cells[method][column]``."""

    side: str                                    # "ours" | "paper"
    paper: str
    table: str
    compare_to: str
    metric: str
    dataset: str = ""
    protocol: str = ""
    columns: list[str] = field(default_factory=list)
    methods: list[str] = field(default_factory=list)
    cells: dict[str, dict[str, Cell]] = field(default_factory=dict)
    kind: dict[str, str] = field(default_factory=dict)
    condition: dict[str, str] = field(default_factory=dict)
    note: dict[str, str] = field(default_factory=dict)
    source: str = ""                             # ours gathered from another table: "<paper> <table>"

    @property
    def label(self) -> str:
        if self.side == "paper":
            return f"paper, {self.compare_to}"
        return f"ours, {self.dataset}" + (f" vs '{self.compare_to}'" if self.compare_to else "") + \
            (f", {self.protocol}" if self.protocol else "")

    def value(self, method: str, column: str) -> float:
        c = self.cells.get(method, {}).get(column)
        return c.value if c is not None else math.nan


def _method_names(df: pd.DataFrame) -> pd.Series:
    """Method names, disambiguated by condition where one method appears twice in a block."""
    dup = df.duplicated(["method", "column"], keep=False)
    names = df["method"].copy()
    names[dup] = df.loc[dup, "method"] + " (" + df.loc[dup, "condition"] + ")"
    return names


def _as_list(x: Any) -> list[str]:
    """``None`` -> ``[]``, a string -> ``[it]``, a sequence -> a list."""
    return [] if x is None else [x] if isinstance(x, str) else list(x)


def _select(df: pd.DataFrame, paper: str, table: str | Sequence[str] | None) -> pd.DataFrame:
    """The rows of ``paper`` and of ``table`` (one, several, or every table when ``None``)."""
    tables = _as_list(table)
    return df[(df["paper"] == paper) & (df["table"].isin(tables) if tables else True)]


def ours_blocks(ours: pd.DataFrame, paper: str, table: str | Sequence[str] | None) -> list[Block]:
    sel = _select(ours, paper, table)
    blocks = []
    group = ["table", *BLOCK]
    for key, df in sel.sort_values("order").groupby(group, sort=False):
        tbl, ds, comp, metric, proto = key
        b = Block("ours", paper, tbl, comp, metric, dataset=ds, protocol=proto,
                  source=str(df["source"].iloc[0]) if "source" in df.columns else "")
        df = df.assign(display=_method_names(df))
        b.columns = list(dict.fromkeys(df["column"]))
        for r in df.itertuples():
            if r.display not in b.cells:
                b.methods.append(r.display)
                b.cells[r.display] = {}
                b.kind[r.display] = r.kind or "model"
                b.condition[r.display] = r.condition
                b.note[r.display] = r.note
            b.cells[r.display][r.column] = Cell(float(r.value), float(r.std), float(r.n), float(r.seeds))
            if r.note and r.note not in b.note[r.display].split("\n"):
                b.note[r.display] = "\n".join(x for x in (b.note[r.display], r.note) if x)
        blocks.append(b)
    return blocks


def paper_blocks(pub: pd.DataFrame, paper: str, table: str | Sequence[str] | None) -> list[Block]:
    sel = _select(pub, paper, table)
    blocks = []
    for (tbl, comp, metric), df in sel.sort_values("order").groupby(["table", "compare_to", "metric"], sort=False):
        b = Block("paper", paper, tbl, comp, metric)
        b.columns = list(dict.fromkeys(df["column"]))
        for r in df.itertuples():
            if r.method not in b.cells:
                b.methods.append(r.method)
                b.cells[r.method] = {}
                b.kind[r.method] = "model"
                b.condition[r.method] = r.condition
                b.note[r.method] = r.note
            b.cells[r.method][r.column] = Cell(float(r.value))
        blocks.append(b)
    return blocks


def gather(ours: pd.DataFrame, src: Mapping[str, Any], paper: str, table: str,
           datasets: Sequence[str] | None = None) -> pd.DataFrame:
    """Our rows for a table that no suite writes (``ours_from``: GlocalNet Table 2, GloGen's loss
    ablation, whose published numbers are on a dataset we do not have): the rows of the tables
    ``src["tables"]`` (``[paper, table]`` pairs) of the methods ``src["methods"]`` (our name -> the name
    shown, as the paper writes it), plus the reference rows named in ``src["references"]``, on
    ``datasets`` (all when ``None``), re-labelled as rows of ``(paper, table)``; ``source`` names the
    table each came from. No number is changed."""
    names = dict(src.get("methods") or {})
    refs = set(src.get("references") or [])
    parts = []
    for p, t in src.get("tables") or []:
        sel = ours[(ours["paper"] == p) & (ours["table"] == t)]
        if datasets:
            sel = sel[sel["dataset"].isin(list(datasets))]
        keep = sel["method"].isin(list(names)) | ((sel["kind"] == "reference") & sel["method"].isin(refs))
        parts.append(sel[keep].assign(source=f"{p} {t}"))
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=[*ours.columns, "source"])
    if out.empty:
        return pd.DataFrame(columns=[*ours.columns, "source"])
    return out.assign(method=out["method"].map(lambda m: names.get(m, m)), paper=paper, table=table)


def orderings(blocks: Sequence[Block], names: Sequence[str], patterns: Sequence[str] | None,
              digits: int = 3) -> str:
    """For each block and column (those matching one of ``patterns``; all when none), the methods
    ``names`` that have a value there, in ascending order of it: what stays comparable where the
    absolute values are not (ours beside a paper's numbers on another dataset)."""
    rows = []
    for b in blocks:
        for col in b.columns:
            if patterns and not any(re.fullmatch(p, col) for p in patterns):
                continue
            vals = {m: b.cells[m][col] for m in names
                    if col in b.cells.get(m, {}) and np.isfinite(b.cells[m][col].value)}
            if len(vals) < 2:
                continue
            order = sorted(vals, key=lambda m: vals[m].value)
            rows.append([b.label + (f" ({b.metric})" if b.side == "ours" else ""), col,
                         " < ".join(f"{m} {cell(vals[m].value, vals[m].std, digits)}" for m in order)])
    return md_table(["block", "column", "ascending (mean ± std over seeds where random)"], rows) if rows else ""


def match(block: Block, pub_blocks: list[Block]) -> Block | None:
    return next((p for p in pub_blocks if (p.table, p.compare_to, p.metric) ==
                 (block.table, block.compare_to, block.metric)), None)


# ============================================================================ tables

def render_block(ours: Block | None, pub: Block | None, digits: int = 3, not_run: Mapping[str, str] | None = None) -> str:
    """Markdown of one block: models (ours and paper lines), then our reference rows apart. A published
    method without our row says why where ``not_run`` (``conf/report: not_run``) names it."""
    columns = list(dict.fromkeys([*(pub.columns if pub else []), *(ours.columns if ours else [])]))
    header = ["method", "source", "condition", *columns, "n × seeds"]
    rows = []
    ours_models = [m for m in (ours.methods if ours else []) if ours.kind.get(m) != "reference"]
    methods = list(dict.fromkeys([*(pub.methods if pub else []), *ours_models]))
    for m in methods:
        if ours is not None:
            if m in ours.cells:
                cs = ours.cells[m]
                ns = {(c.n, c.seeds) for c in cs.values()}
                rows.append([f"**{m}**", "ours", ours.condition[m],
                             *[cell(cs[c].value, cs[c].std, digits) if c in cs else DASH for c in columns],
                             "; ".join(_count(n, s) for n, s in sorted(ns, key=str))])
            else:
                why = (not_run or {}).get(m)
                rows.append([f"**{m}**", "ours", f"not run: {' '.join(str(why).split())}" if why else DASH,
                             *[DASH] * len(columns), ""])
        if pub is not None:
            first = ours is None
            if m in pub.cells:
                cs = pub.cells[m]
                rows.append([f"**{m}**" if first else "", "paper", pub.condition[m],
                             *[cell(cs[c].value, digits=digits) if c in cs else DASH for c in columns], ""])
            else:
                rows.append([f"**{m}**" if first else "", "paper", DASH, *[DASH] * len(columns), ""])
    out = [md_table(header, rows)] if rows else []
    refs = [m for m in (ours.methods if ours else []) if ours.kind.get(m) == "reference"]
    if refs:
        rh = ["calibration / reference row (no trained model)", "condition", *columns, "n × seeds"]
        rr = []
        for m in refs:
            cs = ours.cells[m]
            ns = {(c.n, c.seeds) for c in cs.values()}
            rr.append([f"*{m}*", ours.condition[m], *[cell(cs[c].value, cs[c].std, digits) if c in cs else DASH
                                                     for c in columns],
                       "; ".join(_count(n, s) for n, s in sorted(ns, key=str))])
        out.append("Calibration and reference rows, for reading the models' numbers (not models):\n\n" + md_table(rh, rr))
    notes = []
    if ours is not None:
        seen = set()
        for m in ours.methods:
            for nt in ours.note.get(m, "").split("\n"):                         # every distinct note of the row
                if nt and (m, nt) not in seen:
                    seen.add((m, nt))
                    notes.append(f"- *{m}*: {nt}")
    if notes:
        out.append("<details><summary>Notes on our rows</summary>\n\n" + "\n".join(notes) + "\n\n</details>")
    return "\n\n".join(out)


def _count(n: float, seeds: float) -> str:
    a = str(int(n)) if np.isfinite(n) else "?"
    b = str(int(seeds)) if np.isfinite(seeds) else "1"
    return f"{a} × {b}"


def render_table(spec: Mapping[str, Any], ours: pd.DataFrame, pub: pd.DataFrame, status: Mapping[str, str],
                 digits: int = 3, not_run: Mapping[str, str] | None = None) -> tuple[str, dict[str, Any]]:
    """Markdown of one configured table (title, intro, status, blocks) and a summary of what it holds."""
    paper, table = spec["paper"], spec.get("table")
    datasets = list(spec.get("datasets") or [])
    src = spec.get("ours_from")
    if src:                                       # ours come from other tables' rows (:func:`gather`)
        ours = gather(ours, src, paper, table, datasets)
    ob, pb = ours_blocks(ours, paper, table), paper_blocks(pub, paper, table)
    parts = [f"### {spec['title']}", str(spec.get("intro", "")).strip()]
    missing = [ds for ds in datasets if status.get(ds, "not evaluated").startswith("not evaluated")]
    for ds in missing:
        parts.append(f"**{ds}: {status.get(ds, 'not evaluated (not in the evaluate list)')}.** "
                     f"{'Only the published numbers are shown.' if pb else ''}")
    wanted = list(dict.fromkeys((src.get("methods") or {}).values())) if src else []
    for ds in datasets:
        if ds in missing:
            continue
        if not any(b.dataset == ds for b in ob):
            where = ", ".join(" ".join(t) for t in (src or {}).get("tables") or [])
            why = (f"(none of {', '.join(wanted)} in {where}: trained and evaluated?)." if src
                   else f"(is the suite in `conf/dataset/{ds}.yaml: evaluate.suites`?).")
            parts.append(f"**{ds}: evaluated, but its results hold no rows for {paper} {table or ''}** {why}")
            continue
        absent = [m for m in wanted if not any(b.dataset == ds and m in b.cells for b in ob)]
        if absent:
            parts.append(f"**{ds}: {', '.join(absent)} not evaluated** (no rows: the run is not trained, or "
                         f"`evaluate@{ds}` has not run since).")
    used = set()
    for b in ob:
        p = match(b, pb)
        if p is not None:
            used.add(id(p))
        head = f"**{b.dataset}**" + (f" — compared with *{b.compare_to}*" if b.compare_to else "") + \
               f" — {b.metric}" + (f" — protocol: {b.protocol}" if b.protocol else "")
        if b.source:
            head += f" — our rows of {b.source}"
        elif p is None and pb:
            head += " (no published counterpart)"
        parts += [head, render_block(b, p, digits, not_run)]
    for p in pb:
        if id(p) not in used:
            parts += [f"**published** — *{p.compare_to}* — {p.metric}: {spec['published_label']}"
                      if spec.get("published_label") else
                      f"**published only** — *{p.compare_to}* — {p.metric} (no counterpart in our data)",
                      render_block(None, p, digits)]
    if src and (ob or pb):
        order = orderings([*ob, *pb], wanted, spec.get("order_columns"), digits)
        if order:
            parts += ["**Orderings** — the one comparison that carries over between our data and the paper's: "
                      "the variants in ascending order of each column (lower is better for every distance here: "
                      "MMD, Euclidean distance, FID, jitter).", order]
    summary = {"blocks": len(ob), "published_blocks": len(pb), "rows": int(sum(len(b.methods) for b in ob)),
               "missing": missing}
    return "\n\n".join(x for x in parts if x), summary


# ============================================================================ claims

@dataclass
class Outcome:
    block: str
    side: str
    verdict: str
    detail: str


@dataclass
class ClaimResult:
    claim: Mapping[str, Any]
    outcomes: list[Outcome]

    def verdict(self, side: str) -> str:
        v = [o.verdict for o in self.outcomes if o.side == side]
        judged = [x for x in v if x != NA]
        if not judged:
            return NA
        for one in (HOLDS, FAILS, NOISE):
            if all(x == one for x in judged):
                return one
        return "mixed"


def _excluded(name: str, patterns: Sequence[str]) -> bool:
    return any(re.search(p, name) for p in patterns)


def _methods(claim: Mapping[str, Any]) -> list[str]:
    """The claim's ``method``: one name or a list of names (each judged)."""
    return _as_list(claim.get("method"))


def _baselines(block: Block, method: str, exclude: Sequence[str], claim: Mapping[str, Any] | None = None) -> list[str]:
    """The rows ``method`` is compared with: the claim's ``baselines`` where it names them (those the block
    holds), else every other model row of the block but the claim's other methods and ``exclude``."""
    claim = claim or {}
    if claim.get("baselines") is not None:
        return [m for m in claim["baselines"] if m in block.cells and block.kind.get(m) != "reference"]
    others = set(_methods(claim)) | {method}
    return [m for m in block.methods if m not in others and block.kind.get(m) != "reference"
            and not _excluded(m, exclude)]


def _columns(block: Block, claim: Mapping[str, Any]) -> list[str]:
    """The columns a claim is judged at in ``block``: its ``columns`` that the block has (every column of
    the block when it names none)."""
    return [c for c in claim["columns"] if c in block.columns] if claim.get("columns") else list(block.columns)


def _applies(block: Block, claim: Mapping[str, Any]) -> bool:
    """Whether a block is one the claim is about: one of its methods there, its ``metrics`` (when it names
    some) and at least one of its ``columns`` (when it names some)."""
    if claim["test"] != "column_less" and not any(m in block.cells for m in _methods(claim)):
        return False
    if claim.get("metrics") and block.metric not in claim["metrics"]:
        return False
    return not (claim.get("columns") and claim["test"] in ("lowest", "below_references") and not _columns(block, claim))


def _spread(block: Block, method: str, column: str) -> float:
    c = block.cells.get(method, {}).get(column)
    return c.std if c is not None and np.isfinite(c.std) else 0.0


def _noise(gap: float, *stds: float) -> bool:
    """Whether a difference ``gap`` is within noise: smaller than twice the larger of the two rows'
    standard deviations (over training seeds, or over evaluation seeds for stochastic rows)."""
    sd = max([x for x in stds if np.isfinite(x)] or [0.0])
    return sd > 0 and abs(gap) < 2.0 * sd


def _verdict(fails: list[str], parts: list[str], skipped: list[str], method: str,
             noisy: list[str] | None = None) -> tuple[str, str]:
    """Columns judged -> holds / does not hold, or *within noise* when no column fails outright and some
    column's gap is within noise (:func:`_noise`); none judged -> not evaluated; missing ones are named."""
    miss = f"not evaluated at {', '.join(skipped)} (no {method} or comparison value)" if skipped else ""
    if not parts:
        return NA, miss or "no values"
    verdict = FAILS if fails else (NOISE if noisy else HOLDS)
    return verdict, "; ".join(parts + ([miss] if miss else []))


def _judge(block: Block, claim: Mapping[str, Any], refs: Block | None = None,
           candidate: float | None = None, expected: set[str] | None = None) -> tuple[str, str]:
    """One claim on one block: ``(verdict, detail with the numbers)``. A claim naming several methods is
    judged for each the block holds (:func:`_judge_one`): it does not hold if it fails for one, it is
    within noise if it holds for none outright, it holds if it holds for all; the methods the block
    lacks are named (not evaluated), those of ``expected`` only where given (the methods that some
    block of the block's table holds: a method another table names is not missing here)."""
    names = _methods(claim)
    if claim["test"] == "column_less" or len(names) <= 1:
        return _judge_one(block, claim, refs, candidate)
    results, absent = [], []
    for m in names:
        if m in block.cells:
            results.append((m, *_judge_one(block, {**claim, "method": m}, refs, candidate)))
        elif expected is None or m in expected:
            absent.append(m)
    judged = [v for _, v, _ in results if v != NA]
    verdict = NA if not judged else FAILS if FAILS in judged else NOISE if NOISE in judged else HOLDS
    detail = "; ".join(f"{m}: {d}" for m, _, d in results)
    if absent:
        detail += f"; not evaluated for {', '.join(absent)} (no row)"
    return verdict, detail


def _judge_one(block: Block, claim: Mapping[str, Any], refs: Block | None = None,
               candidate: float | None = None) -> tuple[str, str]:
    """One claim on one block for one method: ``(verdict, detail with the numbers)``."""
    test = claim["test"]
    method = claim.get("method")
    exclude = list(claim.get("exclude") or [])
    columns = _columns(block, claim)

    if test == "column_less":
        better, worse = claim["better"], claim["worse"]
        methods = list(claim.get("methods") or [m for m in block.methods if block.kind.get(m) != "reference"])
        pairs = [(m, block.value(m, better), block.value(m, worse)) for m in methods]
        pairs = [p for p in pairs if np.isfinite(p[1]) and np.isfinite(p[2])]
        if not pairs:
            return NA, f"no method with both '{better}' and '{worse}'"
        bad = [p for p in pairs if not p[1] < p[2]]
        detail = "; ".join(f"{m}: {fmt(a)} vs {fmt(b)}" for m, a, b in pairs)
        close = [m for m, a, b in pairs if abs(b - a) < max(_spread(block, m, better), _spread(block, m, worse))]
        return (FAILS if bad else HOLDS), f"{better} vs {worse}: {detail}" + \
            (f" (within the seed spread for {', '.join(close)})" if close else "")

    if method not in block.cells and candidate is None:
        return NA, f"no {method} row"

    def val(col: str) -> float:
        return candidate if candidate is not None else block.value(method, col)

    named = list(claim.get("baselines") or [])
    gone = [m for m in named if m not in block.cells]
    lacking = f"; not evaluated against {', '.join(gone)} (no row)" if gone else ""

    if test == "lowest":
        base = _baselines(block, method, exclude, claim)
        if not base:
            return NA, (f"none of the baselines {', '.join(named)} has a row" if named else "no baseline rows")
        fails, parts, skipped, noisy = [], [], [], []
        for col in columns:
            v = val(col)
            bv = {m: block.value(m, col) for m in base}
            bv = {m: x for m, x in bv.items() if np.isfinite(x)}
            if not np.isfinite(v) or not bv:
                skipped.append(col)
                continue
            best = min(bv, key=bv.get)
            noise = candidate is None and _noise(bv[best] - v, _spread(block, method, col), _spread(block, best, col))
            note = " (within noise: less than twice the larger std)" if noise else ""
            parts.append(f"{col}: {fmt(v)} vs best baseline {best} {fmt(bv[best])}{note}")
            if noise:
                noisy.append(col)
            elif not v < bv[best]:
                fails.append(col)
        verdict, detail = _verdict(fails, parts, skipped, method, noisy)
        return verdict, detail + lacking

    if test == "growth":
        a, b = claim["from"], claim["to"]
        base = _baselines(block, method, exclude, claim)
        g = val(b) - val(a)
        gb = {m: block.value(m, b) - block.value(m, a) for m in base}
        gb = {m: x for m, x in gb.items() if np.isfinite(x)}
        if not np.isfinite(g) or not gb:
            return NA, f"missing {a} or {b} values"
        least = min(gb, key=gb.get)

        def sd(m: str) -> float:                       # std of a rise: both ends' stds combined
            return float(np.hypot(_spread(block, m, a), _spread(block, m, b)))

        detail = f"rise {a}→{b}: {method} {fmt(g)} vs least-rising baseline {least} {fmt(gb[least])}{lacking}"
        if candidate is None and _noise(gb[least] - g, sd(method), sd(least)):
            return NOISE, detail + " (within noise: less than twice the larger std)"
        return (HOLDS if g < gb[least] else FAILS), detail

    if test == "below_references":
        src = refs if refs is not None else block
        names = list(claim.get("references") or [])
        fails, parts, skipped = [], [], []
        for col in columns:
            v = val(col)
            rv = {r: src.value(r, col) for r in names if r in src.cells}
            rv = {r: x for r, x in rv.items() if np.isfinite(x)}
            if not np.isfinite(v) or not rv:
                skipped.append(col)
                continue
            lowest = min(rv, key=rv.get)
            note = " (within the seed spread)" if abs(rv[lowest] - v) < max(_spread(src, lowest, col),
                                                                             _spread(block, method, col)) else ""
            parts.append(f"{col}: {fmt(v)} vs lowest reference {lowest} {fmt(rv[lowest])}{note}")
            if not v < rv[lowest]:
                fails.append(col)
        return _verdict(fails, parts, skipped, method)

    raise ValueError(f"claim {claim.get('id')}: unknown test {test!r} (lowest, growth, below_references, column_less, "
                     "reproduces)")


def _reproduces(block: Block, pub: Block | None, claim: Mapping[str, Any]) -> tuple[str, str]:
    """The ``reproduces`` test: our value of the claim's method within ``tolerance`` (relative) of the
    published value of the matching block (:func:`match`), at every column both hold. Where our row has a
    std (over training or evaluation seeds) and our value lies less than twice it from the edge of the
    tolerance band, inside or outside, the column is *within noise* (:func:`_noise`), not judged."""
    method, tol = claim["method"], float(claim.get("tolerance", 0.3))
    if pub is None or method not in pub.cells:
        return NA, f"no published {method} value for {block.compare_to or block.dataset}, {block.metric}"
    fails, parts, skipped, noisy = [], [], [], []
    for col in _columns(block, claim):
        v, ref = block.value(method, col), pub.value(method, col)
        if not (np.isfinite(v) and np.isfinite(ref) and ref != 0):
            skipped.append(col)
            continue
        rel = v / ref - 1.0
        noise = _noise(abs(v - ref) - tol * abs(ref), _spread(block, method, col))   # distance to the band's edge
        parts.append(f"{col}: ours {fmt(v)} vs published {fmt(ref)} ({rel:+.0%}; within ±{tol:.0%}: "
                     f"{'yes' if abs(rel) <= tol else 'no'}"
                     + ("; within noise: less than twice its std from the band's edge" if noise else "") + ")")
        if noise:
            noisy.append(col)
        elif abs(rel) > tol:
            fails.append(col)
    return _verdict(fails, parts, skipped, method, noisy)


def evaluate_claim(claim: Mapping[str, Any], ours: pd.DataFrame, pub: pd.DataFrame,
                   spec: Mapping[str, Any] | None = None) -> ClaimResult:
    """Judge ``claim`` on every block of its table(s), ours and published (module docstring). ``spec``: the
    configured table of the claim's ``(paper, table)``; where it gathers our rows from other tables
    (``ours_from``, :func:`gather`), the claim is judged on those."""
    src = claim.get("ours_from") or (spec or {}).get("ours_from")
    if src:
        ours = gather(ours, src, claim["paper"], claim["table"], (spec or {}).get("datasets"))
    ob = ours_blocks(ours, claim["paper"], claim.get("table"))
    pb = paper_blocks(pub, claim["paper"], claim.get("table"))
    several = len(_as_list(claim.get("table"))) > 1
    held: dict[str, set[str]] = {}                # per table: the methods some block of it holds
    for b in [*ob, *pb]:
        held.setdefault(b.table, set()).update(b.cells)

    def where(b: Block) -> str:                   # the block's label, with its table where the claim spans several
        return f"{b.table}, {b.label}" if several else b.label

    out = []
    for b in ob:
        if not _applies(b, claim) or (claim.get("protocol") and b.protocol != claim["protocol"]):
            continue
        if claim["test"] == "reproduces":         # ours against the paper's own number: no paper-side verdict
            out.append(Outcome(where(b), "ours", *_reproduces(b, match(b, pb), claim)))
            continue
        v, d = _judge(b, claim, expected=held.get(b.table))
        out.append(Outcome(where(b), "ours", v, d))
    if claim["test"] == "reproduces":
        return ClaimResult(claim, out)
    for p in pb:
        if claim["test"] == "below_references":
            proto = claim.get("paper_protocol")
            for b in ob:                                   # the published value against our calibration rows
                if (b.compare_to, b.metric) == (p.compare_to, p.metric) and (proto is None or b.protocol == proto) \
                        and claim.get("method") in p.cells:
                    cols = [c for c in (claim.get("columns") or p.columns) if c in p.cells[claim["method"]]]
                    if not cols:
                        continue
                    parts, verdicts = [], []
                    for c in cols:
                        vv, dd = _judge(b, {**claim, "columns": [c]}, refs=b, candidate=p.value(claim["method"], c))
                        verdicts.append(vv)
                        parts.append(dd)
                    v = NA if NA in verdicts else (FAILS if FAILS in verdicts else HOLDS)
                    out.append(Outcome(f"paper's {claim['method']} vs our calibration rows ({b.dataset}, {b.protocol})",
                                       "paper", v, "; ".join(parts)))
            continue
        if not _applies(p, claim):
            continue
        v, d = _judge(p, claim, expected=held.get(p.table))
        out.append(Outcome(where(p), "paper", v, d))
    return ClaimResult(claim, out)


def render_claims(results: Sequence[ClaimResult], why_missing: Mapping[str, str] | None = None) -> str:
    """The verdict table and, per claim, every block's verdict with its numbers. ``why_missing``:
    claim id -> why our side has no block (e.g. its dataset was not evaluated)."""
    rows = [[r.claim["text"], r.verdict("paper"), r.verdict("ours")] for r in results]
    parts = [md_table(["claim", "in the paper's numbers", "in ours"], rows)]
    for r in results:
        lines = [f"- **{r.claim['text']}**" + (f" ({r.claim['says']})" if r.claim.get("says") else "")]
        for o in r.outcomes:
            lines.append(f"  - {o.block}: **{o.verdict}** — {o.detail}")
        for side in ("ours", "paper"):
            if not any(o.side == side for o in r.outcomes):
                why = (why_missing or {}).get(r.claim.get("id"), "") if side == "ours" else (
                    r.claim.get("paper_note") or ("the published value is set beside our calibration rows, and there "
                                                  "are none" if r.claim["test"] == "below_references" else ""))
                at = f" at {', '.join(r.claim['columns'])}" if r.claim.get("columns") else ""
                lines.append(f"  - {side}: **{NA}** — " + (why or f"no {r.claim['paper']} "
                                                              f"{', '.join(_as_list(r.claim.get('table')))} block "
                                                              f"holds {' or '.join(_methods(r.claim)) or 'the methods'}"
                                                              f"{at}"))
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


# ============================================================================ plots

def plot_curves(reports: Path, datasets: Sequence[str], kinds: Mapping[tuple[str, str], str], out: Path,
                opts: Mapping[str, Any]) -> list[Path]:
    """One PNG per ``plots/<ds>/<curve>.csv``: lines for numeric horizons, a heat map for named ones."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    files = []
    labels = dict(opts.get("labels") or {})
    log_y = list(opts.get("log_y") or [])
    for ds in datasets:
        for csv in sorted((Path(reports) / "plots" / ds).glob("*.csv")):
            df = pd.read_csv(csv, keep_default_na=False)
            if df.empty or not {"method", "horizon", "value"} <= set(df.columns):
                continue
            name = csv.stem
            xl, yl = next((v for k, v in labels.items() if re.fullmatch(k, name)), ("horizon", "value"))
            df["value"] = pd.to_numeric(df["value"], errors="coerce")
            x = pd.to_numeric(df["horizon"], errors="coerce")
            if x.notna().all():
                fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=int(opts.get("dpi", 90)))
                df = df.assign(x=x)
                k_model = k_ref = 0
                for m, g in df.groupby("method", sort=False):
                    ref = kinds.get((ds, m)) == "reference"              # references: grey, a dash style each
                    style = dict(ls=("--", ":", "-.")[k_ref % 3], lw=1.3, color=("0.35", "0.55", "0.2")[k_ref % 3]) \
                        if ref else dict(ls="-", lw=1.8, color=f"C{k_model % 10}")
                    k_ref, k_model = k_ref + ref, k_model + (not ref)
                    ax.plot(g["x"], g["value"], label=m + (" (reference)" if ref else ""),
                            marker="o" if len(g) <= 12 else None, ms=3, **style)
                if any(re.fullmatch(p, name) for p in log_y) and (df["value"] > 0).all():
                    ax.set_yscale("log")             # floor: half the lowest method median (seed frames score ~0)
                    ax.set_ylim(bottom=0.5 * float(df.groupby("method")["value"].median().min()))
                ax.set_xlabel(xl)
                ax.set_ylabel(yl)
                ax.grid(alpha=0.3)
                ax.legend(fontsize=7, ncol=2, frameon=False)
            else:
                piv = df.pivot_table(index="method", columns="horizon", values="value", sort=False)
                fig, ax = plt.subplots(figsize=(max(5.0, 2.5 + 0.62 * piv.shape[1]), max(2.6, 1.4 + 0.3 * piv.shape[0])),
                                       dpi=int(opts.get("dpi", 90)))
                im = ax.imshow(piv.to_numpy(), cmap="viridis_r", aspect="auto")
                ax.set_xticks(range(piv.shape[1]), [str(c) for c in piv.columns], rotation=45, ha="right", fontsize=7)
                ax.set_yticks(range(piv.shape[0]), [m + (" (ref.)" if kinds.get((ds, m)) == "reference" else "")
                                                    for m in piv.index], fontsize=7)
                vals = piv.to_numpy()
                for i in range(vals.shape[0]):
                    for j in range(vals.shape[1]):
                        if np.isfinite(vals[i, j]):
                            ax.text(j, i, fmt(vals[i, j], 2), ha="center", va="center", fontsize=6,
                                    color="w" if vals[i, j] > np.nanmean(vals) else "k")
                fig.colorbar(im, ax=ax, label=yl, fraction=0.04)
                ax.set_xlabel(xl)
            ax.set_title(f"{ds}: {name}", fontsize=9)
            fig.tight_layout()
            path = out / f"{ds}__{name}.png"
            fig.savefig(path)
            plt.close(fig)
            files.append(path)
    return files


# ============================================================================ the report

def metrics_check(reports: Path, ds: str, df: pd.DataFrame) -> str:
    """Does ``metrics/<ds>.json`` (what ``dvc metrics show`` and MLflow show) hold the same numbers
    as ``results.csv``? Every finite value, keyed ``{slug(method): {key: round(value, 6)}}``."""
    path = Path(reports) / "metrics" / f"{ds}.json"
    if not path.exists():
        return "no metrics file"
    m = json.loads(path.read_text())
    fin = df[np.isfinite(df["value"].astype(float))]
    bad = sum(1 for r in fin.itertuples()
              if not math.isclose(float((m.get(slug(r.method)) or {}).get(r.key, math.nan)), round(float(r.value), 6),
                                  rel_tol=1e-9, abs_tol=1e-12))
    n = sum(len(v) for v in m.values())
    return f"{n} values" + (", the same as results.csv" if not bad else f", {bad} differ from results.csv")


def _status_section(datasets: Sequence[str], status: Mapping[str, str], ours: pd.DataFrame, reports: Path,
                    animations: Mapping[str, Any]) -> str:
    rows = []
    for ds in datasets:
        df = ours[ours["dataset"] == ds]
        if status[ds] != "evaluated" or df.empty:
            rows.append([ds, status[ds], "", "", "", "", "", ""])
            continue
        models = sorted(set(df.loc[df["kind"] != "reference", "method"]))
        ns = df["n"].dropna()
        seeds = df["seeds"].dropna()
        t = Path(reports) / "eval" / ds / "timings.json"
        timing = json.loads(t.read_text()) if t.exists() else {}
        anim = animations.get(ds) or {}
        rows.append([ds, f"{len(df)} rows, {len(set(df['table']))} tables", metrics_check(reports, ds, df),
                     ", ".join(models),
                     f"{int(ns.min())}–{int(ns.max())}" if len(ns) else "?",
                     f"{int(seeds.min())}–{int(seeds.max())}" if len(seeds) else "?",
                     ", ".join(f"{k} {v:g} s" for k, v in timing.items()) or "?",
                     f"{anim.get('total_s', '?')} s" if anim else "not rendered"])
    return md_table(["dataset", "results", "DVC metrics", "methods", "samples n (per seed)", "seeds", "evaluate time",
                     "animate time"], rows)


def _animations_section(reports: Path, datasets: Sequence[str]) -> tuple[str, dict[str, Any]]:
    parts, index = [], {}
    for ds in datasets:
        d = Path(reports) / "animations" / ds
        f = d / "index.json"
        if not f.exists():
            parts.append(f"**{ds}**: no animations (`dvc repro animate@{ds}` renders them).")
            continue
        idx = json.loads(f.read_text())
        index[ds] = idx
        if not idx.get("sequences"):
            parts.append(f"**{ds}**: the evaluate stage sampled no sequences to animate.")
            continue
        parts.append(f"**{ds}** — {idx.get('title', '')}")
        for s in idx["sequences"]:
            links = []
            if s.get("gif"):
                links.append(f"![{ds} sequence {s['index']}](animations/{ds}/{s['gif']})")
            if s.get("mp4"):
                links.append(f"[MP4](animations/{ds}/{s['mp4']})")
            parts.append(f"Sequence {s['index']}{(' (' + s['source'] + ')') if s.get('source') else ''}: "
                         f"{s['frames']} frames at {s['fps']:g} fps ({s['seconds']:.1f} s), panels: "
                         f"{', '.join(s['panels'])}.\n\n" + " ".join(links))
    return "\n\n".join(parts), index


def write_report(reports: Path, datasets: Sequence[str], published: Path, opts: Mapping[str, Any],
                 profile: str = "", eval_opts: Mapping[str, Any] | None = None,
                 mlflow_hint: str = "") -> dict[str, Any]:
    """Write ``README.md``, ``tables/*.md`` and ``figures/eval/*.png`` under ``reports``.

    Returns ``{"files": [...], "claims": [ClaimResult], "status": {ds: ...}, "metrics": {...}}``."""
    t0 = time.perf_counter()
    reports = Path(reports)
    pub = read_published(published)
    ours, status = read_results(reports, datasets)
    digits = int(opts.get("decimals", 3))
    tables_dir = reports / "tables"
    tables_dir.mkdir(parents=True, exist_ok=True)
    for old in tables_dir.glob("*.md"):
        old.unlink()
    files: list[Path] = []
    table_md = []
    for spec in opts.get("tables") or []:
        md, _ = render_table(spec, ours, pub, status, digits, opts.get("not_run"))
        path = tables_dir / f"{spec['id']}.md"
        path.write_text(md.replace("### ", "# ", 1) + "\n")
        files.append(path)
        table_md.append((spec, md))
    specs = list(opts.get("tables") or [])
    claims, why = [], {}
    for c in opts.get("claims") or []:
        tables = _as_list(c.get("table"))
        mine = [t for t in specs if t["paper"] == c["paper"] and (t.get("table") in tables if tables
                                                                  else t.get("table") is None)]
        claims.append(evaluate_claim(c, ours, pub, mine[0] if len(mine) == 1 else None))
        gone = [f"{ds} {status.get(ds, 'not evaluated')}" for t in mine for ds in t.get("datasets") or []
                if status.get(ds, "not evaluated").startswith("not evaluated")]
        if gone:
            why[c["id"]] = "; ".join(dict.fromkeys(gone))
    kinds = {(r.dataset, r.method): r.kind for r in ours.itertuples()}
    fig_dir = reports / "figures" / "eval"
    if fig_dir.exists():
        for old in fig_dir.glob("*.png"):
            old.unlink()
    figures = plot_curves(reports, datasets, kinds, fig_dir, opts.get("plots") or {})
    train_md, train_figs = training_section(reports, datasets, fig_dir, opts.get("plots") or {},
                                            (opts.get("notes") or {}).get("training"))
    files += figures + train_figs
    anim_md, anim_index = _animations_section(reports, datasets)
    e = dict(eval_opts or {})

    parts = ["# Results: the papers' tables, reproduced",
             f"Generated by the `report` stage (`dvc repro report`) from `reports/eval/<dataset>/results.csv` and the "
             f"published numbers in `reports/published_results.csv`. **Profile: `{profile}`.** "
             + (f"Evaluation: {e.get('seeds', '?')} seeds for stochastic models and random draws (mean ± std over "
                f"seeds), up to {e.get('max_windows', '?')} test windows per protocol, "
                f"{(e.get('animation') or {}).get('sequences', '?')} animated sequences per dataset. " if e else "")
             + "Every number below is in `dvc metrics show` (files `reports/metrics/<dataset>.json`) and in MLflow "
               f"(experiments `motionsynth/<dataset>`, runs `evaluate:<method>`; this report: `report:all`){mlflow_hint}.",
             "## Status", _status_section(datasets, status, ours, reports, anim_index),
             "## Training", train_md,
             "## Do the papers' claims hold here?",
             "Each claim is checked from the numbers of the tables below, on the paper's own numbers and on ours "
             "(block by block; `mixed`: holds in some blocks only).",
             render_claims(claims, why),
             "## Tables",
             "Each table: our value (mean ± std over seeds where the method or the measurement is random) on the "
             "`ours` line, the published value on the `paper` line; `—`: that side has no such row.",
             *[md for _, md in table_md]]
    titles = opts.get("note_titles") or {}
    for key, text in (opts.get("notes") or {}).items():       # `training` goes into the Training section
        if key != "training":
            parts += [f"### {titles.get(key, key)}", str(text).strip()]
    parts.append("## Plots")
    if figures:
        parts += [f"![{f.stem}](figures/eval/{f.name})" for f in figures]
    else:
        parts.append("No curves (`reports/plots/<dataset>/*.csv`) yet.")
    parts += ["## Animations",
              "Ground truth and every method side by side, the same camera for all panels (3-D: following the "
              "ground truth's root; the ground truth drawn faintly behind each method). GIFs embedded, MP4s linked.",
              anim_md or "No animations."]
    readme = reports / "README.md"
    readme.write_text("\n\n".join(p for p in parts if p) + "\n")
    files.insert(0, readme)
    metrics = {}
    for r in claims:
        for side in ("paper", "ours"):
            v = r.verdict(side)
            if v in (HOLDS, FAILS):
                metrics[f"claim/{r.claim['id']}/{side}"] = 1.0 if v == HOLDS else 0.0
    log.info("report: %d tables, %d claims, %d figures in %.1f s", len(table_md), len(claims), len(figures),
             time.perf_counter() - t0)
    return {"files": files, "claims": claims, "status": status, "metrics": metrics,
            "seconds": round(time.perf_counter() - t0, 2)}


def log_report(root: Path, experiment: str, result: Mapping[str, Any], params: Mapping[str, Any]) -> list[str]:
    """The report as one MLflow run ``report:all``: claim verdicts as metrics and tags, files as artifacts."""
    from .. import tracking

    tags = {"stage": "report", **{f"claim.{r.claim['id']}.{s}": r.verdict(s) for r in result["claims"]
                                  for s in ("paper", "ours")}}
    tags.update({f"status.{k}": v[:250] for k, v in result["status"].items()})
    return tracking.log_runs(root, experiment, [{"run_name": "report:all", "metrics": result["metrics"],
                                                 "params": dict(params), "tags": tags,
                                                 "artifacts": [str(f) for f in result["files"]]}])


__all__ = ["write_report", "log_report", "evaluate_claim", "render_table", "read_results", "read_published"]

"""The report's training section: every training stage's budget, selected step, convergence and
learning curve (not an evaluation suite: ``context.NOT_SUITES`` lists it).

Inputs, written by the ``train@<ds>-<run>`` stages:

* ``reports/metrics/train/<ds>/<run>.json``: the run's summary (``steps``, ``budget_steps``,
  ``best_step``, ``converged``, ``monitor`` and its best value, ``seconds``, ...);
* ``reports/plots/train/<ds>/<run>.csv``: one row per validation round (``step``, ``criterion``,
  ``train_loss``, ``val_loss``, ``val_pred_mse`` ...), also drawn by ``dvc plots``.

Outputs: a markdown section (a status table with a ``converged`` column, the stages that stopped
on their budget before converging named with their last improvement, and the stages whose
selected weights come from the first validation round) and one PNG of learning curves per
dataset (``figures/eval/<ds>__learning_curves.png``): per run, the training loss and the
validation loss (left axis, log) and the selection criterion (right axis), the selected step
marked.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from .markdown import md_table


def read_runs(reports: Path, dataset: str) -> list[dict[str, Any]]:
    """The summaries of a dataset's training runs (sorted by run name), each with its curve (``_curve``)."""
    out = []
    for f in sorted((Path(reports) / "metrics" / "train" / dataset).glob("*.json")):
        s = json.loads(f.read_text())
        s.setdefault("run", f.stem)
        c = Path(reports) / "plots" / "train" / dataset / f"{f.stem}.csv"
        s["_curve"] = pd.read_csv(c) if c.exists() else None
        out.append(s)
    return out


def _num(v: Any, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    return f"{float(v):.{digits}g}"


def last_gain(curve: pd.DataFrame | None, tail: float) -> str:
    """How much the criterion still improved over the last ``tail`` of the steps (relative)."""
    if curve is None or curve.empty:
        return "no curve"
    c = curve.dropna(subset=["criterion"])
    last = float(c["step"].max())
    before = c[c["step"] <= (1 - tail) * last]["criterion"]
    if before.empty:
        return "no validation before the last 20 % of the steps"
    b0, b1 = float(before.min()), float(c["criterion"].min())
    return f"{100 * (b0 - b1) / abs(b0):.1f} % better over the last {100 * tail:.0f} % of the steps"


def section(reports: Path, datasets: Sequence[str], fig_dir: Path, opts: Mapping[str, Any] | None = None,
            reasons: Mapping[str, str] | None = None) -> tuple[str, list[Path]]:
    """The markdown of the training section and the learning-curve PNGs it embeds. ``reasons`` maps a
    model name to why its stages stop on their budget (``conf/report/default.yaml: notes.training``);
    reference stages (zero-velocity, the mean pose: no optimiser steps) are marked as such, not as
    converged."""
    opts, reasons = dict(opts or {}), dict(reasons or {})
    rows, not_converged, first_round, figures = [], [], [], []
    n_trained = n_converged = 0
    for ds in datasets:
        runs = read_runs(reports, ds)
        for s in runs:
            mon = s.get("monitor", "")
            trained = int(s.get("budget_steps") or 0) > 0
            conv = ("yes" if s.get("converged") else "**no**") if trained else "reference (not trained)"
            n_trained += trained
            n_converged += bool(trained and s.get("converged"))
            rows.append([ds, s["run"], f"{_num(s.get('steps'))} / {_num(s.get('budget_steps'))}",
                         _num(s.get("best_step")) if trained else "—", conv,
                         f"{mon.split('/')[-1]} {_num(s.get(mon))}", _num(s.get("val/pred_mse")),
                         _num(s.get("val/zero_velocity_mse")), _num(s.get("seconds"), 3)])
            if trained and not s.get("converged"):
                why = reasons.get(str(s.get("model")), "")
                not_converged.append(f"`{ds}/{s['run']}`: stopped at step {_num(s.get('steps'))} of "
                                     f"{_num(s.get('budget_steps'))}, {last_gain(s['_curve'], 0.2)}"
                                     + (f" ({why})" if why else ""))
            if trained and s.get("best_epoch") == 0:
                first_round.append(f"`{ds}/{s['run']}`")
        if runs:
            f = plot_dataset(ds, runs, fig_dir, opts)
            if f is not None:
                figures.append(f)
    if not rows:
        return "No training summaries (`reports/metrics/train/<dataset>/*.json`) yet.", figures
    header = ["dataset", "run", "steps run / budget", "selected step", "converged", "selection criterion (val)",
              "val pred MSE", "zero-velocity MSE", "train s"]
    parts = ["Every training stage: its budget in optimiser steps, the step whose weights were selected (on the "
             "validation split, by the selection criterion; `rel_zv`: per-horizon MSE relative to zero-velocity, "
             "weighted 1/h, which a constant pose cannot win), and whether it converged (the criterion improved by "
             "less than 1 % over the last 20 % of the steps). `val pred MSE` is the long roll-out error (all frames "
             "after the seed, normalised units), kept for reference: the mean pose wins it.",
             md_table(header, rows)]
    parts.append(f"**{n_converged} of {n_trained} trained stages converged.** The references (zero-velocity, the "
                 "mean pose) have no optimiser steps and are not counted. **Stopped on the budget before converging:**"
                 + ("\n\n" + "\n".join(f"- {x}" for x in not_converged) if not_converged
                    else " none: every trained stage converged."))
    parts.append("**Selected weights from the first validation round:** " + (", ".join(first_round) if first_round
                                                                            else "none."))
    parts += [f"![{f.stem}](figures/eval/{f.name})" for f in figures]
    return "\n\n".join(parts), figures


def plot_dataset(ds: str, runs: list[dict[str, Any]], fig_dir: Path, opts: Mapping[str, Any]) -> Path | None:
    """One PNG: a panel per run with a curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [s for s in runs if s["_curve"] is not None and len(s["_curve"]) > 1]
    if not runs:
        return None
    cols = int(opts.get("curve_columns", 4))
    nrows = -(-len(runs) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.3 * cols, 2.4 * nrows), dpi=int(opts.get("dpi", 90)),
                             squeeze=False)
    for ax in axes.flat[len(runs):]:
        ax.axis("off")
    for ax, s in zip(axes.flat, runs):
        c = s["_curve"]
        ax.plot(c["step"], c["train_loss"], color="0.5", lw=1.0, label="train loss")
        if "val_loss" in c:
            ax.plot(c["step"], c["val_loss"], color="C0", lw=1.2, label="val loss")
        if (c[["train_loss"] + (["val_loss"] if "val_loss" in c else [])] > 0).all().all():
            ax.set_yscale("log")
        ax2 = ax.twinx()
        ax2.plot(c["step"], c["criterion"], color="C3", lw=1.4, label=s.get("monitor", "criterion"))
        if s.get("best_step") is not None:
            ax2.axvline(float(s["best_step"]), color="C3", ls=":", lw=1)
        ax2.tick_params(axis="y", labelcolor="C3", labelsize=7)
        ax.tick_params(labelsize=7)
        ok = "converged" if s.get("converged") else "NOT converged"
        ax.set_title(f"{s['run']} ({ok})", fontsize=8)
        ax.set_xlabel("optimiser step", fontsize=7)
    h1, l1 = axes.flat[0].get_legend_handles_labels()
    fig.legend(h1 + [plt.Line2D([], [], color="C3")], l1 + ["selection criterion (right axis)"], loc="upper center",
               ncol=3, fontsize=8, frameon=False)
    fig.suptitle(f"{ds}: learning curves (dotted: the selected step)", fontsize=9, y=0.995)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig_dir.mkdir(parents=True, exist_ok=True)
    path = fig_dir / f"{ds}__learning_curves.png"
    fig.savefig(path)
    plt.close(fig)
    return path

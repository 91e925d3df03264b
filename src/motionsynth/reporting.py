"""Markdown report writers (data report now; model tables in the evaluation stage)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from .data.prepare import select_joints
from .data.store import Store
from .viz.skeleton_plot import dataset_figure

DATA_COLUMNS = ["seen", "accepted", "rejected", "filtered", "sequences", "frames", "hours", "fps", "joints", "classes",
                "subjects", "views", "multi_body_sequences"]
UNKNOWN_IF_ZERO = {"subjects", "views"}  # 0 means the source does not record it


def md_table(header: list[str], rows: list[list[Any]]) -> str:
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:,.0f}" if abs(v) >= 100 else f"{v:.3g}" if v != int(v) else f"{int(v)}"
        if isinstance(v, int):
            return f"{v:,}"
        return str(v).replace("|", "\\|")
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def example_index(store: Store, example: str | None = None) -> int:
    """The sequence drawn in the data figure: ``example`` if configured, else the
    longest of the sequences with the most people (deterministic)."""
    meta = store.meta
    if example is not None:
        hits = np.flatnonzero(meta["sequence_id"].to_numpy() == example)
        if len(hits):
            return int(hits[0])
    bodies = meta["bodies"].to_numpy() if "bodies" in meta else np.ones(len(meta))
    return int(np.lexsort((-meta["frames"].to_numpy(), -bodies))[0])


def ingest_metrics(summary: dict[str, Any]) -> dict[str, Any]:
    """The flat per-dataset DVC metrics of ``ingest`` (one row per dataset in ``dvc metrics show``)."""
    return {k: (summary["accepted"] if k == "sequences" else summary.get(k, 0)) for k in DATA_COLUMNS}


def kept_joints(store: Store, dataset: dict[str, Any]) -> tuple[np.ndarray, Any]:
    """The joints ``prepare`` keeps in the dataset's first 3-D representation (e.g. Bandai without
    the static ``joint_Root`` at the origin): their indices in the store and the reduced skeleton."""
    reps = ((dataset.get("prepare") or {}).get("representations") or {}).values()
    rep = next((r for r in reps if r.get("space", "3d") == "3d"), None)
    if rep is None:
        return np.arange(store.skeleton.num_joints), store.skeleton
    return select_joints(store.skeleton, rep)


def data_report(datasets: list[dict[str, Any]], stage_metrics: Path, interim: Path, figures: Path,
                out_md: Path, profile: str) -> dict[str, Any]:
    """Write ``reports/data.md`` (table, figures, rejected items, notes) from the per-stage summaries."""
    rows, metrics, sections = [], {}, []
    for ds in datasets:
        name = ds["name"]
        d = stage_metrics / name
        ing = json.loads((d / "ingest.json").read_text())
        prep = json.loads((d / "prepare.json").read_text()) if (d / "prepare.json").exists() else {}
        spl = json.loads((d / "split.json").read_text()) if (d / "split.json").exists() else {}
        if ing["accepted"] + ing["rejected"] + ing.get("filtered", 0) != ing["seen"]:
            raise AssertionError(f"{name}: accepted + rejected + filtered != seen in {d / 'ingest.json'}")
        metrics[name] = m = ingest_metrics(ing)
        rows.append([name] + [("—" if k in UNKNOWN_IF_ZERO and m[k] == 0 else m[k]) for k in DATA_COLUMNS])
        store = Store.open(interim / name)
        i = example_index(store, (ds.get("report") or {}).get("example"))
        seq = store.sequence(i)
        keep, skel = kept_joints(store, ds)
        fig = dataset_figure(seq.positions[:, keep], skel, f"{name}: {seq.meta['sequence_id']} "
                             f"({seq.meta.get('label_name', '')})", figures / f"{name}.png", body_mask=seq.body_mask,
                             views2d=None if seq.views2d is None else seq.views2d[:, :, keep])
        sec = [f"### {name}", "", f"{ds.get('description', '').strip()}", "",
               f"Licence: {ds.get('licence', 'see datasets README')}", "",
               f"![{name}: pose and root trajectory]({fig.relative_to(out_md.parent).as_posix()})", ""]
        if ing.get("limited_to"):
            sec.append(f"**Profile `{profile}` limited ingest to {ing['limited_to']} of "
                       f"{ing['listed_in_archive']} listed items.**\n")
        if ing["rejected_items"]:
            sec += ["Rejected items:", ""] + [f"- `{r['member']}`: {r['reason']}" for r in ing["rejected_items"]] + [""]
        if ing.get("filtered"):
            sec += [f"Filtered out by the dataset config ({ing['filtered']:,} members, listed in "
                    f"`data/interim/{name}/filtered.csv`):", ""]
            sec += [f"- {n:,}: {why}" for why, n in ing.get("filtered_reasons", {}).items()] + [""]
        if ing.get("class_table"):
            sec.append(f"Classes ({len(ing['class_table'])}, label: name"
                       + (", raw id in the source" if any(c["raw"] != c["label"] for c in ing["class_table"]) else "")
                       + "): " + ", ".join(f"{c['label']}: {c['name']}" + (f" ({c['raw']})" if c["raw"] != c["label"]
                                                                            else "") for c in ing["class_table"]) + "\n")
        if ing["notes"]:
            sec += ["Notes:", ""] + [f"- {n}" for n in ing["notes"]] + [""]
        for rep, s in prep.get("representations", {}).items():
            clips = ", ".join(f"{fam}: {c['windows']:,} windows from {c['sequences_used']} sequences"
                              f" ({c['sequences_too_short']} too short)" for fam, c in s["clips"].items())
            sec.append(f"- prepared `{rep}`: {s['sequences']:,} sequences, {s['frames']:,} frames at "
                       f"{s['fps']:g} fps, {s['joints']} joints x {s['dims']}-D; {clips}"
                       + (f"; {s['dropped_untracked_frames']} untracked frames dropped"
                          if s.get("dropped_untracked_frames") else ""))
        for key, s in spl.items():
            sq = s["sequences"]
            sec.append(f"- split `{key}`: train {sq['train']}, val {sq['val']}, test {sq['test']}"
                       + (f", unused {sq['unused']}" if sq["unused"] else "") + " sequences")
        sections.append("\n".join(sec) + "\n")
    text = [
        "# Data report", "",
        f"Generated by `dvc repro` (stage `data_report`, profile `{profile}`). Every archive member that a "
        "reader lists, and every member of its format that the dataset config leaves out, is counted once as "
        "*seen*, and ends up *accepted*, *rejected* with a reason, or *filtered* out by the config (with the "
        "setting that left it out): accepted + rejected + filtered = seen holds for every row.", "",
        md_table(["dataset"] + DATA_COLUMNS, rows), "",
        "Columns: `sequences` = accepted source sequences; `frames` and `hours` at the source frame rate; "
        "`views` = 2-D camera views per sequence; `multi_body_sequences` = sequences with 2 or more people; "
        "— = not recorded by the source (Bandai and the CMU dances name no performers).", "",
        "## Datasets", "",
    ] + sections
    out_md.write_text("\n".join(text))
    return metrics

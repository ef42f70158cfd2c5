"""Reporting an evaluation: the summary (results.json), the table (results.md) and writing both.

:func:`summarize` turns the per-replication values of a
:class:`~t2m.evaluate.protocol.ProtocolResult` into mean and 95% interval per row and metric, with
the settings and every deviation from the standard protocol; :func:`format_markdown` renders it
like Table 2 of Guo et al.; :func:`write_results` writes both files atomically.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from dataset_tools.io import write_json_atomic, write_text_atomic
from t2m.evaluate import metrics
from t2m.evaluate.protocol import (
    GT_LENGTH,
    METRICS,
    PLAN_NAMES,
    ProtocolResult,
    deviations,
    other_plan,
    plan_row,
)

# Column headings of results.md.
COLUMN_TITLES = {
    "r_precision_top1": "R-precision top 1 ↑",
    "r_precision_top2": "R-precision top 2 ↑",
    "r_precision_top3": "R-precision top 3 ↑",
    "fid": "FID ↓",
    "mm_dist": "MM-Dist ↓",
    "diversity": "Diversity →",
    "multimodality": "MultiModality ↑",
    "semantic_accuracy": "Semantic accuracy ↑",
    "semantic_accuracy_all_fixed_timing": "Semantic accuracy, fixed timing ↑",
}


def _entry(series: list[float]) -> dict[str, Any]:
    """Mean, 95% interval and values of one metric; the interval is None (n/a) for a single
    replication, and a non-finite number is None, so results.json is standard JSON."""
    mean, interval = metrics.confidence_interval(series)
    return {
        "mean": _finite(mean),
        "interval": _finite(interval) if len(series) > 1 else None,
        "values": [_finite(value) for value in series],
    }


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def summarize(result: ProtocolResult) -> dict[str, Any]:
    """The results.json content: settings, deviations, and per row/metric mean, interval, values."""
    rows: dict[str, dict[str, Any]] = {}
    for row in result.rows:
        rows[row] = {}
        for name, series in result.values[row].items():
            rows[row][name] = _entry(series)
        for name, series in result.semantic[row].items():
            key = "semantic_accuracy" if name == "all" else f"semantic_accuracy_{name}"
            rows[row][key] = _entry(series)
        for name, series in result.physical.get(row, {}).items():
            rows[row][f"physical_{name}"] = _entry(series)
    notes = deviations(result.config, result.num_items, result.plans_differ, result.stratified)
    return {
        "quick": result.config.quick,
        "standard_protocol": not notes,
        "deviations": notes,
        "settings": dataclasses.asdict(result.config),
        "num_items": result.num_items,
        "num_items_available": result.num_available,
        "stratified": result.stratified,
        "rows": rows,
        "timings_s": result.timings_s,
    }


def _number(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _cell(entry: dict[str, Any] | None, digits: int = 3) -> str:
    """``mean ±interval``; ``n/a`` for a value that is not a number or an interval that one
    replication cannot give."""
    if entry is None:
        return "-"
    return f"{_number(entry['mean'], digits)} ±{_number(entry['interval'], digits)}"


def _semantic_breakdown(summary: dict[str, Any]) -> list[str]:
    """Per-action semantic accuracy (segments of that action recovered), one column per row."""
    prefix = "semantic_accuracy_action_"
    rows = list(summary["rows"])
    actions = sorted(
        {
            key[len(prefix) :]
            for row in rows
            for key in summary["rows"][row]
            if key.startswith(prefix)
        }
    )
    if not actions:
        return []
    lines = [
        "Segments recovered, per action (segments: how many were scored per replication, so "
        "how much one segment moves the share):",
        "",
        "| Action | segments | " + " | ".join(rows) + " |",
        "|---|---|" + "---|" * len(rows),
    ]
    for action in actions:
        cells = [_cell(summary["rows"][row].get(prefix + action)) for row in rows]
        scored = [
            summary["rows"][row].get(f"semantic_accuracy_scored_action_{action}") for row in rows
        ]
        counts = [entry["mean"] for entry in scored if entry is not None]
        segments = f"{counts[0]:.0f}" if counts else "-"
        lines.append(f"| {action} | {segments} | " + " | ".join(cells) + " |")
    return lines


# Columns of the physical-quality table (figures of dataset_tools.physical): title, digits.
PHYSICAL_COLUMNS = {
    "skating_ratio": ("Foot skating ratio ↓", 3),
    "penetration_mm": ("Penetration, mm ↓", 1),
    "floating_ratio": ("Floating ratio ↓", 3),
    "jerk_mean": ("Jerk mean, m/s³ →", 0),
    "jerk_peak": ("Jerk peak, m/s³ →", 0),
    "jerk_area": ("Jerk area vs real, m/s² ↓", 0),
    "bone_stretch_max_m": ("Bone stretch max, m ↓", 4),
    "bone_stretch_mean_m": ("Bone stretch mean, m ↓", 4),
    "bone_stretch_max_rel": ("Bone stretch max, relative ↓", 3),
    "bone_stretch_mean_rel": ("Bone stretch mean, relative ↓", 4),
}


def _physical_table(summary: dict[str, Any]) -> list[str]:
    """The physical-quality table (one line per row), or nothing when it was not measured."""
    rows = list(summary["rows"])
    if not any("physical_skating_ratio" in summary["rows"][row] for row in rows):
        return []
    lines = [
        "Physical quality (see `dataset_tools.physical`):",
        "",
        "| Method | " + " | ".join(title for title, _ in PHYSICAL_COLUMNS.values()) + " |",
        "|---|" + "---|" * len(PHYSICAL_COLUMNS),
    ]
    for row in rows:
        cells = [
            _cell(summary["rows"][row].get(f"physical_{name}"), digits)
            for name, (_, digits) in PHYSICAL_COLUMNS.items()
        ]
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Foot skating: share of frame steps in which a toe joint within 5 cm of the floor moves "
        "faster than 0.5 m/s (and so does its 5-frame average). Penetration: mean depth of the "
        "lowest foot joint below the floor. Floating: share of frames with a predicted foot "
        "contact and every foot joint above 5 cm. Jerk: per frame the largest joint's summed "
        "|xyz| third difference; its mean and peak per motion (closer to the real row is better), "
        "and the area between the row's mean jerk curve and that of real motions drawn apart. "
        "Bone stretch: per bone and frame, how far its length is from its median length in "
        "the motion (metres, and as a share of that length); per motion its largest and mean.",
    ]
    return lines


def _evaluator_line(evaluator: dict[str, Any]) -> str:
    """Which evaluator embedded the motions (its file and hash) and what normalised its input."""
    path, digest = evaluator["path"], evaluator["sha256"]
    where = "untrained, no file" if path is None else f"`{path}`, sha256 `{digest}`"
    return (
        f"Evaluator: {evaluator['source']} ({where}). Its input: raw features (generated ones "
        f"de-normalised with their generator's own statistics) normalised with "
        f"{evaluator['normalization']}."
    )


def format_markdown(summary: dict[str, Any], title: str = "Text-to-motion evaluation") -> str:
    """The results table (like Table 2 of Guo et al.) with a header that cannot be misread."""
    lines = [f"# {title}", ""]
    if summary["quick"]:
        lines += [
            "> **QUICK MODE — development numbers on a subset with few replications; do not "
            "compare them with published results.**",
            "",
        ]
    settings = summary["settings"]
    lines.append(
        f"Split `{settings['split']}`: {summary['num_items']} items evaluated "
        f"(of {summary['num_items_available']} usable), {settings['replications']} replications, "
        f"seed {settings['seed']}. Each cell is mean ±95% interval (1.96 σ / √replications"
        + ("; n/a with one replication)." if settings["replications"] == 1 else ").")
    )
    lines.append("")
    if "evaluator" in summary:
        lines += [_evaluator_line(summary["evaluator"]), ""]
    if summary["deviations"]:
        lines.append("Deviations from the standard protocol:")
        lines += [f"- {note}" for note in summary["deviations"]]
    else:
        lines.append("Standard protocol (Guo et al. 2022).")
    lines.append("")
    rows = list(summary["rows"])
    columns = list(METRICS)
    for semantic in ("semantic_accuracy", "semantic_accuracy_all_fixed_timing"):
        if any(semantic in summary["rows"][row] for row in rows):
            columns.append(semantic)
    lines.append("| Method | " + " | ".join(COLUMN_TITLES[c] for c in columns) + " |")
    lines.append("|---|" + "---|" * len(columns))
    for row in rows:
        cells = [_cell(summary["rows"][row].get(c)) for c in columns]
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    lines += ["", _plan_line(summary)]
    lines += [
        "",
        f"R-precision: each caption ranks the {settings['pool_size']} motions of its pool by "
        "embedding distance (the original evaluation code's orientation; each motion ranking the "
        "captions is in results.json as r_precision_motion_query_*). FID: against real motions "
        "re-drawn every replication. MM-Dist: distance between a motion and its caption. "
        "Diversity: mean distance of random pairs of motions (closer to the real row is better). "
        f"MultiModality: {settings['mm_texts']} captions x {settings['mm_samples']} generations, "
        f"{settings['mm_pairs']} pairs each.",
    ]
    if "semantic_accuracy" in columns:
        lines.append(
            "Semantic accuracy: fraction of motions whose ground-truth labels (action, side, "
            "direction, count) the demo corpus' detectors recover from the joints, in the "
            "labelled order wherever the motion performs them"
            + (
                "; fixed timing: cut in the proportions of the labelled clip."
                if "semantic_accuracy_all_fixed_timing" in columns
                else "."
            )
        )
        lines += ["", *_semantic_breakdown(summary)]
    physical_lines = _physical_table(summary)
    if physical_lines:
        lines += ["", *physical_lines]
    timings = summary.get("timings_s", {})
    if "total_s" in timings:
        lines += ["", f"Wall time: {timings['total_s']:.1f} s."]
    return "\n".join(lines) + "\n"


def _plan_line(summary: dict[str, Any]) -> str:
    """How the generated rows were made: the plan, and the other plan's rows where tabled."""
    plan = summary["settings"].get("plan", "whole")
    line = f"Generated rows: captions of several clauses {PLAN_NAMES[plan]}" + (
        " (as t2m.sample and the web app)" if plan == "clauses" else " (as the paper)"
    )
    other = plan_row(GT_LENGTH, other_plan(plan))
    if other in summary["rows"]:
        line += (
            f"; the row named '{PLAN_NAMES[other_plan(plan)]}' generates the same items, "
            "captions, lengths and seeds with the other plan (no MultiModality)."
        )
    else:
        line += "."
    return line


def _spread(entry: dict[str, Any] | None, digits: int = 3) -> str:
    """``mean (lowest-highest)`` over the replications of one metric."""
    if entry is None or entry["mean"] is None:
        return "n/a"
    values = [value for value in entry["values"] if value is not None]
    mean = f"{entry['mean']:.{digits}f}"
    if len(values) < 2:
        return mean
    return f"{mean} ({min(values):.{digits}f}-{max(values):.{digits}f})"


def headline(summary: dict[str, Any]) -> list[str]:
    """The evaluation's headline numbers as lines of text: per generated row with ground-truth
    lengths (each plan tabled), semantic accuracy, R-precision top 1 and FID, then semantic
    accuracy per action, each as mean (lowest-highest) over the replications."""
    settings = summary["settings"]
    rows = [row for row in summary["rows"] if row.startswith(GT_LENGTH[:-1])]
    lines = [
        f"mean (lowest-highest) over {settings['replications']} replications, each its own "
        f"generation seed and draw of {summary['num_items']} test items"
        + (
            f" (at least {settings['min_segments']} segments of every action)"
            if summary.get("stratified")
            else ""
        )
        + ":"
    ]
    for row in rows:
        values = summary["rows"][row]
        name = row if row != GT_LENGTH else f"{row[:-1]}, {PLAN_NAMES[settings['plan']]})"
        cells = []
        if "semantic_accuracy" in values:
            cells.append(f"semantic accuracy {_spread(values['semantic_accuracy'])}")
        cells.append(f"R@1 {_spread(values.get('r_precision_top1'))}")
        cells.append(f"FID {_spread(values.get('fid'))}")
        lines.append(f"  {name}: " + ", ".join(cells))
    prefix = "semantic_accuracy_action_"
    main = summary["rows"].get(GT_LENGTH, {})
    actions = sorted(key[len(prefix) :] for key in main if key.startswith(prefix))
    if actions:
        lines.append(f"  per action ({PLAN_NAMES[settings['plan']]}, ground-truth length):")
        cells = [f"{action} {_spread(main[prefix + action], 2)}" for action in actions]
        for start in range(0, len(cells), 4):
            lines.append("    " + ", ".join(cells[start : start + 4]))
    return lines


def write_results(summary: dict[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``results.json`` and ``results.md`` into ``out_dir`` (atomically)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out_dir / "results.json", out_dir / "results.md"
    write_json_atomic(json_path, summary)
    write_text_atomic(md_path, format_markdown(summary))
    return json_path, md_path

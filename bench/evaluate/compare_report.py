"""The ``compare`` report's Markdown: who leads, the figures, the tables, where each fails."""

from __future__ import annotations

import json

import pandas as pd

from bench.evaluate.band import band_section
from bench.evaluate.leaders import is_peer, leader_lines, spread_verdict

#: The backend's own pose errors in the scores (NaN for OpenCV, which has none).
OWN_POSE = ("own_rot_err_deg", "own_trans_err_mm")


def _markdown_table(frame: pd.DataFrame, floats: str = "{:.3g}") -> str:
    cells = [
        [floats.format(v) if isinstance(v, float) else str(v) for v in row]
        for row in frame.itertuples(index=False)
    ]
    head = "| " + " | ".join(frame.columns) + " |\n|" + "---|" * len(frame.columns) + "\n"
    return head + "".join("| " + " | ".join(row) + " |\n" for row in cells)


def render_report(
    summary: pd.DataFrame,
    tables: dict[str, pd.DataFrame],
    edges: pd.DataFrame,
    leads: pd.DataFrame,
    grids: dict[str, list[str]],
    meta: dict,
    failed: dict[str, str] | None = None,
) -> str:
    """The report's Markdown: who leads, the figures, the tables, where each variant fails;
    ``failed``: why each method that failed did (it has no measure)."""
    columns = [
        "pipeline",
        "fps",
        "fps_min",
        "fps_max",
        "correct_rate",
        "recall",
        "deflection_err_mm",
        "corner_err_px",
        "rot_err_deg",
        "trans_err_mm",
        *[c for c in (*OWN_POSE, "failed_frames") if c in summary],
        "false_positive_samples",
        "false_negative_samples",
        "refused_samples",
        "false_detections",
    ]
    lines = [
        "# Pipeline comparison",
        "",
        f"Dataset `{meta['dataset']}` ({meta['samples']} samples); speed on its own frames "
        "(below), one OpenCV thread; "
        f"{meta['cpu_count']} cores, OpenCV {meta['opencv']}, Mitsuba variant {meta['variant']}; "
        f"the whole comparison took {meta['wall_s']:.0f} s.",
        "",
        "## Who leads",
        "",
        "Per measure, the leading pipeline, the best of the project's pipelines and the best "
        "peer detector (`leaders.csv`); failure boundaries: how far recall stays >= 95 %.",
        "",
        *[f"- {line}" for line in leader_lines(leads)],
        *[f"- {line}" for line in failed_frame_lines(tables)],
        *[f"- {line}" for line in refused_lines(summary)],
        *[f"- {name}: failed, no measure: {why}" for name, why in (failed or {}).items()],
        "",
        *band_section(leads, meta),
        "## Accuracy against speed",
        "",
        *speed_section(leads, meta["speed"]),
        "![accuracy against speed](pareto.png)",
        "",
        _markdown_table(summary[columns]),
        "## Where each variant fails: recall and pose error against the imaging conditions",
        "",
        "Each axis varies one condition from a base point; dots are single seeds, lines their "
        "mean, so a boundary whose seeds disagree is visible as spread.",
        "",
        "![sweeps](sweeps.png)",
        "",
        _markdown_table(edges),
        "## Samples each variant gets wrong",
        "",
    ]
    for name, table in tables.items():
        wrong = table[table["outcome"] != "correct"]
        lines.append(f"### {name}: {len(table) - len(wrong)}/{len(table)} correct")
        lines.append("")
        if len(wrong):
            lines.append(
                _markdown_table(wrong[["sample_id", "outcome", "estimated_gaps", "true_gaps"]])
            )
        lines += [f"![{name} {g}](grids/{g})" for g in grids.get(name, [])] + [""]
    return "\n".join(lines) + "\n"


def speed_section(leads: pd.DataFrame, speed: dict) -> list[str]:
    """How frames/s was measured, and whether the speed lead is within the spread."""
    if not speed["frames"]:  # only results files and branch finders, or every pipeline failed
        return ["Frames/s: no pipeline was timed here; every method is accuracy only.", ""]
    lines = [
        f"Frames/s: {speed['frames']} frames of this dataset, in {speed['runs']} runs of "
        f"consecutive frames from {speed['samples']} samples (`speed_frames.csv`), each after an "
        "untimed lead-in frame; the pipelines alternate on every run, each round starting one "
        f"pipeline later, over {speed['rounds']} rounds (`speed_rounds.csv`), so a change in the "
        "machine's load falls on all of them alike. `fps` is the median over rounds, `fps_min` "
        "and `fps_max` the slowest and fastest round (the chart's bars). A method not timed in "
        "the rounds (a results file, with its own times or none; a branch finder) is not a "
        "rival for the speed lead.",
        "",
    ]
    fps = leads[leads["measure"] == "fps"]
    if len(fps) and isinstance(fps["lead_within_spread"].iloc[0], bool):
        row = next(fps.itertuples(index=False))
        lines += [f"The speed lead of {row.leader}: {spread_verdict(row)}.", ""]
    return lines


def refused_lines(summary: pd.DataFrame) -> list[str]:
    """A line per pipeline that refused every sample: it has no accuracy measure, so it leads
    on none and has no point in the accuracy charts; the line says why instead."""
    everything = summary[summary["refused_samples"] == summary["samples"]]
    return [
        f"{row.pipeline}: refused all {row.samples} samples (why: `refused_reason` in its "
        "scores' samples.csv), so it has no accuracy measure"
        for row in everything.itertuples()
    ]


def failed_frame_lines(tables: dict[str, pd.DataFrame]) -> list[str]:
    """A line per peer: the frames its backend crashed on, per sample (from the scores'
    ``failed_frames`` and ``failed_frame_ids``; NaN for a refused sample is no failure)."""
    lines = []
    for name, table in tables.items():
        if not is_peer(name) or "failed_frames" not in table:
            continue
        failed = table[table["failed_frames"] > 0]
        if failed.empty:
            lines.append(f"{name}: no failed frames")
            continue
        where = "; ".join(
            f"{r.sample_id} frames {', '.join(map(str, json.loads(r.failed_frame_ids)))}"
            if "failed_frame_ids" in table
            else f"{r.sample_id} ({int(r.failed_frames)} frames)"
            for r in failed.itertuples()
        )
        lines.append(f"{name}: {int(failed['failed_frames'].sum())} failed frames: {where}")
    return lines

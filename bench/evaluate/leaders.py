"""Who leads: per measure, the best pipeline, the best peer and the best project pipeline.

A comparison with peers (:mod:`pipeline.backends`) must say, measure by measure, whether the
project's pipelines or a peer detector is ahead; a chart alone leaves it to the reader. A
*peer* is a pipeline whose preset is named after a peer backend (``locus``, ``apriltag``, and
their ``/choice=`` variants): the detector as its authors ship it. A project preset on a peer's
detector (``robust/detector=locus``) is the project's pipeline, and counts as the project's.

Measures come from the ``compare`` summary or ``bench pipeline``'s rows (only the columns
present are read) and, for the failure boundaries, from
:func:`bench.evaluate.sweep_report.boundaries`: how far each pipeline keeps recall >= 95 %
(``last_ok``; a pipeline that fails at the first level is behind every other) and, on the
lighting axis, how many lightings it fails. Ties name every tied pipeline.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pipeline.backends import BACKENDS

#: Measures of a summary row: column, what it is, whether higher is better.
SUMMARY_MEASURES = (
    ("fps", "frames/s", True),
    ("recall", "marker recall", True),
    ("corner_err_px", "corner error (px, median)", False),
    ("rot_err_deg", "rotation error, project pose (deg, median)", False),
    ("trans_err_mm", "translation error, project pose (mm, median)", False),
    ("own_rot_err_deg", "rotation error, the backend's own pose (deg, median)", False),
    ("own_trans_err_mm", "translation error, the backend's own pose (mm, median)", False),
    ("correct_rate", "branch outcome correct (fraction of samples)", True),
)
#: Failure-boundary axes: axis, what is compared, whether higher is better.
BOUNDARY_MEASURES = (
    ("alpha_deg", "alpha kept (deg, last level with recall >= 95 %)", True),
    ("phi_deg", "tilt kept (deg, last level with recall >= 95 %)", True),
    ("blur_px", "motion blur kept (px, last level with recall >= 95 %)", True),
    ("read_noise_e", "read noise kept (e-, last level with recall >= 95 %)", True),
    ("lighting", "lightings failed (recall < 95 %)", False),
)
COLUMNS = (
    "measure", "label", "higher_better", "leader", "value",
    "best_project", "project_value", "best_peer", "peer_value",
)  # fmt: skip


def is_peer(pipeline: str) -> bool:
    """Whether the pipeline's preset is a peer backend's (``locus``, ``apriltag/...``)."""
    preset = pipeline.split("/")[0]
    return preset in BACKENDS and preset != "opencv"


def leaders(summary: pd.DataFrame, edges: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per measure present: the leader(s) and value, the best project pipeline and
    the best peer with theirs (empty name and NaN where that group has no value)."""
    measures = [
        (label, column, higher, summary.set_index("pipeline")[column])
        for column, label, higher in SUMMARY_MEASURES
        if column in summary
    ]
    if edges is not None and len(edges):
        for axis, label, higher in BOUNDARY_MEASURES:
            part = edges[edges["axis"] == axis].set_index("pipeline")
            if part.empty:
                continue
            if axis == "lighting":
                failing = part["failing"].fillna("").astype(str)
                values = failing.map(lambda f: float(len([x for x in f.split(",") if x])))
            else:  # failing at the first level: behind every pipeline that passes it
                values = part["last_ok"].astype(float).fillna(-math.inf)
            measures.append((label, axis, higher, values))
    rows = []
    for label, column, higher, values in measures:
        peers = np.array([is_peer(n) for n in values.index], bool)
        leader, value = _best(values, higher)
        project, project_value = _best(values[~peers], higher)
        peer, peer_value = _best(values[peers], higher)
        rows.append(
            dict(zip(COLUMNS, (column, label, higher, leader, value, project, project_value,
                               peer, peer_value), strict=True))
        )  # fmt: skip
    return pd.DataFrame(rows, columns=list(COLUMNS))


def _best(values: pd.Series, higher: bool) -> tuple[str, float]:
    """(the pipelines with the best finite value, comma-joined; that value), or ("", NaN).

    On a boundary axis -inf (failing from the first level) is a value, the worst one."""
    values = values.astype(float)
    values = values[~np.isnan(values.to_numpy())]
    if values.empty:
        return "", float("nan")
    best = values.max() if higher else values.min()
    return ", ".join(values.index[values == best]), float(best)


def leader_lines(table: pd.DataFrame) -> list[str]:
    """The leaders as sentences, one per measure (the report's and ``bench pipeline``'s)."""
    lines = []
    for row in table.itertuples(index=False):
        if not row.leader:
            continue
        verb = "lead" if ", " in row.leader else "leads"  # a tie names every tied pipeline
        parts = [f"{row.label}: {row.leader} {verb} ({_show(row.value)})"]
        if row.best_project:
            parts.append(f"best project pipeline {row.best_project} ({_show(row.project_value)})")
        if row.best_peer:
            parts.append(f"best peer {row.best_peer} ({_show(row.peer_value)})")
        lines.append("; ".join(parts))
    return lines


def _show(value: float) -> str:
    return "fails from the first level" if value == -math.inf else f"{value:.3g}"

"""Who leads: per measure, the best pipeline, the best peer and the best project pipeline.

A comparison with peers (:mod:`pipeline.backends`) must say, measure by measure, whether the
project's pipelines or a peer detector is ahead; a chart alone leaves it to the reader. A
*peer* is a pipeline whose preset is named after a peer backend (``locus``, ``apriltag``, and
their ``/choice=`` variants): the detector as its authors ship it; so is a method from outside
the project (a detector plugin, a results file, a branch finder). A project preset on a peer's
detector (``robust/detector=locus``) is the project's pipeline, and counts as the project's.

Measures come from the ``compare`` summary or ``bench pipeline``'s rows (only the columns
present are read) and, for the failure boundaries, from
:func:`bench.evaluate.sweep_report.boundaries`: how far each pipeline keeps recall >= 95 %
(``last_ok``; a pipeline that fails at the first level is behind every other) and, on the
lighting axis, how many lightings it fails. Ties name every tied pipeline.

The camera twin's lens blur is uncertain (its profile's band), so a lead is also checked at the
band's ends where there is evidence for it (:mod:`bench.evaluate.band`): ``holds_across_band``
is true when a leader at the nominal PSF (one of them, in a tie) also leads at every end, false
when not, empty where the measure was not judged; ``band_leaders`` names who leads at each end.

Frames/s is measured in repeated rounds (:mod:`bench.evaluate.timing`): the value is the median,
and ``fps_min`` and ``fps_max`` (the slowest and fastest round) its spread. A speed lead is
*within the spread* (``lead_within_spread`` true) when another pipeline's fastest round reaches
the leader's slowest round, or the leaders tie: another round could have put that pipeline
first. ``spread_rivals`` names those pipelines; both are empty for a measure without a spread,
or with no other pipeline timed. Only pipelines timed in the rounds (a spread) are compared: a
method with no speed (accuracy only) or a speed from elsewhere (a results file's own times) is
never a rival, and a lead of such a speed is not judged.
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
#: Measures with a spread across rounds: column, (its lowest, its highest) columns.
SPREADS = {"fps": ("fps_min", "fps_max")}
#: Failure-boundary axes: axis, what is compared, whether higher is better.
BOUNDARY_MEASURES = (
    ("alpha_deg", "alpha kept (deg, last level with recall >= 95 %)", True),
    ("phi_deg", "tilt kept (deg, last level with recall >= 95 %)", True),
    ("blur_px", "motion blur kept (px, last level with recall >= 95 %)", True),
    ("read_noise_e", "read noise kept (e-, last level with recall >= 95 %)", True),
    ("lighting", "lightings failed (recall < 95 %)", False),
    ("psf_scale", "lens blur kept (PSF scale, last level with recall >= 95 %)", True),
)
COLUMNS = (
    "measure", "label", "higher_better", "leader", "value",
    "best_project", "project_value", "best_peer", "peer_value",
    "holds_across_band", "band_leaders", "lead_within_spread", "spread_rivals",
)  # fmt: skip


#: How the names of methods from outside the project start: a detector plugin, a results file,
#: a branch finder (:mod:`bench.evaluate.outside`). They count as peers: not the project's.
OUTSIDE_PREFIXES = ("plugin:", "results:", "branch-plugin:")


def is_peer(pipeline: str) -> bool:
    """Whether the pipeline's preset is a peer backend's (``locus``, ``apriltag/...``) or the
    method is from outside the project (a plugin, a results file)."""
    if pipeline.startswith(OUTSIDE_PREFIXES):
        return True
    preset = pipeline.split("/")[0]
    return preset in BACKENDS and preset != "opencv"


def boundary_values(edges: pd.DataFrame, axis: str) -> pd.Series:
    """Per pipeline, what is compared on a boundary axis of ``edges``
    (:func:`bench.evaluate.sweep_report.boundaries`): ``last_ok``, -inf where the first level
    already fails (behind every pipeline that passes it); on lighting, the lightings failed."""
    part = edges[edges["axis"] == axis].set_index("pipeline")
    if axis == "lighting":
        failing = part["failing"].fillna("").astype(str)
        return failing.map(lambda f: float(len([x for x in f.split(",") if x])))
    return part["last_ok"].astype(float).fillna(-math.inf)


def leaders(
    summary: pd.DataFrame,
    edges: pd.DataFrame | None = None,
    band: dict[str, dict[float, pd.Series]] | None = None,
) -> pd.DataFrame:
    """One row per measure present: the leader(s) and value, the best project pipeline and
    the best peer with theirs (empty name and NaN where that group has no value), and whether
    the lead holds across the band.

    ``band``: per measure column, ``{PSF scale: values per pipeline}`` at the band's ends
    (:mod:`bench.evaluate.band`); a measure not in it gets an empty ``holds_across_band``."""
    by_name = summary.set_index("pipeline")
    measures = [
        (label, column, higher, by_name[column])
        for column, label, higher in SUMMARY_MEASURES
        if column in summary
    ]
    if edges is not None and len(edges):
        for axis, label, higher in BOUNDARY_MEASURES:
            if (edges["axis"] == axis).any():
                measures.append((label, axis, higher, boundary_values(edges, axis)))
    rows = []
    for label, column, higher, values in measures:
        peers = np.array([is_peer(n) for n in values.index], bool)
        leader, value = _best(values, higher)
        project, project_value = _best(values[~peers], higher)
        peer, peer_value = _best(values[peers], higher)
        holds, at_ends = _across_band(leader, (band or {}).get(column, {}), higher)
        within, rivals = _within_spread(leader, by_name, column, higher)
        rows.append(
            dict(zip(COLUMNS, (column, label, higher, leader, value, project, project_value,
                               peer, peer_value, holds, at_ends, within, rivals), strict=True))
        )  # fmt: skip
    return pd.DataFrame(rows, columns=list(COLUMNS))


def _across_band(
    leader: str, at_ends: dict[float, pd.Series], higher: bool
) -> tuple[bool | None, str]:
    """(whether one of the nominal ``leader``s also leads at every band end, None where that
    is unknown; the leaders at each end, ``"0.5: a, b; 1.5: c"``)."""
    if not at_ends:
        return None, ""
    ends = {scale: _best(values, higher)[0] for scale, values in sorted(at_ends.items())}
    named = "; ".join(f"{scale:g}: {names or 'none'}" for scale, names in ends.items())
    if not leader or not all(ends.values()):
        return None, named
    keep = set(leader.split(", "))
    for names in ends.values():
        keep &= set(names.split(", "))
    return bool(keep), named


def _within_spread(
    leader: str, by_name: pd.DataFrame, column: str, higher: bool
) -> tuple[bool | None, str]:
    """(whether the lead on ``column`` is within its spread across rounds, None where that is
    not judged; the other pipelines whose range reaches the leader's, comma-joined).

    Only the pipelines timed in the rounds (with a spread) are compared: one without (not
    timed, or a results file's own speed) is never a rival, and its lead is not judged."""
    spread = SPREADS.get(column)
    if not leader or spread is None or not set(spread) <= set(by_name):
        return None, ""
    low, high = (by_name[c].astype(float) for c in spread)
    timed = list(by_name.index[low.notna() & high.notna()])
    leads = leader.split(", ")
    if not set(leads) <= set(timed):  # a lead of a speed not timed here
        return None, ""
    others = [n for n in timed if n not in leads]
    if not others and len(leads) == 1:  # nobody else timed: no lead to judge
        return None, ""
    if higher:  # another's best round reaches the leaders' worst
        rivals = [n for n in others if high[n] >= low[leads].min()]
    else:
        rivals = [n for n in others if low[n] <= high[leads].max()]
    return bool(rivals) or len(leads) > 1, ", ".join(rivals)


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
        if not _named(row.leader):
            continue
        verb = "lead" if ", " in row.leader else "leads"  # a tie names every tied pipeline
        parts = [f"{row.label}: {row.leader} {verb} ({_show(row.value)})"]
        if _named(row.best_project):
            parts.append(f"best project pipeline {row.best_project} ({_show(row.project_value)})")
        if _named(row.best_peer):
            parts.append(f"best peer {row.best_peer} ({_show(row.peer_value)})")
        if _known(row.holds_across_band):
            verdict = "holds" if row.holds_across_band else "does not hold"
            parts.append(f"{verdict} across the band (leading at PSF {row.band_leaders})")
        if _known(row.lead_within_spread):
            parts.append(spread_verdict(row))
        lines.append("; ".join(parts))
    return lines


def spread_verdict(row) -> str:
    """Whether a leaders row's lead is within the spread across rounds, in words."""
    if row.lead_within_spread and _named(row.spread_rivals):
        return f"within the spread across rounds of {row.spread_rivals}"
    if row.lead_within_spread:
        return "a tie, within the spread across rounds"
    return "clear of the spread across rounds (its slowest round beats every other's fastest)"


def band_lines(table: pd.DataFrame) -> list[str]:
    """Which leads hold across the band and which do not, a sentence each (none without
    band evidence)."""
    judged = [r for r in table.itertuples(index=False) if r.leader and _known(r.holds_across_band)]
    held = [f"{r.label} ({r.leader})" for r in judged if r.holds_across_band]
    lost = [
        f"{r.label} ({r.leader} at the nominal PSF; {r.band_leaders})"
        for r in judged
        if not r.holds_across_band
    ]
    lines = []
    if held:
        lines.append("Leads that hold across the band: " + "; ".join(held) + ".")
    if lost:
        lines.append("Leads that do not hold across the band: " + "; ".join(lost) + ".")
    unjudged = [
        r.label
        for r in table.itertuples(index=False)
        if r.leader and not _known(r.holds_across_band)
    ]
    if judged and unjudged:
        lines.append(
            "Not judged across the band (no evidence, or no pipeline with a value at an end): "
            + "; ".join(unjudged)
            + "."
        )
    return lines


def _named(names: object) -> bool:
    """Whether a name cell names a pipeline (empty, or NaN as a CSV read back gives it: no)."""
    return isinstance(names, str) and bool(names)


def _known(holds: object) -> bool:
    """Whether a ``holds_across_band`` value is a verdict (True or False; None or NaN: not
    judged, as a CSV read back gives it)."""
    return isinstance(holds, bool | np.bool_)


def _show(value: float) -> str:
    return "fails from the first level" if value == -math.inf else f"{value:.3g}"

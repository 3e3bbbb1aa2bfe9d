"""Whether a rung matches the reference, and the knee of each axis: plain numbers in, out.

A rung matches when, in every cell (study) or for the clip (video), its detection-rate (or
marker-recall) Wilson interval overlaps the reference's, each median error is within
:data:`TOLERANCES` of the reference's or within twice the control's difference (the reference
rendered and recorded with other random draws: its own spread), and (video) the branch outcome
is the reference's wherever the control keeps it.
The tolerance is the larger of an absolute floor and a fraction of the reference's value:
the floors are about the spread of a median over the ladder's 80 images (corner error
~0.02 px, rotation ~0.05 deg, translation ~0.05 mm between noise seeds), doubled; the 25 %
is what a corner or pose error can move before it changes a pose-accuracy ranking.
"""

from __future__ import annotations

import math

import pandas as pd

#: metric: (absolute floor, fraction of the reference's value).
TOLERANCES = {
    "corner_err_px": (0.05, 0.25),
    "rot_err_deg": (0.1, 0.25),
    "trans_err_mm": (0.1, 0.25),
}

#: How many times the reference's own seed-to-seed difference a rung may differ by: the
#: control is one draw of that difference, a rung's difference is another.
SPREAD_FACTOR = 2.0


def within(value: float, reference: float, metric: str, spread: float = 0.0) -> bool:
    """``value`` within the metric's tolerance of ``reference``, or within
    :data:`SPREAD_FACTOR` times ``spread`` (the control's difference); NaN matches only NaN."""
    if math.isnan(reference) or math.isnan(value):
        return math.isnan(reference) and math.isnan(value)
    floor, fraction = TOLERANCES[metric]
    spread = 0.0 if math.isnan(spread) else spread
    return abs(value - reference) <= max(floor, fraction * abs(reference), SPREAD_FACTOR * spread)


def overlaps(lo: float, hi: float, ref_lo: float, ref_hi: float) -> bool:
    return lo <= ref_hi and ref_lo <= hi


def rung_matches(
    rows: pd.DataFrame, reference: pd.DataFrame, control: pd.DataFrame | None = None
) -> bool:
    """``rows``, ``reference`` and ``control`` (the reference with other random draws, one row
    per draw and cell): rows with ``cell``, rate_lo, rate_hi, the :data:`TOLERANCES` metrics
    and, for a video, ``branch_outcome``. A metric's spread is the largest difference of a draw;
    a branch outcome counts only where every draw keeps the reference's: one that other draws
    of the same scene change is noise, not an outcome."""
    ref = reference.set_index("cell")
    control = control if control is not None else reference.iloc[:0]
    for row in rows.itertuples():
        r = ref.loc[row.cell]
        c = control[control["cell"] == row.cell]  # one row per control draw
        if not overlaps(row.rate_lo, row.rate_hi, r.rate_lo, r.rate_hi):
            return False
        spread = {m: (c[m] - r[m]).abs().max() if len(c) else math.nan for m in TOLERANCES}
        if not all(within(getattr(row, m), r[m], m, spread[m]) for m in TOLERANCES):
            return False
        if "branch_outcome" not in rows:  # the study has none
            continue
        stable = (c["branch_outcome"] == r["branch_outcome"]).all()
        if stable and row.branch_outcome != r["branch_outcome"]:
            return False
    return True


def knee(rungs: pd.DataFrame) -> str | None:
    """The cheapest matching rung of one axis: ``rungs`` has one row per rung with ``rung`` and
    ``matches_reference``, in the axis' order of cost (fewer samples, fewer bounces, coarser,
    the reference last); None when none matches. The order, not the measured seconds, ranks
    them: rungs a few percent apart in cost swap places with the machine's load."""
    matching = rungs[rungs["matches_reference"]]
    return None if matching.empty else str(matching.iloc[0]["rung"])

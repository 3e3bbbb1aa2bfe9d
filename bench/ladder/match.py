"""Whether a rung matches the reference, and the knee of each axis: plain numbers in, out.

A rung matches when, in every cell (study) or for the clip (video), its detection-rate (or
marker-recall) Wilson interval overlaps the reference's, each median error is within
:data:`TOLERANCES` of the reference's, and (video) the branch outcome is the reference's.
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

#: The project's current choice on each axis (FrameSampling and StudyConfig defaults).
CURRENT_DEFAULTS = {
    ("study", "spp"): "16",
    ("study", "integrator"): "direct",
    ("study", "region"): "crop",
    ("study", "stage"): "all on",
    ("video", "spp"): "4",
    ("video", "background_spp"): "1",
    ("video", "integrator"): "direct",
    ("video", "region"): "band",
    ("video", "foliage_detail"): "default",
    ("video", "stage"): "all on",
}


def within(value: float, reference: float, metric: str) -> bool:
    """``value`` within the metric's tolerance of ``reference`` (NaN matches only NaN)."""
    if math.isnan(reference) or math.isnan(value):
        return math.isnan(reference) and math.isnan(value)
    floor, fraction = TOLERANCES[metric]
    return abs(value - reference) <= max(floor, fraction * abs(reference))


def overlaps(lo: float, hi: float, ref_lo: float, ref_hi: float) -> bool:
    return lo <= ref_hi and ref_lo <= hi


def rung_matches(rows: pd.DataFrame, reference: pd.DataFrame) -> bool:
    """``rows`` and ``reference``: one row per cell (column ``cell``) with rate_lo, rate_hi,
    the :data:`TOLERANCES` metrics and, for a video, ``branch_outcome``."""
    ref = reference.set_index("cell")
    for row in rows.itertuples():
        r = ref.loc[row.cell]
        if not overlaps(row.rate_lo, row.rate_hi, r.rate_lo, r.rate_hi):
            return False
        if not all(within(getattr(row, m), r[m], m) for m in TOLERANCES):
            return False
        if "branch_outcome" in rows and row.branch_outcome != r["branch_outcome"]:
            return False
    return True


def knee(rungs: pd.DataFrame) -> str | None:
    """The cheapest matching rung of one axis: ``rungs`` has one row per rung with ``rung``,
    ``s_per_image`` and ``matches_reference``; None when none matches."""
    matching = rungs[rungs["matches_reference"]]
    if matching.empty:
        return None
    return str(matching.sort_values("s_per_image", kind="stable").iloc[0]["rung"])

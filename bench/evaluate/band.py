"""The evidence whether a lead holds across the camera's band: each measure at the band's ends.

The camera twin's lens blur is uncertain (:class:`scenes.profile.Band`: the PSF scale's range
around the table as calibrated), so a leader found at the nominal PSF is only a finding if it
still leads at the band's low and high ends. The evidence differs by measure:

* **failure boundaries** (alpha, tilt, motion blur, read noise, lighting): the sweeps' boundary
  axes run again with the base point's PSF at each end
  (:meth:`~bench.evaluate.sweep_config.SweepConfig.band_end_sweeps`) and are read as at the
  nominal PSF (:func:`~bench.evaluate.leaders.boundary_values`);
* **the summary measures** of ``compare`` (recall, corner and pose errors), which come from the
  dataset at one PSF scale: the lens-sharpness sweep axis at the base point, each end's level
  (mean over seeds of each seed's recall or median error);
* ``bench pipeline``'s frames, recorded again at each end: their own recall and errors.

Each builder returns ``{measure column: {PSF scale: values per pipeline}}``, what
:func:`~bench.evaluate.leaders.leaders` reads; a measure absent there (frames/s, branch outcome)
is not judged. :func:`band_section` is the comparison report's paragraph on them.
"""

from __future__ import annotations

import pandas as pd

from bench.evaluate.leaders import (
    BOUNDARY_MEASURES,
    SUMMARY_MEASURES,
    band_lines,
    boundary_values,
)
from bench.evaluate.sweep_report import boundaries

#: Band values: {measure column: {PSF scale: values (pd.Series indexed by pipeline)}}.
BandValues = dict[str, dict[float, pd.Series]]


def band_end_boundaries(tables: dict[float, pd.DataFrame]) -> pd.DataFrame:
    """The boundaries (:func:`~bench.evaluate.sweep_report.boundaries`) of each band end's
    sweep table, ``{PSF scale: table}``, with that scale as a ``psf_scale`` column."""
    parts = [boundaries(t).assign(psf_scale=scale) for scale, t in tables.items()]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def sweep_band_values(
    sweeps: pd.DataFrame, band_edges: pd.DataFrame, ends: tuple[float, ...]
) -> BandValues:
    """Each measure at each band end: the summary measures from the lens-sharpness axis of the
    nominal sweep table ``sweeps``, the boundary axes from ``band_edges``
    (:func:`band_end_boundaries`)."""
    out: BandValues = {}
    lens = sweeps[sweeps["axis"] == "psf_scale"]
    for column, _, _ in SUMMARY_MEASURES:
        if column not in lens:
            continue
        for end in ends:
            at = lens[lens["level_value"] == end]
            if len(at):
                out.setdefault(column, {})[end] = at.groupby("pipeline", sort=False)[column].mean()
    for axis, _, _ in BOUNDARY_MEASURES:
        for end in ends:
            at = band_edges[(band_edges["psf_scale"] == end) & (band_edges["axis"] == axis)]
            if len(at):
                out.setdefault(axis, {})[end] = boundary_values(at, axis)
    return out


def rows_band_values(rows: dict[float, list[dict]]) -> BandValues:
    """Each measure at each band end from rows of figures (``{PSF scale: [{"pipeline": name,
    measure: value, ...}]}``, e.g. ``bench pipeline``'s frames at each end)."""
    out: BandValues = {}
    for end, figures in rows.items():
        table = pd.DataFrame(figures).set_index("pipeline")
        for column in table.columns:
            out.setdefault(column, {})[end] = table[column]
    return out


def band_section(leads: pd.DataFrame, meta: dict) -> list[str]:
    """The report's paragraph on the lens' uncertain blur: what each verdict rests on, its
    extra cost, and which leads hold across the camera's band and which do not."""
    band = meta["band"]
    if band is None:
        return [
            "The camera profile has no band (its PSF is taken as known): no lead is checked "
            "across one.",
            "",
        ]
    low, high = band["range"]
    ends = " and at ".join(f"{e:g}" for e in band["ends"])  # the nominal end is not rerun
    return [
        "## Across the lens' uncertain blur",
        "",
        f"The camera twin's PSF is known only within its profile's band: {low:g} to {high:g} "
        "times the table as calibrated (1). A lead *holds across the band* when a leader at the "
        "nominal PSF (one of them, in a tie) also leads at the ends (`leaders.csv`: "
        "`holds_across_band`, `band_leaders`). The evidence: for the failure boundaries, the "
        f"sweeps' boundary axes run again with the base point's PSF at {ends} "
        f"({seeds_text(band['band_seeds'])} x {band['images']} images a level, against "
        f"{seeds_text(band['seeds'])} at the nominal PSF; {band['band_sweeps_s']:.0f} s more, "
        f"against {band['sweeps_s']:.0f} s for the nominal sweeps; `sweeps_band_ends.csv`, "
        "`boundaries_band_ends.csv`). The dataset's recall, corner and pose errors were measured "
        f"at one PSF scale ({meta['dataset_psf_scale']:g}); whether their leads hold is judged "
        "on the sweeps' lens-sharpness axis instead: one marker at the base point "
        f"({band['base']}), {seeds_text(band['seeds'])} x {band['images']} images at each end, not "
        "the dataset's frames. Frames/s and the branch outcome are not judged.",
        "",
        *[f"- {line}" for line in band_lines(leads)],
        "",
    ]


def seeds_text(count: int) -> str:
    return f"{count} seed" + ("" if count == 1 else "s")

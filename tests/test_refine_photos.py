"""The edge-line refinement on real photographs of printed markers (tests/data/real_markers, its
SOURCES.md): against the consensus of independent detectors, ``lines`` falls back rarely,
brings OpenCV's corners closer, carries no outward bias on large markers, and says why where it
falls back. The consensus itself is recomputed from the detectors and checked against the
committed table. docs/refine_real.md gives the figures and the command that prints them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bench.evaluate.photos import (
    AGREE_PX,
    PHOTOS,
    PHOTOS_DIR,
    consensus_table,
    figures,
    measure,
    modules,
    read_consensus,
)
from pipeline.backends import available
from pipeline.refine import FAILURES

needs_peers = pytest.mark.skipif(
    not (available("locus") and available("apriltag")), reason="needs the peers extra"
)


def test_the_set_is_photographs_with_their_sources():
    sources = (PHOTOS_DIR / "SOURCES.md").read_text()
    for name, _ in PHOTOS:
        assert (PHOTOS_DIR / name).is_file()
        assert f"| {name} |" in sources  # each file's origin and licence
    assert sum(f.stat().st_size for f in PHOTOS_DIR.iterdir()) < 3_000_000


@pytest.mark.slow
@needs_peers
def test_the_consensus_is_what_the_detectors_agree_on():
    table = read_consensus()
    fresh = consensus_table()
    pd.testing.assert_frame_equal(fresh, table, check_exact=False, atol=1e-3)
    groups = table["references"].str.split("+")
    assert groups.map(len).min() >= 2  # every corner from two detectors or more
    assert set().union(*groups) == {"opencv", "locus", "apriltag"}
    assert table["spread_px"].max() <= AGREE_PX
    assert table["file"].nunique() == len(PHOTOS)  # every photograph contributes markers
    assert len(table) >= 50


@pytest.fixture(scope="module")
def opencv_start() -> dict:
    """``lines`` from OpenCV's unrefined corners (as the pipelines use it), both curves."""
    return {t: measure("lines", "opencv", t) for t in ("auto", "srgb", "linear")}


@needs_peers
@pytest.mark.parametrize("transfer", ["auto", "srgb", "linear"])
def test_lines_falls_back_rarely_and_says_why(opencv_start, transfer):
    """Each fallback's reason is its true cause: "edge scatter" only where a module is under
    4 px (the +-2 px window of an edge then holds the code bits' edges one module inside),
    "moved too far" only where OpenCV's corner is off by more than the shift limit (3/4
    module), and no "low contrast" (the quiet zone of a tag on a cube ends one module out:
    that is no lack of contrast)."""
    outcomes = opencv_start[transfer]
    f = figures(outcomes)
    assert f.markers == len(read_consensus())
    assert f.fallback_rate <= 0.21, f  # 17-21% (docs/refine_real.md), the issue's 15% not met
    assert set(f.reasons) <= set(FAILURES)
    assert "low contrast" not in f.reasons, f
    for o in outcomes:
        module_px = o.side_px / modules(dict(PHOTOS)[o.file])
        if o.failure == "edge scatter":
            assert module_px < 4.0, o
        if o.failure == "moved too far":
            assert o.before_px.max() > 0.75 * module_px, o


@needs_peers
@pytest.mark.parametrize("transfer", ["auto", "srgb", "linear"])
def test_lines_brings_opencv_corners_closer(opencv_start, transfer):
    f = figures(opencv_start[transfer])
    assert f.median_after_px < 0.5 * f.median_before_px, f


@needs_peers
def test_lines_linear_has_no_outward_bias_and_rarely_moves_a_corner_away():
    """Photographs are blurred after their curve (resampling, JPEG): ``transfer="linear"``, as
    tests/test_refine_real.py finds on its synthetic versions of these effects."""
    outcomes = measure("lines", "opencv", "linear")
    f = figures(outcomes)
    assert f.large_markers >= 4 and abs(f.large_outward_px) <= 0.2, f
    assert f.worse_markers <= 1, f
    refined = [o for o in outcomes if o.failure is None]
    worse = np.concatenate([o.after_px - o.before_px for o in refined])
    assert worse.max() < 0.7  # never by as much as the issue's 0.7-1.7 px


#: The issue's three figures with the default settings (transfer="auto"), from each detector's
#: corners. A refined corner may end up to WORSE_PX (0.25 px) further from the consensus than
#: its input: the references themselves lie up to 0.59 px from the consensus (0.32 median).
#: Not met yet (docs/refine_real.md, "What still does not hold"): strict, so that meeting them
#: turns these into failures to be made plain tests. On prints with known corners the consensus
#: itself is off by more than these limits (tests/test_refine_truth.py).
@needs_peers
@pytest.mark.xfail(
    strict=True,
    reason="not met (docs/refine_real.md): from OpenCV's corners fallback 21%, 1 marker moved "
    "away unreported, large-marker bias +0.26 px; from locus 13%, 4; from AprilTag 9%, 5, +0.26 px",
)
@pytest.mark.parametrize("start", ["opencv", "locus", "apriltag"])
def test_lines_defaults_meet_the_issue(start):
    f = figures(measure("lines", start))
    assert f.fallback_rate <= 0.15, f
    assert f.worse_markers == 0, f
    assert np.isnan(f.large_outward_px) or abs(f.large_outward_px) <= 0.2, f


@needs_peers
def test_lines_auto_is_no_worse_than_srgb_on_photographs(opencv_start):
    """What "auto" does hold: fewer markers moved away, less outward bias and closer corners
    than "srgb", and each fallback's reason is one of FAILURES."""
    auto, srgb = figures(opencv_start["auto"]), figures(opencv_start["srgb"])
    assert auto.worse_markers < srgb.worse_markers, (auto, srgb)
    assert abs(auto.large_outward_px) < 0.6 * abs(srgb.large_outward_px), (auto, srgb)
    assert auto.median_after_px < srgb.median_after_px, (auto, srgb)
    assert set(auto.reasons) <= set(FAILURES)

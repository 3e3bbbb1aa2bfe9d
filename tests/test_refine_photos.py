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
    return {t: measure("lines", "opencv", t) for t in ("srgb", "linear")}


@needs_peers
@pytest.mark.parametrize("transfer", ["srgb", "linear"])
def test_lines_falls_back_rarely_and_says_why(opencv_start, transfer):
    f = figures(opencv_start[transfer])
    assert f.markers == len(read_consensus())
    assert f.fallback_rate <= 0.15, f
    assert set(f.reasons) <= set(FAILURES)
    # the quiet zone of a tag on a cube ends one module out: that is no lack of contrast
    assert "low contrast" not in f.reasons, f


@needs_peers
@pytest.mark.parametrize("transfer", ["srgb", "linear"])
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
    assert worse.max() < 0.7  # never by as much as the 0.7-1.7 px

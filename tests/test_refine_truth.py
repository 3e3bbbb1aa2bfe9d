"""The references of the real-photograph consensus against the truth, on ray-cast prints of the
same kinds (bench.evaluate.prints): the consensus that ``lines`` is measured against on the real
set (tests/test_refine_photos.py) lies inside the true corners by more than the limits it is
held to there, and ``lines`` lies within a few hundredths of the truth on large markers.
docs/refine_real.md gives the whole table (``python -m bench.benchmarks.refine_truth``)."""

from __future__ import annotations

import pytest

from bench.evaluate.prints import FAMILIES, offsets
from pipeline.backends import available

needs_peers = pytest.mark.skipif(
    not (available("locus") and available("apriltag")), reason="needs the peers extra"
)


@pytest.fixture(scope="module")
def measured() -> dict:
    """Every method on the twin's kind of print (blur before the curve, noise, JPEG) and on a
    photograph's (blur after the curve, JPEG, uneven light), both sizes, and the latter's large
    markers in a quiet zone one module wide (the tags on cubes)."""
    runs = [(f, s, False) for f in ("twin", "jpeg") for s in ("large", "small")]
    runs.append(("jpeg", "large", True))
    return {key: offsets(*FAMILIES[key[0]], key[1], key[2]) for key in runs}


@pytest.mark.slow
@needs_peers
def test_every_method_is_measured_on_several_prints_of_each_kind(measured):
    """The means below are over 3 to 9 prints (OpenCV misses most of the twin's noisy small
    markers, the references disagree by over 1 px on 3 of its large ones)."""
    for key, row in measured.items():
        for method, r in row.items():
            assert r.found >= 3, (key, method, r)  # of 9 prints
    assert all(r.found == 9 for r in measured[("jpeg", "large", True)].values())


@pytest.mark.slow
@needs_peers
def test_opencv_subpix_and_the_consensus_lie_inside_the_true_corners(measured):
    """cornerSubPix puts the outer corners 0.3 px or more inside on every kind; the consensus
    (its mean with the peers that agree) is pulled inside with it, by up to half a pixel on
    small markers: more than the 0.2-0.25 px the issue's limits allow on the real set."""
    for key, row in measured.items():
        assert row["opencv"].outward_px < -0.3, (key, row["opencv"])
        assert row["consensus"].outward_px < -0.05, (key, row["consensus"])
    assert measured[("twin", "small", False)]["consensus"].outward_px < -0.25


@pytest.mark.slow
@needs_peers
def test_lines_is_nearer_the_truth_than_the_consensus_on_large_markers(measured):
    for key, row in measured.items():
        if key[1] == "large":
            assert abs(row["lines"].outward_px) < 0.05, (key, row["lines"])
            assert row["lines"].median_px < 0.06, (key, row["lines"])
            assert row["lines"].median_px < row["consensus"].median_px, key


@pytest.mark.slow
@needs_peers
def test_lines_is_nearer_the_truth_than_the_consensus_on_small_markers(measured):
    """Modules of 4 px or more have their curve measured on the border (5 px before: a
    photograph's small markers, blurred after the curve, came out 0.3 px outward)."""
    for kind, limit in (("twin", 0.1), ("jpeg", 0.15)):
        row = measured[(kind, "small", False)]
        assert abs(row["lines"].outward_px) < limit, (kind, row["lines"])
        assert row["lines"].median_px < row["consensus"].median_px, (kind, row)

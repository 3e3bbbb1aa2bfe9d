"""Scoring counts planted misses, false positives and errors correctly."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bench.evaluate.score import branch_outcome, score_markers
from scenes.conventions import make_T
from scenes.tables import (
    CORNER_COLUMNS,
    OWN_POSE_PREFIX,
    ROTATION_COLUMNS,
    TRANSLATION_COLUMNS,
    corner_values,
    pose_values,
)


@pytest.mark.parametrize(
    ("estimated", "true", "outcome", "fp", "fn"),
    [
        ([(3, 4)], [(3, 4)], "correct", 0, 0),
        ([(4, 5)], [(3, 4)], "correct", 0, 0),  # within one gap
        ([(5, 6)], [(3, 4)], "false_positive+false_negative", 1, 1),
        ([(3, 4), (9, 10)], [(3, 4)], "false_positive", 1, 0),  # planted false positive
        ([(3, 4)], [(3, 4), (8, 9)], "false_negative", 0, 1),  # planted miss
        ([], [], "correct", 0, 0),
        ([(6, 7)], [], "false_positive", 1, 0),
    ],
)
def test_branch_outcomes(estimated, true, outcome, fp, fn) -> None:
    got = branch_outcome(estimated, true)
    assert (got["outcome"], got["false_positives"], got["missed"]) == (outcome, fp, fn)


def _labels(n_frames: int = 3, n: int = 2) -> pd.DataFrame:
    rows = []
    for f in range(n_frames):
        for m in range(n):
            row = {"frame": f, "marker_id": m, "visible": True, "deflection_mm": 1.0 * f}
            row["contact"] = f >= 1
            corners = np.column_stack([10.0 * np.arange(4), np.full(4, 5.0 * m)])
            row.update({k: v[0] for k, v in corner_values(corners).items()})
            row.update({k: v[0] for k, v in pose_values(make_T(np.eye(3), [0, 0, 200])).items()})
            rows.append(row)
    return pd.DataFrame(rows)


def _detections(labels: pd.DataFrame) -> pd.DataFrame:
    """The labels as a detector without a pose of its own (opencv) would report them."""
    own = pose_values(np.full((len(labels), 4, 4), np.nan), OWN_POSE_PREFIX)
    return labels.drop(columns=["visible"]).assign(**own)


def test_marker_scores_count_misses_and_errors() -> None:
    labels = _labels()
    det = _detections(labels)
    det = det[~((det["frame"] == 2) & (det["marker_id"] == 1))]  # a planted miss
    det[CORNER_COLUMNS[0][0]] += 0.4  # one corner off by 0.4 px: mean corner error 0.1 px
    det[TRANSLATION_COLUMNS[0]] += 3.0
    det["deflection_mm"] += 0.5
    det.loc[det["frame"] == 0, "contact"] = True  # two planted false contacts
    s = score_markers(det, labels, foreign_ids=2)
    assert s["markers_visible"] == 6 and s["markers_found"] == 5
    assert s["recall"] == pytest.approx(5 / 6)
    assert s["false_detections"] == 2
    assert s["corner_err_px"] == pytest.approx(0.1)
    assert s["trans_err_mm"] == pytest.approx(3.0) and s["rot_err_deg"] == pytest.approx(0.0)
    assert s["deflection_err_mm"] == pytest.approx(0.5)
    assert s["contact_recall"] == pytest.approx(1.0)
    assert s["contact_precision"] == pytest.approx(3 / 5)
    rotated = det.copy()
    c, s_ = np.cos(np.radians(10)), np.sin(np.radians(10))
    for name, value in zip(ROTATION_COLUMNS, [c, -s_, 0, s_, c, 0, 0, 0, 1], strict=True):
        rotated[name] = value
    assert score_markers(rotated, labels)["rot_err_deg"] == pytest.approx(10.0)


def test_a_tracking_only_table_is_scored_without_deflection() -> None:
    """Detections straight from tracking (no deflection, no contact) against full labels."""
    labels = _labels()
    det = _detections(labels).drop(columns=["deflection_mm", "contact"]).iloc[1:]
    s = score_markers(det, labels)
    assert s["recall"] == pytest.approx(5 / 6) and "deflection_err_mm" not in s


def test_a_twin_of_another_layout_gives_no_threshold() -> None:
    """The threshold comes from the no-branch sample of the same foliage layout; a dataset
    made before layouts were shared says its twin is other foliage."""
    from bench.evaluate.score import OTHER_LAYOUT_TWIN, SAME_LAYOUT_TWIN, _none_twin

    def record(branches: str, group: str | None) -> dict:
        out = {"sample_id": f"soft-far-{branches}-indoor-sun"}
        return out if group is None else {**out, "foliage_group": group}

    for twin_group, sample_group, expected in (
        ("soft@1", "soft@1", ("soft-far-none-indoor-sun", SAME_LAYOUT_TWIN)),
        ("soft@2", "soft@1", (None, "")),
        (None, None, ("soft-far-none-indoor-sun", OTHER_LAYOUT_TWIN)),
    ):
        twin, sample = record("none", twin_group), record("0", sample_group)
        records = {r["sample_id"]: r for r in (twin, sample)}
        assert _none_twin(sample, records) == expected
    lone = record("0", "soft@1")
    assert _none_twin(lone, {lone["sample_id"]: lone}) == (None, "")

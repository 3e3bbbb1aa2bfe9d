"""The per-marker tables' schema: writers produce it exactly, readers refuse what departs from it,
and the column names are spelled in scenes/tables.py only."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.dataset.labels import label_table
from pipeline.detect import DetectorConfig
from pipeline.track import MarkerSet, track
from scenes.array import ArraySpec
from scenes.camera import default_camera
from scenes.marker import get_dictionary
from scenes.tables import (
    CORNER_COLUMNS,
    LABELS,
    TRACK,
    TRANSLATION_COLUMNS,
    Schema,
    check_table,
    corner_values,
    corners_of,
    names,
    ordered,
    pose_values,
    rotations_of,
    translations_of,
)

ROOT = Path(__file__).resolve().parents[1]
SPEC = ArraySpec()


def _assert_matches(table: pd.DataFrame, schema: Schema) -> None:
    """Names, order and exact dtypes."""
    assert list(table.columns) == names(schema)
    assert [str(table[c.name].dtype) for c in schema] == [c.dtype for c in schema]


def _labels(n_frames: int = 3) -> pd.DataFrame:
    rng = np.random.default_rng(0)
    angles = rng.uniform(-0.2, 0.2, (n_frames, SPEC.n_whiskers, 2))
    flags = angles[..., 0] > 0
    frames = np.arange(n_frames)
    return label_table(default_camera(), SPEC, angles, flags, ~flags, frames / 30.0, 2 * frames)


def frame_with_marker(marker_id: int) -> np.ndarray:
    """A grey frame of the default camera with one upright marker near the image centre."""
    camera = default_camera()
    frame = np.full((camera.height_px, camera.width_px), 128, np.uint8)
    image = get_dictionary(SPEC.dictionary).generateImageMarker(marker_id, 96, borderBits=1)
    y, x = camera.height_px // 2, camera.width_px // 2
    frame[y - 80 : y + 80, x - 80 : x + 80] = 255  # white quiet zone
    frame[y - 48 : y + 48, x - 48 : x + 48] = image
    return frame


def test_the_labels_writer_writes_the_labels_schema() -> None:
    labels = _labels()
    _assert_matches(labels, LABELS)
    assert len(labels) == 3 * SPEC.n_whiskers


def test_the_pipeline_writes_the_track_schema_with_and_without_detections() -> None:
    markers = MarkerSet(SPEC.marker_ids, SPEC.marker_size_mm)
    marked = frame_with_marker(SPEC.marker_ids[3])
    frames = [marked, np.full_like(marked, 128)]
    result = track(frames, default_camera(), markers, DetectorConfig())
    _assert_matches(result.detections, TRACK)
    assert result.detections[["frame", "whisker"]].to_numpy().tolist() == [[0, 3]]
    empty = track(frames[1:], default_camera(), markers, DetectorConfig()).detections
    _assert_matches(empty, TRACK)  # no marker seen: still integers and floats, not objects
    assert empty.empty


def test_values_round_trip_through_the_grouped_columns() -> None:
    rng = np.random.default_rng(1)
    corners = rng.uniform(0, 100, (5, 4, 2))
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, :3] = np.linalg.qr(rng.normal(size=(5, 3, 3)))[0]
    T[:, :3, 3] = rng.normal(size=(5, 3))
    table = pd.DataFrame({**corner_values(corners), **pose_values(T)})
    np.testing.assert_array_equal(corners_of(table), corners)
    np.testing.assert_array_equal(rotations_of(table), T[:, :3, :3])
    np.testing.assert_array_equal(translations_of(table), T[:, :3, 3])
    truth = table.add_suffix("_gt")
    np.testing.assert_array_equal(corners_of(truth, "_gt"), corners)


def test_ordered_refuses_a_column_the_schema_lacks_or_a_missing_one() -> None:
    values = dict(_labels().items())
    with pytest.raises(ValueError, match="missing: \\['visible'\\]"):
        ordered(LABELS, {k: v for k, v in values.items() if k != "visible"})
    with pytest.raises(ValueError, match="not in the schema: \\['extra'\\]"):
        ordered(LABELS, {**values, "extra": values["frame"]})


def test_check_table_accepts_the_writers_output_and_other_integer_widths() -> None:
    labels = _labels()
    check_table(labels, LABELS, "labels.parquet")
    check_table(labels.astype({"frame": "int32", "marker_id": "uint8"}), LABELS, "labels.parquet")
    check_table(labels.assign(extra="text"), LABELS, "labels.parquet")  # extra columns ignored


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.drop(columns=["visible"]), "column 'visible' is missing"),
        (
            lambda t: t.drop(columns=[TRANSLATION_COLUMNS[0]]),
            f"column '{TRANSLATION_COLUMNS[0]}' is missing",
        ),
        (lambda t: t.astype({"frame": float}), "column 'frame' is float64, must be int64"),
        (lambda t: t.astype({"visible": int}), "column 'visible' is int64, must be bool"),
        (
            lambda t: t.astype({CORNER_COLUMNS[1][0]: str}),
            f"column '{CORNER_COLUMNS[1][0]}' is (object|str), must be float64",  # pandas 2 | 3
        ),
        (lambda t: t.astype({"frame": "Int64"}), "column 'frame' is Int64, must be int64"),
    ],
)
def test_check_table_refuses_a_missing_column_or_a_wrong_dtype(tmp_path, edit, message) -> None:
    path = tmp_path / "sample" / "labels.parquet"
    path.parent.mkdir()
    edit(_labels()).to_parquet(path)
    with pytest.raises(ValueError) as info:
        check_table(pd.read_parquet(path), LABELS, path)
    assert re.fullmatch(re.escape(f"{path}: ") + message, str(info.value))


# -- spelled once -----------------------------------------------------------------------------

#: The old notation of the columns and the new column names: in no module but scenes/tables.py.
OLD = re.compile(r"R_CM_|t_CM_|t_M0M_")
NEW = re.compile(r"R_cam_marker_\w|t_cam_marker_\w|t_marker0_marker_\w|\bc(\d|\{k\})_[xy]_px")


def _sources() -> list[Path]:
    folders = ("scenes", "renderers", "pipeline", "bench", "tests")
    files = [p for d in folders for p in (ROOT / d).rglob("*.py")]
    assert len(files) > 50
    return [p for p in files if p.name not in ("tables.py", "test_tables.py")]


@pytest.mark.parametrize(
    ("pattern", "example"),
    [(OLD, "t_M0M_x_mm"), (NEW, 'f"c{k}_x_px"'), (NEW, "R_cam_marker_01"), (NEW, "c3_y_px")],
)
def test_column_names_are_spelled_in_scenes_tables_only(pattern, example) -> None:
    assert pattern.search(example)  # the scan below would see such a spelling
    hits = [
        f"{p.relative_to(ROOT)}:{n}: {line.strip()}"
        for p in _sources()
        for n, line in enumerate(p.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert not hits, "column names outside scenes/tables.py:\n" + "\n".join(hits)

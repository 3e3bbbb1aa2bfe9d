"""The columns of the per-marker tables, defined once: names, dtypes, units and meaning.

Three tables, one row per frame and marker, joined on :data:`JOIN_KEY`:

``TRACK``
    what :func:`pipeline.track.track` returns: corners and pose of every detected marker, the
    detector backend's own pose beside the project's (NaN where it has none) and whether the
    corner refinement fell back;
``DETECTIONS``
    ``detections.parquet`` (``whiskerbench detect``): ``TRACK`` plus deflection and contact;
``LABELS``
    ``labels.parquet`` of a dataset sample: the exact truth, same corner and pose columns.

Frames and units follow :mod:`scenes.conventions`: ``R_cam_marker_{ij}`` and
``t_cam_marker_{x,y,z}_mm`` are the rotation and translation of ``T_cam_marker``,
``t_marker0_marker_{x,y,z}_mm`` the translation of ``T_marker0_marker``; corners are pixel
coordinates with the centre of the top-left pixel at (0, 0), in ArUco order. Writers build their
columns with :func:`corner_values`, :func:`pose_values` and :func:`ordered`; readers take them
with :func:`corners_of`, :func:`rotations_of`, :func:`translations_of`; a table handed over on
disk is checked with :func:`check_table` before use. Plain NumPy: no pandas import here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Column:
    """One column: its name, the NumPy dtype writers produce, its unit ("" if none), meaning."""

    name: str
    dtype: str
    unit: str
    doc: str


Schema = tuple[Column, ...]

#: Suffix of the labels' columns in a detections-labels join (``detections.merge(labels)``).
TRUTH_SUFFIX = "_gt"

#: (x, y) column names of the four corners, ArUco order (TL, TR, BR, BL of the marker).
CORNER_COLUMNS: tuple[tuple[str, str], ...] = tuple((f"c{k}_x_px", f"c{k}_y_px") for k in range(4))
#: The rotation of T_cam_marker, row-major: R_cam_marker_{ij} is R[i, j].
ROTATION_COLUMNS: tuple[str, ...] = tuple(
    f"R_cam_marker_{i}{j}" for i in range(3) for j in range(3)
)
#: The translation of T_cam_marker (mm).
TRANSLATION_COLUMNS: tuple[str, ...] = tuple(f"t_cam_marker_{a}_mm" for a in "xyz")
#: Prefix of the backend's own pose columns (:mod:`pipeline.backends`): ``own_R_cam_marker_{ij}``,
#: ``own_t_cam_marker_{x,y,z}_mm``, read with ``rotations_of(table, prefix=OWN_POSE_PREFIX)``.
OWN_POSE_PREFIX = "own_"
#: The translation of T_marker0_marker (mm): the marker's displacement from its no-contact pose.
DISPLACEMENT_COLUMNS: tuple[str, ...] = tuple(f"t_marker0_marker_{a}_mm" for a in "xyz")

_KEY: Schema = (
    Column("frame", "int64", "", "index of the frame in the video, from 0"),
    Column("marker_id", "int64", "", "ArUco id of the marker"),
)
#: The columns a detections table and a labels table are joined on (``list(JOIN_KEY)``).
JOIN_KEY: tuple[str, ...] = tuple(c.name for c in _KEY)
_WHISKER = Column("whisker", "int64", "", "whisker index in array order, 0 .. n-1")
_CORNERS: Schema = tuple(
    Column(name, "float64", "px", f"corner {k} {axis}, ArUco order")
    for k, pair in enumerate(CORNER_COLUMNS)
    for axis, name in zip("xy", pair, strict=True)
)
_POSE: Schema = tuple(
    Column(name, "float64", "", f"T_cam_marker rotation [{name[-2]}, {name[-1]}]")
    for name in ROTATION_COLUMNS
) + tuple(Column(name, "float64", "mm", "T_cam_marker translation") for name in TRANSLATION_COLUMNS)
#: The backend's own T_cam_marker, a pinhole's (both peers ignore the lens): NaN where none.
_OWN_POSE: Schema = tuple(
    Column(OWN_POSE_PREFIX + c.name, c.dtype, c.unit, f"backend's own {c.doc}; NaN: it has none")
    for c in _POSE
)
_DEFLECTION = Column("deflection_mm", "float64", "mm", "hypot(x, y) of T_marker0_marker (SPEC 3)")
_CONTACT = Column("contact", "bool", "", "the whisker touches something in this frame")

TRACK: Schema = (
    *_KEY,
    _WHISKER,
    *_CORNERS,
    *_POSE,
    Column("reprojection_err_px", "float64", "px", "reprojection error of the chosen pose"),
    Column("ambiguity_ratio", "float64", "", "second-best / best reprojection error; inf: one"),
    *_OWN_POSE,
    Column("refine_failed", "bool", "", "refinement 'lines' kept the backend's corners"),
)
DETECTIONS: Schema = (*TRACK, _DEFLECTION, _CONTACT)
LABELS: Schema = (
    _KEY[0],
    Column("source_frame", "int64", "", "index of the frame at the protocol's full frame rate"),
    Column("time_s", "float64", "s", "time of the frame: the middle of its exposure"),
    _KEY[1],
    _WHISKER,
    *_CORNERS,
    *_POSE,
    *(Column(n, "float64", "mm", "T_marker0_marker translation") for n in DISPLACEMENT_COLUMNS),
    _DEFLECTION,
    Column("theta_h_rad", "float64", "rad", "horizontal deflection angle of the whisker"),
    Column("theta_v_rad", "float64", "rad", "vertical deflection angle of the whisker"),
    _CONTACT,
    Column("branch_contact", "bool", "", "the whisker touches a branch in this frame"),
    Column("visible", "bool", "", "all four corners in the image and the face towards the camera"),
)


def names(schema: Schema) -> list[str]:
    """The column names of ``schema``, in order."""
    return [c.name for c in schema]


def ordered(schema: Schema, values: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """``values`` as 1-D arrays in the schema's order and dtypes, ready for ``pd.DataFrame``.

    A writer that produces a column the schema lacks, or misses one, is a bug: ValueError.
    """
    extra = set(values) - set(names(schema))
    missing = [n for n in names(schema) if n not in values]
    if extra or missing:
        raise ValueError(f"columns not in the schema: {sorted(extra)}; missing: {missing}")
    return {c.name: np.asarray(values[c.name]).ravel().astype(c.dtype) for c in schema}


def corner_values(corners_px: np.ndarray) -> dict[str, np.ndarray]:
    """Corner columns of (..., 4, 2) corners, (x, y) in pixels, flattened over ``...``."""
    corners_px = np.asarray(corners_px, dtype=float)
    return {
        name: corners_px[..., k, i].ravel()
        for k, pair in enumerate(CORNER_COLUMNS)
        for i, name in enumerate(pair)
    }


def pose_values(T_cam_marker: np.ndarray, prefix: str = "") -> dict[str, np.ndarray]:
    """Rotation and translation columns of (..., 4, 4) poses T_cam_marker, flattened;
    ``prefix`` :data:`OWN_POSE_PREFIX` names the backend's own pose columns."""
    T = np.asarray(T_cam_marker, dtype=float)
    rotation = T[..., :3, :3].reshape(-1, 9)
    translation = T[..., :3, 3].reshape(-1, 3)
    return {
        **{prefix + name: rotation[:, k] for k, name in enumerate(ROTATION_COLUMNS)},
        **{prefix + name: translation[:, k] for k, name in enumerate(TRANSLATION_COLUMNS)},
    }


def displacement_values(t_marker0_marker: np.ndarray) -> dict[str, np.ndarray]:
    """Displacement columns of (..., 3) translations of T_marker0_marker (mm), flattened."""
    t = np.asarray(t_marker0_marker, dtype=float).reshape(-1, 3)
    return {name: t[:, k] for k, name in enumerate(DISPLACEMENT_COLUMNS)}


def _named(columns: tuple[str, ...], suffix: str, prefix: str) -> list[str]:
    return [prefix + name + suffix for name in columns]


def corners_of(table: Any, suffix: str = "") -> np.ndarray:
    """(N, 4, 2) corners of a table's rows; ``suffix`` picks the truth side of a join."""
    flat = [name + suffix for pair in CORNER_COLUMNS for name in pair]
    return table[flat].to_numpy(dtype=float).reshape(-1, 4, 2)


def rotations_of(table: Any, suffix: str = "", prefix: str = "") -> np.ndarray:
    """(N, 3, 3) rotations of T_cam_marker of a table's rows (``prefix``: see pose_values)."""
    return table[_named(ROTATION_COLUMNS, suffix, prefix)].to_numpy(float).reshape(-1, 3, 3)


def translations_of(table: Any, suffix: str = "", prefix: str = "") -> np.ndarray:
    """(N, 3) translations of T_cam_marker (mm) of a table's rows (``prefix``: see pose_values)."""
    return table[_named(TRANSLATION_COLUMNS, suffix, prefix)].to_numpy(dtype=float)


def check_table(table: Any, schema: Schema, what: object) -> None:
    """Refuse a table (a pandas DataFrame) that lacks a column of ``schema`` or holds one of
    another kind (integer, float, bool): ValueError naming ``what`` (the file) and the column.

    Columns the schema does not name are ignored. Integer and float widths are not checked
    (a table written by another tool may use int32), the kind is: a text or nullable column
    would fail later, far from its cause.
    """
    for column in schema:
        if column.name not in table.columns:
            raise ValueError(f"{what}: column {column.name!r} is missing")
        dtype = table.dtypes[column.name]
        want = np.dtype(column.dtype)
        if not isinstance(dtype, np.dtype) or dtype.kind not in _KINDS[want.kind]:
            raise ValueError(f"{what}: column {column.name!r} is {dtype}, must be {column.dtype}")


def check_labels(table: Any, frames: int, what: object) -> None:
    """Refuse a labels table (:data:`LABELS`) that is not one row per marker for each of the
    sample's ``frames`` frames, or that marks a marker visible without finite corners:
    ValueError naming ``what`` (the file), the frame and the marker. A frame without rows would
    read as a frame in which no marker is seen, a repeated row would count twice, and a visible
    marker's NaN corner would drop out of the corner error."""
    check_table(table, LABELS, what)
    frame = table["frame"].to_numpy()
    if frames and not len(table):
        raise ValueError(f"{what}: no rows, for a sample of {frames} frames")
    if len(table) and (frame.min() < 0 or frame.max() >= frames):
        raise ValueError(
            f"{what}: frames {frame.min()}..{frame.max()} outside the sample's 0..{frames - 1}"
        )
    missing = np.setdiff1d(np.arange(frames), frame)
    if missing.size:
        raise ValueError(f"{what}: no rows for frame {missing[0]} (of 0..{frames - 1})")
    twice = table.duplicated(list(JOIN_KEY)).to_numpy()
    if twice.any():
        row = table.iloc[int(np.argmax(twice))]
        raise ValueError(f"{what}: frame {row['frame']}, marker {row['marker_id']}: two rows")
    corners = table[[c.name for c in _CORNERS]].to_numpy(dtype=float)
    bad = table["visible"].to_numpy() & ~np.isfinite(corners).all(axis=1)
    if bad.any():
        row = table.iloc[int(np.argmax(bad))]
        raise ValueError(
            f"{what}: frame {row['frame']}, marker {row['marker_id']}: visible, with a corner "
            "that is not a finite number"
        )


#: Accepted dtype kinds per schema kind: any integer width, signed or not; a float column may
#: hold integers (they convert exactly), an integer column no floats.
_KINDS = {"i": "iu", "f": "fiu", "b": "b"}

"""Camera calibrations written by other tools, read as exact :class:`FisheyeCamera` models.

The layouts follow each tool's own reader or writer:

``kalibr``
    camchain YAML (``kalibr_common/ConfigReader.py``): one mapping ``camN`` per camera with
    ``camera_model``, ``intrinsics``, ``distortion_model``, ``distortion_coeffs`` and
    ``resolution: [width, height]``. Read: ``pinhole``-``equidistant`` (``[fu, fv, pu, pv]``,
    ``[k1, k2, k3, k4]``: Kannala-Brandt), ``ds``-``none`` (``[xi, alpha, fu, fv, pu, pv]``),
    ``eucm``-``none`` (``[alpha, beta, fu, fv, pu, pv]``) and ``omni``-``none``
    (``[xi, fu, fv, pu, pv]``: Mei's unified model, ``ucm`` here with the same xi and focal).
``basalt``
    calibration JSON (basalt-headers ``headers_serialization.h``): ``value0.intrinsics[i]`` is
    ``{"camera_type": ..., "intrinsics": {...}}`` and ``value0.resolution[i]`` is
    ``[width, height]``. Read: ``kb4`` (fx, fy, cx, cy, k1..k4), ``ds`` (.., xi, alpha),
    ``eucm`` (.., alpha, beta) and ``ucm`` (.., alpha). Basalt's UCM divides by
    ``alpha |p| + (1 - alpha) z``, Mei's by ``z + xi |p|``; the two agree with
    ``xi = alpha / (1 - alpha)`` and ``f_mei = f_basalt / (1 - alpha) = f_basalt (1 + xi)``.
``ocamcalib``
    ``calib_results.txt`` (OCamCalib's ``export_data.m``, read by ``get_ocam_model`` in
    ``ocam_functions.c``): five data lines after ``#`` comments: the polynomial
    ``N a0 .. a(N-1)``, its approximate inverse ``M b0 .. b(M-1)`` (not used: projection is
    solved exactly), the centre ``row col`` counted from 0, the affine ``c d e``, and
    ``height width``. See :mod:`scenes.camera` for the mapping onto this project's frame.
``opencv``
    an OpenCV fisheye calibration (K, D, size) in JSON or YAML: ``cv2.FileStorage`` files
    (``%YAML:1.0`` with ``!!opencv-matrix``, or its JSON form), ROS ``camera_info`` YAML, or
    plain lists. Keys accepted: the 3x3 matrix as ``K``, ``camera_matrix`` or ``cameraMatrix``;
    the 4 coefficients as ``D``, ``distortion_coefficients``, ``dist_coeffs`` or ``distCoeffs``;
    the size as ``size`` or ``image_size`` ``[width, height]``, or ``image_width`` and
    ``image_height``. A matrix is a nested list, a flat list, or a mapping with ``data``. An
    optional ``distortion_model`` must be ``equidistant``, ``fisheye`` or ``kannala_brandt``.

``theta_max_deg`` (the image-circle limit) defaults to the largest ray angle reaching the image
(at its farthest corner), capped at the model's own valid limit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from scenes.bounded_read import (
    BoundedReadError,
    BoundedSafeLoader,
    BoundedYamlError,
    input_problem,
    parse_json,
    read_bounded_text,
)
from scenes.camera import MIN_THETA_MAX_DEG, FisheyeCamera
from scenes.input_limits import SETTINGS_BYTES, SETTINGS_DEPTH, YAML_NODES

FORMATS = ("kalibr", "basalt", "ocamcalib", "opencv")
#: Largest calibration file read: real ones are a few kB; this bounds memory on a hostile input.
MAX_FILE_BYTES = SETTINGS_BYTES
KALIBR_SUPPORTED = ("pinhole-equidistant", "ds-none", "eucm-none", "omni-none")
BASALT_TYPES = {
    "kb4": ("kannala_brandt", ("k1", "k2", "k3", "k4")),
    "ds": ("double_sphere", ("xi", "alpha")),
    "eucm": ("eucm", ("alpha", "beta")),
    "ucm": ("ucm", ("alpha",)),
}
OPENCV_KEYS = {
    "K": ("K", "camera_matrix", "cameraMatrix"),
    "D": ("D", "distortion_coefficients", "dist_coeffs", "distCoeffs"),
    "size": ("size", "image_size"),
}
OPENCV_FISHEYE_MODELS = ("equidistant", "fisheye", "kannala_brandt")


class CalibrationError(ValueError):
    """A calibration file that cannot be read; names the file and the field."""

    def __init__(self, path: Path | str, field_name: str, message: str) -> None:
        super().__init__(f"{path}: {field_name}: {message}")
        self.path, self.field, self.detail = str(path), field_name, message


#: (model, params, fx, fy, cx, cy, shear, (width, height)) of one calibrated camera
Intrinsics = tuple[
    str, tuple[float, ...], float, float, float, float, tuple[float, float], tuple[int, int]
]


def import_calibration(
    path: str | Path, fmt: str, camera_index: int = 0, theta_max_deg: float | None = None
) -> FisheyeCamera:
    """The camera ``camera_index`` of a calibration file in format ``fmt`` (see module doc)."""
    path = Path(path)
    if fmt not in FORMATS:
        raise CalibrationError(path, "format", f"{fmt!r}: must be one of {', '.join(FORMATS)}")
    if isinstance(camera_index, bool) or not isinstance(camera_index, int) or camera_index < 0:
        raise CalibrationError(path, "camera_index", f"{camera_index!r}: must be an integer >= 0")
    if fmt in ("ocamcalib", "opencv") and camera_index != 0:
        raise CalibrationError(
            path, "camera_index", f"{camera_index}: a {fmt} file holds one camera; use 0"
        )
    text = _read_text(path)
    reader: Callable[[Path, str, int], tuple[str, Intrinsics]] = {
        "kalibr": _kalibr,
        "basalt": _basalt,
        "ocamcalib": _ocamcalib,
        "opencv": _opencv,
    }[fmt]
    field_name, intrinsics = reader(path, text, camera_index)
    return _camera(path, field_name, intrinsics, theta_max_deg)


# --- Common -----------------------------------------------------------------------------------


def _read_text(path: Path) -> str:
    if not path.is_file():
        raise CalibrationError(path, "file", input_problem(path) or "not a readable file")
    try:
        return read_bounded_text(path, MAX_FILE_BYTES)
    except BoundedReadError as exc:
        raise CalibrationError(path, "file", f"cannot be read as UTF-8 text: {exc}") from None


def _json(path: Path, text: str) -> Any:
    try:
        return parse_json(text, SETTINGS_DEPTH)
    except BoundedReadError as exc:
        raise CalibrationError(path, "file", str(exc)) from None


def _numbers(path: Path, field_name: str, value: Any, count: int | None = None) -> list[float]:
    """A list of finite numbers (of length ``count`` when given), else CalibrationError."""
    ok = isinstance(value, list | tuple) and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value
    )
    if not ok or (count is not None and len(value) != count):
        need = f"{count} finite numbers" if count is not None else "a list of finite numbers"
        raise CalibrationError(path, field_name, f"{value!r}: needs {need}")
    return [float(v) for v in value]


def _size(path: Path, field_name: str, value: Any) -> tuple[int, int]:
    ok = isinstance(value, list | tuple) and len(value) == 2
    ok = ok and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value)
    if not ok:
        raise CalibrationError(path, field_name, f"{value!r}: needs [width, height] in pixels")
    return int(value[0]), int(value[1])


def _mapping(path: Path, field_name: str, value: Any) -> dict:
    if not isinstance(value, dict):
        raise CalibrationError(path, field_name, "missing, or not a mapping")
    return value


def _camera(
    path: Path, field_name: str, intrinsics: Intrinsics, theta_max_deg: float | None
) -> FisheyeCamera:
    """The camera, with theta_max given, or defaulted to the farthest image corner's angle."""
    model, params, fx, fy, cx, cy, shear, (width, height) = intrinsics

    def build(theta_deg: float) -> FisheyeCamera:
        return FisheyeCamera(width, height, fx, fy, cx, cy, theta_deg, model, params, shear)

    try:  # the narrowest image circle: the parameters are checked before any limit is computed
        probe = build(MIN_THETA_MAX_DEG)
    except (ValueError, TypeError, IndexError, ZeroDivisionError) as exc:
        raise CalibrationError(path, field_name, str(exc)) from None
    limit_deg = probe.theta_valid_max_deg
    if theta_max_deg is not None:
        ok = isinstance(theta_max_deg, int | float) and MIN_THETA_MAX_DEG <= theta_max_deg < 180
        if not ok or theta_max_deg > limit_deg + 1e-9:
            top = f"{limit_deg:.4f}]" if limit_deg < 180.0 else "180)"
            raise CalibrationError(
                path,
                "theta_max_deg",
                f"{theta_max_deg!r}: the {model} model is valid up to {limit_deg:.4f} deg, and a "
                f"field under {MIN_THETA_MAX_DEG:g} deg off axis is no fisheye's; allowed range is "
                f"[{MIN_THETA_MAX_DEG:g}, {top}",
            )
        return build(float(theta_max_deg))
    corners = np.array(
        [[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5], [width - 0.5, height - 0.5]]
    )
    corner_deg = math.degrees(float(probe.theta_of_pixel(corners).max()))
    if corner_deg >= 180.0:
        raise CalibrationError(
            path, "theta_max_deg", "the image reaches 180 deg from the axis; give theta_max_deg"
        )
    try:  # a field under MIN_THETA_MAX_DEG: a telephoto's focal length, or a wrong one
        return build(min(corner_deg, limit_deg))
    except ValueError as exc:
        raise CalibrationError(path, "theta_max_deg", str(exc)) from None


# --- Kalibr -----------------------------------------------------------------------------------


def _yaml(path: Path, text: str) -> Any:
    try:
        return yaml.load(text, Loader=_OpenCVLoader)  # a SafeLoader: plain data only
    except BoundedYamlError as exc:  # an alias, too many nodes, too deep
        raise CalibrationError(path, "file", f"refused YAML: {exc}") from None
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise CalibrationError(path, "file", f"not valid YAML{line}") from None


def _kalibr(path: Path, text: str, index: int) -> tuple[str, Intrinsics]:
    data = _mapping(path, "file", _yaml(path, text))
    key = f"cam{index}"
    if key not in data:
        cams = sorted(k for k in data if isinstance(k, str) and k.startswith("cam"))
        raise CalibrationError(
            path, "camera_index", f"{index}: no '{key}' in the camchain (has {', '.join(cams)})"
        )
    cam = _mapping(path, key, data[key])
    for name in ("camera_model", "intrinsics", "distortion_model", "resolution"):
        if name not in cam:
            raise CalibrationError(path, f"{key}.{name}", "missing")
    kind = f"{cam['camera_model']}-{cam['distortion_model']}"
    if kind not in KALIBR_SUPPORTED:
        raise CalibrationError(
            path,
            f"{key}.camera_model",
            f"{kind} is not supported; supported: {', '.join(KALIBR_SUPPORTED)}",
        )
    size = _size(path, f"{key}.resolution", cam["resolution"])
    field_name = f"{key}.intrinsics"
    n = {"pinhole": 4, "omni": 5, "ds": 6, "eucm": 6}[cam["camera_model"]]
    values = _numbers(path, field_name, cam["intrinsics"], n)
    coeffs = cam.get("distortion_coeffs", [])
    if kind == "pinhole-equidistant":
        k = _numbers(path, f"{key}.distortion_coeffs", coeffs, 4)
        return field_name, ("kannala_brandt", tuple(k), *values, (0.0, 0.0), size)
    if coeffs not in ([], None):
        raise CalibrationError(path, f"{key}.distortion_coeffs", "must be empty for 'none'")
    model, n_params = {"omni": ("ucm", 1), "ds": ("double_sphere", 2), "eucm": ("eucm", 2)}[
        cam["camera_model"]
    ]
    params, (fx, fy, cx, cy) = tuple(values[:n_params]), values[n_params:]
    return field_name, (model, params, fx, fy, cx, cy, (0.0, 0.0), size)


# --- Basalt -----------------------------------------------------------------------------------


def _basalt(path: Path, text: str, index: int) -> tuple[str, Intrinsics]:
    data = _json(path, text)
    root = _mapping(path, "value0", _mapping(path, "file", data).get("value0"))
    cams, sizes = root.get("intrinsics"), root.get("resolution")
    if not isinstance(cams, list) or not cams:
        raise CalibrationError(path, "value0.intrinsics", "missing, or not a non-empty list")
    if not isinstance(sizes, list) or len(sizes) != len(cams):
        raise CalibrationError(path, "value0.resolution", f"needs {len(cams)} [width, height]")
    if index >= len(cams):
        raise CalibrationError(path, "camera_index", f"{index}: the file has {len(cams)} camera(s)")
    key = f"value0.intrinsics[{index}]"
    cam = _mapping(path, key, cams[index])
    kind = cam.get("camera_type")
    if not isinstance(kind, str) or kind not in BASALT_TYPES:  # a list or object: unhashable
        raise CalibrationError(
            path,
            f"{key}.camera_type",
            f"{kind!r} is not supported; supported: {', '.join(BASALT_TYPES)}",
        )
    model, names = BASALT_TYPES[kind]
    values = _mapping(path, f"{key}.intrinsics", cam.get("intrinsics"))
    missing = [n for n in ("fx", "fy", "cx", "cy", *names) if n not in values]
    if missing:
        raise CalibrationError(path, f"{key}.intrinsics", f"lacks {', '.join(missing)}")
    field_name = f"{key}.intrinsics"
    fx, fy, cx, cy, *params = _numbers(
        path, field_name, [values[n] for n in ("fx", "fy", "cx", "cy", *names)]
    )
    if kind == "ucm":  # Basalt's alpha form to Mei's xi (module doc)
        alpha = params[0]
        if not 0.0 <= alpha < 1.0:
            raise CalibrationError(path, f"{field_name}.alpha", f"{alpha}: allowed range [0, 1)")
        params, fx, fy = [alpha / (1.0 - alpha)], fx / (1.0 - alpha), fy / (1.0 - alpha)
    size = _size(path, f"value0.resolution[{index}]", sizes[index])
    return field_name, (model, tuple(params), fx, fy, cx, cy, (0.0, 0.0), size)


# --- OCamCalib --------------------------------------------------------------------------------

_OCAM_LINES = ("polynomial", "inverse polynomial", "centre", "affine", "image size")


def _ocamcalib(path: Path, text: str, index: int) -> tuple[str, Intrinsics]:
    lines = [
        ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if len(lines) < len(_OCAM_LINES):
        missing = _OCAM_LINES[len(lines)]
        raise CalibrationError(path, missing, f"missing: the file has {len(lines)} data lines")
    rows = []
    for name, tokens in zip(_OCAM_LINES, lines, strict=False):
        try:
            rows.append([float(t) for t in tokens])
        except ValueError:
            raise CalibrationError(path, name, f"{' '.join(tokens)!r}: not numbers") from None
        if not all(math.isfinite(v) for v in rows[-1]):
            raise CalibrationError(path, name, "must be finite numbers")
    for name, row in zip(_OCAM_LINES[:2], rows[:2], strict=False):
        if not row or row[0] != int(row[0]) or int(row[0]) != len(row) - 1 or row[0] < 1:
            raise CalibrationError(path, name, "needs a count N >= 1 followed by N coefficients")
    pol = tuple(rows[0][1:])
    for name, row, n in zip(_OCAM_LINES[2:], rows[2:], (2, 3, 2), strict=False):
        if len(row) != n:
            raise CalibrationError(path, name, f"needs {n} numbers, got {len(row)}")
    (xc, yc), (c, d, e), (height, width) = rows[2], rows[3], rows[4]
    if pol[0] >= 0:
        raise CalibrationError(path, "polynomial", f"a0={pol[0]}: OCamCalib's a0 is negative")
    if c - d * e <= 0:
        raise CalibrationError(path, "affine", f"c - d*e = {c - d * e}: must be > 0")
    size = _size(path, "image size", [_int(width), _int(height)])
    s = -pol[0]  # scale: d(theta) ~ theta near the axis (scenes.camera)
    return "polynomial", ("ocamcalib", pol, s, c * s, yc, xc, (e * s, d * s), size)


def _int(value: float) -> int | float:
    return int(value) if value == int(value) else value


# --- OpenCV -----------------------------------------------------------------------------------


class _OpenCVLoader(BoundedSafeLoader):
    """YAML as cv2.FileStorage writes it: ``!!opencv-matrix`` mappings read as plain mappings;
    no aliases, at most :data:`~scenes.input_limits.YAML_NODES` nodes nested
    :data:`~scenes.input_limits.SETTINGS_DEPTH` deep."""

    max_nodes = YAML_NODES
    max_depth = SETTINGS_DEPTH


_OpenCVLoader.add_constructor(
    "tag:yaml.org,2002:opencv-matrix", lambda loader, node: loader.construct_mapping(node, True)
)


def _matrix(path: Path, field_name: str, value: Any, count: int) -> np.ndarray:
    if isinstance(value, dict):
        value = value.get("data")
    flat = np.asarray(value, dtype=object).ravel().tolist() if isinstance(value, list) else value
    return np.array(_numbers(path, field_name, flat, count))


def _opencv(path: Path, text: str, index: int) -> tuple[str, Intrinsics]:
    if text.lstrip().startswith("{"):
        data = _json(path, text)
    else:  # cv2.FileStorage writes a "%YAML:1.0" directive that YAML 1.1 parsers refuse
        body = "\n".join(ln for ln in text.splitlines() if not ln.startswith("%YAML"))
        data = _yaml(path, body)
    data = _mapping(path, "file", data)
    found = {}
    for name, keys in OPENCV_KEYS.items():
        found[name] = next((k for k in keys if k in data), None)
    if found["size"] is None and {"image_width", "image_height"} <= set(data):
        size = _size(path, "image_width/image_height", [data["image_width"], data["image_height"]])
    elif found["size"] is not None:
        size = _size(path, found["size"], data[found["size"]])
    else:
        raise CalibrationError(path, "size", "missing: give size, image_size or image_width/height")
    for name in ("K", "D"):
        if found[name] is None:
            raise CalibrationError(
                path, name, f"missing: give one of {', '.join(OPENCV_KEYS[name])}"
            )
    kind = data.get("distortion_model", "equidistant")
    if kind not in OPENCV_FISHEYE_MODELS:
        raise CalibrationError(
            path,
            "distortion_model",
            f"{kind!r} is not a fisheye model; supported: {', '.join(OPENCV_FISHEYE_MODELS)}",
        )
    K = _matrix(path, found["K"], data[found["K"]], 9).reshape(3, 3)
    D = _matrix(path, found["D"], data[found["D"]], 4)
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
        raise CalibrationError(
            path, found["K"], f"{K.tolist()}: needs [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]"
        )
    model, params = ("kannala_brandt", tuple(D)) if D.any() else ("equidistant", ())
    return found["K"], (model, params, K[0, 0], K[1, 1], K[0, 2], K[1, 2], (0.0, 0.0), size)

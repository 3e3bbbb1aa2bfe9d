"""The AprilTag 3 backend: the C library bundled by ``apriltag-python`` (PyPI, BSD-2), by ctypes.

The Python module ``apriltag`` knows only AprilTag families, so this adapter drives the library's
C API itself (structs as in AprilTag 3.4.5's ``apriltag.h``, ``apriltag_pose.h``, ``matd.h``,
``zarray.h``, ``image_types.h``). AprilTag families use the library's own (``tagXXhY_create``);
ArUco families get a family built from OpenCV's dictionary (:mod:`pipeline.backends.tag_family`),
so one decoder reads both and the ids are OpenCV's.

Mapping to the project's conventions, checked in ``tests/test_backends.py``:

- corners: the library puts pixel centres at +0.5 (it samples pixel ``i`` at ``i + 0.5``);
  subtract 0.5. Its ``p[0..3]`` are the tag's (-1, +1), (+1, +1), (+1, -1), (-1, -1) in a tag
  frame with +y down its upright tag: bottom-left, bottom-right, top-right, top-left, so ArUco's
  order TL, TR, BR, BL is ``p[3], p[2], p[1], p[0]`` where the library's upright is OpenCV's
  (ArUco families, built so). OpenCV 5.0 draws the AprilTag families a half turn from the
  library's upright (:func:`pipeline.backends.tag_family.opencv_turn` measures it), so their
  order is ``p[1], p[0], p[3], p[2]`` (the Python module's ``lb-rb-rt-lt`` is then TR, TL, BL,
  BR of OpenCV's drawing).
- own pose: ``estimate_tag_pose`` in the units of ``tagsize`` (mm here) of a tag frame with +x
  right, +y down, +z into the printed face of the library's upright tag; the project's marker
  frame has +y up and +z out of the face (a half-turn about x) and is OpenCV's upright (the
  measured turn about z). It reads pixels at +0.5 too, so the principal point goes in shifted
  by 0.5. Pinhole only: on the fisheye its pose is a pinhole's.

Memory safety: the image is handed over as an ``image_u8_t`` over the numpy buffer itself, a
C-contiguous 2-D uint8 array whose stride is its row length, so the library reads exactly the
buffer; with ``QUAD_SIGMA = 0`` and ``QUAD_DECIMATE = 1`` it never writes into it. Images under
8 px a side are not passed (AprilTag 3.4.5 lacks the later upstream check for them). Every C
object a call creates (detections, pose matrices) is freed before it returns.
"""

from __future__ import annotations

from ctypes import (
    CDLL,
    POINTER,
    Structure,
    byref,
    c_bool,
    c_double,
    c_float,
    c_int,
    c_int32,
    c_size_t,
    c_uint,
    c_void_p,
    cast,
    pointer,
)
from functools import cache
from importlib.util import find_spec
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pipeline.backends import Found, PoseRequest, missing_library
from pipeline.backends.tag_family import Family, aruco_family, opencv_turn

if TYPE_CHECKING:
    from pipeline.detect import DetectorConfig

PIXEL_SHIFT = 0.5  # the library's pixel coordinates minus the project's
#: ArUco order (TL, TR, BR, BL) as indices into the library's p[0..3] (BL, BR, TR, TL), for a
#: marker whose upright is the library's.
UPRIGHT_CORNER_ORDER = np.array([3, 2, 1, 0])
#: R_tag_marker for the same: the project's marker frame in the library's tag frame.
UPRIGHT_R_TAG_MARKER = np.diag([1.0, -1.0, -1.0])
#: The library's own families by the project's names.
LIBRARY_FAMILIES = {
    "apriltag_16h5": "tag16h5",
    "apriltag_25h9": "tag25h9",
    "apriltag_36h10": "tag36h10",
    "apriltag_36h11": "tag36h11",
}
#: Detector settings: the library's defaults (apriltag_detector_create) except the decimation,
#: which the Python module also sets to 1 (full-resolution quads, as the other backends search).
#: One thread: the comparison measures single-core speed.
NTHREADS = 1
QUAD_DECIMATE = 1.0
QUAD_SIGMA = 0.0  # no blur; non-zero would also make the library blur the input in place
REFINE_EDGES = True
DECODE_SHARPENING = 0.25
#: Most bit errors the decoder corrects: the library's default, 2, where the family's minimum
#: Hamming distance h (over ids and rotations) keeps corrected codes unique, (h - 1) // 2, else
#: fewer. More would raise false ids on small families and the table grows as nbits^bits.
MAX_BITS_CORRECTED = 2
MIN_SIDE_PX = 8


class _Detector(Structure):
    """The leading fields of apriltag_detector_t (only these are set; the library owns it)."""

    _fields_ = [
        ("nthreads", c_int),
        ("quad_decimate", c_float),
        ("quad_sigma", c_float),
        ("refine_edges", c_bool),
        ("decode_sharpening", c_double),
        ("debug", c_bool),
    ]


class _Detection(Structure):
    """apriltag_detection_t."""

    _fields_ = [
        ("family", POINTER(Family)),
        ("id", c_int),
        ("hamming", c_int),
        ("decision_margin", c_float),
        ("H", c_void_p),
        ("c", c_double * 2),
        ("p", (c_double * 2) * 4),
    ]


class _Zarray(Structure):
    """zarray_t: here always of apriltag_detection_t pointers."""

    _fields_ = [("el_sz", c_size_t), ("size", c_int), ("alloc", c_int), ("data", c_void_p)]


class _ImageU8(Structure):
    """image_u8_t: buf[y * stride + x]."""

    _fields_ = [("width", c_int32), ("height", c_int32), ("stride", c_int32), ("buf", c_void_p)]


class _Matd(Structure):
    """matd_t: row-major doubles."""

    _fields_ = [("nrows", c_uint), ("ncols", c_uint), ("data", POINTER(c_double))]


class _DetectionInfo(Structure):
    """apriltag_detection_info_t: tagsize in the unit the pose comes back in."""

    _fields_ = [("det", POINTER(_Detection))] + [
        (name, c_double) for name in ("tagsize", "fx", "fy", "cx", "cy")
    ]


class _Pose(Structure):
    """apriltag_pose_t: R (3x3) and t (3x1), owned by the caller."""

    _fields_ = [("R", POINTER(_Matd)), ("t", POINTER(_Matd))]


#: The functions used: name -> (restype, argtypes).
PROTOTYPES = {
    "apriltag_detector_create": (POINTER(_Detector), []),
    "apriltag_detector_add_family_bits": (None, [POINTER(_Detector), POINTER(Family), c_int]),
    "apriltag_detector_detect": (POINTER(_Zarray), [POINTER(_Detector), POINTER(_ImageU8)]),
    "apriltag_detections_destroy": (None, [POINTER(_Zarray)]),
    "estimate_tag_pose": (c_double, [POINTER(_DetectionInfo), POINTER(_Pose)]),
    "matd_destroy": (None, [POINTER(_Matd)]),
} | {f"{name}_create": (POINTER(Family), []) for name in LIBRARY_FAMILIES.values()}


@cache
def load() -> CDLL:
    """The AprilTag 3 library with its prototypes declared, or BackendUnavailableError."""
    spec = find_spec("apriltag")  # the package, without importing its extension module
    path = None if spec is None else Path(spec.origin).with_name("libapriltag.so.3")
    if path is None or not path.is_file():
        raise missing_library("apriltag", "apriltag-python")
    lib = CDLL(str(path))
    for name, (restype, argtypes) in PROTOTYPES.items():
        getattr(lib, name).restype = restype
        getattr(lib, name).argtypes = argtypes
    return lib


class _Family(NamedTuple):
    """A family the detector decodes and how OpenCV's drawing of it maps to the library's."""

    struct: POINTER(Family)  # kept for the process's life: the detector points into it
    corner_order: np.ndarray  # (4,) ArUco order of OpenCV's drawing as indices into p[0..3]
    R_tag_marker: np.ndarray  # (3, 3) the project's marker frame in the library's tag frame


@cache
def _family(family: str) -> _Family:
    """The family struct for ``family`` and the mapping of its corners and pose."""
    if family in LIBRARY_FAMILIES:
        struct = getattr(load(), f"{LIBRARY_FAMILIES[family]}_create")()
        turn = opencv_turn(family, struct)  # np.rot90(OpenCV's drawing, turn) is the library's
    else:
        struct, turn = aruco_family(family), 0
    c, s = np.cos(turn * np.pi / 2), np.sin(turn * np.pi / 2)
    R_upright_marker = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).round()
    return _Family(
        struct, np.roll(UPRIGHT_CORNER_ORDER, turn), UPRIGHT_R_TAG_MARKER @ R_upright_marker
    )


@cache
def _detector(family: str) -> POINTER(_Detector):
    """One detector per family and process, with this module's settings."""
    lib = load()
    detector = lib.apriltag_detector_create()
    settings = detector.contents
    settings.nthreads = NTHREADS
    settings.quad_decimate = QUAD_DECIMATE
    settings.quad_sigma = QUAD_SIGMA
    settings.refine_edges = REFINE_EDGES
    settings.decode_sharpening = DECODE_SHARPENING
    struct = _family(family).struct
    bits = min(MAX_BITS_CORRECTED, max(0, (int(struct.contents.h) - 1) // 2))
    lib.apriltag_detector_add_family_bits(detector, struct, bits)
    return detector


def detect(
    image: np.ndarray, config: DetectorConfig, frame_side_px: int, pose: PoseRequest | None
) -> Found:
    """The library's ids and corners (and own poses when ``pose`` asks) in the project's
    conventions; size limits are applied by :func:`pipeline.detect.detect_markers`."""
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"need an 8-bit grey image, got {image.dtype} of shape {image.shape}")
    if min(image.shape) < MIN_SIDE_PX:
        return Found(np.zeros(0, int), np.zeros((0, 4, 2)))
    image = np.ascontiguousarray(image)  # stride = row length: the library reads this buffer
    height, width = image.shape
    c_image = _ImageU8(width, height, width, image.ctypes.data)
    lib, family = load(), _family(config.dictionary)
    detections = lib.apriltag_detector_detect(_detector(config.dictionary), byref(c_image))
    try:
        array = detections.contents
        pointers = cast(array.data, POINTER(POINTER(_Detection)))
        items = [pointers[k].contents for k in range(array.size)]
        ids = np.array([d.id for d in items], dtype=int).reshape(-1)
        p = np.array([np.ctypeslib.as_array(d.p) for d in items]).reshape(-1, 4, 2)
        own = None
        if pose is not None and items:
            own = np.array([_pose(lib, d, pose, family.R_tag_marker) for d in items])
    finally:
        lib.apriltag_detections_destroy(detections)
    return Found(ids, p[:, family.corner_order] - PIXEL_SHIFT, own)


def _pose(lib: CDLL, detection, pose: PoseRequest, R_tag_marker: np.ndarray) -> np.ndarray:
    """T_cam_marker (4, 4), mm, from the library's estimate_tag_pose for one detection."""
    info = _DetectionInfo(
        pointer(detection), pose.size_mm, pose.fx_px, pose.fy_px, pose.cx_px + PIXEL_SHIFT,
        pose.cy_px + PIXEL_SHIFT,
    )  # fmt: skip
    result = _Pose()
    lib.estimate_tag_pose(byref(info), byref(result))
    try:
        R_cam_tag = np.ctypeslib.as_array(result.R.contents.data, (3, 3)).copy()
        t_cam_tag = np.ctypeslib.as_array(result.t.contents.data, (3,)).copy()
    finally:
        lib.matd_destroy(result.R)
        lib.matd_destroy(result.t)
    T = np.eye(4)
    T[:3, :3] = R_cam_tag @ R_tag_marker
    T[:3, 3] = t_cam_tag
    return T

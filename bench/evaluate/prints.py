"""Synthetic printed markers with known corners, and how far each detector's corners lie from
them: the references of the real-photograph consensus (:mod:`bench.evaluate.photos`) measured
where the truth is known.

The set (:func:`prints`) is ray cast exactly by :mod:`renderers.printed` through a plain camera:
a 4x4 marker (a family that OpenCV, locus and AprilTag all decode) at 100-240 px ("large") and
20-40 px ("small") a side, three poses each, photographed with the effects of :data:`FAMILIES`:
blur before the transfer curve (the lens, as in the camera twin) or after it (resampling,
sharpening, JPEG, as in most photographs handed over). :func:`one_module_quiet_zone` darkens
everything beyond one module outside the marker, as on the tags on cubes of the real set.
``tests/test_refine_real.py`` checks ``lines`` on it; :func:`offsets` measures every method's
corners on it against the truth (``python -m bench.benchmarks.refine_truth`` prints them).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from bench.evaluate.photos import REFERENCES, agreeing, detector_corners, match, outward
from pipeline.refine import refine_corners_by_edges
from renderers.printed import Photo, gradient, marker_albedo_image, photograph
from scenes.camera import FisheyeCamera
from scenes.conventions import make_T, rot_x, rot_y
from scenes.marker import MarkerSpec
from scenes.study import facing_rotation

CAMERA = FisheyeCamera(
    width_px=640, height_px=480, fx_px=500.0, fy_px=500.0, cx_px=319.5, cy_px=239.5
)
SPEC = MarkerSpec("4x4_50", 7, 50.0)
MODULES = 6  # across the black square of a 4x4 marker
SIDES_PX = {"large": (100, 170, 240), "small": (20, 30, 40)}
#: (x, y) of the marker as fractions of its distance, tilts about y and x (deg)
POSES = ((0.1, 0.05, 0.0, 0.0), (-0.15, 0.1, 25.0, 10.0), (0.05, -0.1, -15.0, 35.0))
#: Blur before the transfer curve, as the camera twin makes it: (photograph, light gradient)
BEFORE_CURVE = {
    "optics": (Photo(optics_sigma_px=1.0), None),
    "uneven": (Photo(optics_sigma_px=1.0), (0.3, 1.0)),
    "twin": (Photo(optics_sigma_px=1.2, full_well_e=6457, read_noise_e=2, jpeg_quality=80), None),
}
#: Blur after it, as cameras' processing adds
AFTER_CURVE = {
    "blur": (Photo(encoded_sigma_px=1.5), None),
    "sharpen": (Photo(encoded_sigma_px=1.2, sharpen_amount=1.0, sharpen_sigma_px=1.5), None),
    "jpeg": (Photo(encoded_sigma_px=1.0, jpeg_quality=75), (0.35, 1.0)),
}
FAMILIES = {**BEFORE_CURVE, **AFTER_CURVE}


def pose(side_px: float, k: int) -> np.ndarray:
    """T_cam_marker of pose ``k`` with the marker ``side_px`` a side (about)."""
    x, y, tilt_y, tilt_x = POSES[k]
    z = CAMERA.fx_px * SPEC.size_mm / side_px
    position = np.array([x * z, y * z, z])
    c, s = math.cos(0.3 * k + 0.2), math.sin(0.3 * k + 0.2)  # turned in the marker's plane
    R = facing_rotation(position) @ rot_y(math.radians(tilt_y)) @ rot_x(math.radians(tilt_x))
    return make_T(R @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), position)


def prints(size: str) -> list[tuple[np.ndarray, tuple[int, int], np.ndarray]]:
    """The albedo crops of one size class: (albedo, offset, true corners) each."""
    return [
        marker_albedo_image(
            CAMERA, pose(side, k), SPEC, int(0.6 * side) + 12, 4 if side > 60 else 8, k
        )
        for side in SIDES_PX[size]
        for k in range(len(POSES))
    ]


def one_module_quiet_zone(
    albedo: np.ndarray, offset, truth: np.ndarray, level: float = 0.15
) -> np.ndarray:
    """The albedo with everything beyond one module outside the marker at ``level`` of white: a
    quiet zone one module wide, as on the tags on cubes of tests/data/real_markers (the ring's
    outer edge is placed through the homography of the true corners, to a fraction of a px)."""
    square = np.array([[0, 0], [MODULES, 0], [MODULES, MODULES], [0, MODULES]], np.float32)
    H = cv2.getPerspectiveTransform((truth - np.asarray(offset)).astype(np.float32), square)
    h, w = albedo.shape
    pixels = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).astype(np.float32)
    uv = cv2.perspectiveTransform(pixels.reshape(-1, 1, 2), H).reshape(h, w, 2)
    beyond = (uv < -1.0).any(axis=-1) | (uv > MODULES + 1.0).any(axis=-1)
    return np.where(beyond, level * albedo.max(), albedo).astype(albedo.dtype)


def image_of(i: int, albedo: np.ndarray, photo: Photo, light) -> np.ndarray:
    """The 8-bit photograph of print ``i`` (its light gradient and noise seeded by ``i``)."""
    illumination = None if light is None else gradient(albedo.shape, *light, 35.0 + 40 * i)
    return photograph(albedo, photo, illumination, np.random.default_rng(i))


#: The methods :func:`offsets` measures: each reference detector's own corners (OpenCV's
#: sub-pixel ones), their consensus as the real set's is formed, and ``lines`` from OpenCV's
#: unrefined corners (as the pipelines run it).
METHODS = (*REFERENCES, "consensus", "lines")


class Offsets(NamedTuple):
    """One method on one kind of print: markers found, their corners' mean signed outward
    offset from the truth and the median corner error (px)."""

    found: int
    outward_px: float
    median_px: float


def offsets(
    photo: Photo, light, size: str, narrow: bool = False, methods=METHODS
) -> dict[str, Offsets]:
    """Each method's corners on the prints of ``size`` photographed as ``photo`` (and ``light``),
    against the truth; ``narrow``: with a one-module quiet zone. A method that finds no marker
    of a print (or, for ``lines``, falls back) leaves it out."""
    measured: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {m: [] for m in methods}
    for i, (albedo, offset, truth) in enumerate(prints(size)):
        if narrow:
            albedo = one_module_quiet_zone(albedo, offset, truth)
        image = image_of(i, albedo, photo, light)
        local = truth - np.asarray(offset)  # the detectors see the crop
        corners = {}
        for name in REFERENCES:
            refinement = "subpix" if name == "opencv" else "none"
            found = detector_corners(image, SPEC.dictionary, name, refinement)
            c = match(found, SPEC.marker_id, local)
            if c is not None:
                corners[name] = c
        group = agreeing(corners)
        if group:
            corners["consensus"] = np.mean([corners[r] for r in group], axis=0)
        if "lines" in methods:
            raw = match(
                detector_corners(image, SPEC.dictionary, "opencv", "none"), SPEC.marker_id, local
            )
            if raw is not None:
                refined, failure = refine_corners_by_edges(
                    image, raw + offset, CAMERA, MODULES, offset
                )
                if failure is None:
                    corners["lines"] = refined - offset
        for m in methods:
            if m in corners:
                c = corners[m]
                measured[m].append((outward(c, local), np.linalg.norm(c - local, axis=1)))
    return {
        m: Offsets(
            len(pairs),
            float(np.mean([o for o, _ in pairs])) if pairs else float("nan"),
            float(np.median([e for _, e in pairs])) if pairs else float("nan"),
        )
        for m, pairs in measured.items()
    }

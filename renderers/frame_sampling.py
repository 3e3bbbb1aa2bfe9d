"""Where and how finely a sample's frames are rendered: plain numbers, no Mitsuba.

:class:`FrameSampling` (samples per pixel on and off the markers, subframes per exposure) and
:func:`marker_region` (the rows and box every marker pixel can reach) decide a dataset's cost
and are validated with its config, before any renderer is loaded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from renderers.window import Window
from scenes.array import ArraySpec, T_cam_marker, T_cam_whisker
from scenes.camera import FisheyeCamera
from scenes.conventions import marker_corners_marker
from scenes.validation import FieldError

#: Light transport of a frame (:class:`renderers.frames.FrameRenderer`): direct light only, or
#: paths with ``path_depth`` indirect bounces.
INTEGRATORS = ("direct", "path")
MAX_PATH_DEPTH = 8


@dataclass(frozen=True)
class FrameSampling:
    """How many samples where, over how much time, and which light paths.

    ``integrator``: ``"direct"`` (sun and unoccluded sky at the first hit) or ``"path"`` (sun
    at every vertex of ``path_depth`` cosine-sampled bounces, the sky occluded along them, the
    unoccluded sky at the last); see :mod:`renderers.frames`. ``path_depth`` is used only by
    ``"path"``. ``adaptive``: every pixel's first sample, then its others only near an edge
    (:mod:`renderers.frame_passes`); False renders every sample of every pixel.
    """

    marker_spp: int = 4
    background_spp: int = 1
    subframes: int = 4
    full_frame: bool = False
    margin_px: int = 16  # > half the detector's largest threshold window (23 px)
    integrator: str = "direct"
    path_depth: int = 3
    adaptive: bool = False

    def __post_init__(self) -> None:
        for name in ("marker_spp", "background_spp", "subframes"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise FieldError(name, f"{getattr(self, name)!r}: must be an integer >= 1")
        if not isinstance(self.adaptive, bool):
            raise FieldError("adaptive", f"{self.adaptive!r}: must be true or false")
        if self.margin_px < 0:
            raise FieldError("margin_px", f"{self.margin_px}: must be >= 0")
        check_light_paths(self.integrator, self.path_depth)


def check_light_paths(integrator: str, path_depth: int) -> None:
    """FieldError unless ``integrator`` is one of :data:`INTEGRATORS` and ``path_depth`` an
    integer 1..:data:`MAX_PATH_DEPTH` (both renderers take these two)."""
    if integrator not in INTEGRATORS:
        raise FieldError("integrator", f"{integrator!r}: choose from {INTEGRATORS}")
    if type(path_depth) is not int or not 1 <= path_depth <= MAX_PATH_DEPTH:  # bool is no depth
        raise FieldError("path_depth", f"{path_depth!r}: must be an integer 1..{MAX_PATH_DEPTH}")


def marker_region(
    camera: FisheyeCamera,
    spec: ArraySpec,
    margin_px: int,
    angles_rad: np.ndarray | None = None,
    block_px: int = 1,
) -> tuple[Window, Window]:
    """(band, zone): the full-width rows and the box that every marker pixel lies in.

    With ``angles_rad`` (..., n, 2), the deflections a sample will show, the box holds the
    markers' carriers at all of them; without, any deflection at all (a marker corner stays
    within ``marker_offset_mm + carrier half-diagonal`` of its coupling: the projections of those
    spheres, sampled densely). ``margin_px`` adds room for the detector's threshold windows.
    Both boxes are then grown to whole ``block_px`` blocks of the full frame (clipped to it).
    """
    if angles_rad is None:
        half_diag = math.sqrt(2) * spec.marker_spec(spec.marker_ids[0]).carrier_half_mm
        radius = spec.marker_offset_mm + half_diag + 1.0
        polar = np.linspace(0, math.pi, 25)
        azimuth = np.linspace(0, 2 * math.pi, 48, endpoint=False)
        p, a = np.meshgrid(polar, azimuth)
        sphere = radius * np.stack(
            [np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1
        ).reshape(-1, 3)
        centres = T_cam_whisker(spec)[:, :3, 3]
        points = (centres[:, None, :] + sphere[None]).reshape(-1, 3)
    else:
        carrier_mm = 2 * spec.marker_spec(spec.marker_ids[0]).carrier_half_mm
        corners = marker_corners_marker(carrier_mm)
        T = T_cam_marker(spec, np.asarray(angles_rad, dtype=float).reshape(-1, spec.n_whiskers, 2))
        points = np.einsum("...ij,kj->...ki", T[..., :3, :3], corners) + T[..., None, :3, 3]
        points = points.reshape(-1, 3)
    px = camera.project(points)
    if np.isnan(px).any():
        raise ValueError("a marker can leave the image circle: the array does not fit this camera")
    lo = np.floor(px.min(axis=0)).astype(int) - margin_px
    hi = np.ceil(px.max(axis=0)).astype(int) + margin_px
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [camera.width_px - 1, camera.height_px - 1])
    band = Window(0, int(lo[1]), camera.width_px, int(hi[1] - lo[1] + 1))
    zone = Window(int(lo[0]), int(lo[1]), int(hi[0] - lo[0] + 1), band.height)
    return band.aligned(block_px, camera), zone.aligned(block_px, camera)

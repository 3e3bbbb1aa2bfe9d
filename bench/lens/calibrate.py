"""What the camera's own processing does to a measured edge, found by running the twin.

A colour sensor's demosaicing, sharpening and MJPEG change an edge's fitted width on top of the
lens's PSF (bilinear demosaicing alone adds about 0.3 px^2 of variance, as much as a 0.55 px
Gaussian), and the twin applies those stages again after its PSF stage. So the PSF the twin needs
is the one that, through the profile's own downstream stages, gives the width seen in the
footage. This module renders sharp markers, blurs them with the twin's PSF stage at a ladder of
isotropic widths, passes them through the profile's sensor, processing and stream stages (noise
off), fits them as footage is fitted, and so maps lens variance to measured variance; the map is
inverted edge by edge. Stages that depend on the field (lateral colour) are not in the map.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import cv2
import numpy as np

from bench.lens.edges import PIXEL_VARIANCE_PX2, black_cells, edge_samples, fit_edges
from pipeline.detect import DetectorConfig, detect_markers
from renderers.camera_twin import STAGES, optical_image, sensor_images
from scenes.profile import CameraProfile, PsfTable

#: Isotropic PSF widths (px) at which the processing is probed: the range real lenses span.
LEVELS_PX = (0.0, 0.3, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)
MODULE_PX = 20  # room for wide levels: the fit's band needs 3 s <= one module
CELL_PX = 192  # one marker per cell of the probe sheet (a 120-px marker turned 45 deg: 170 px)
SHEET_PX = 576
SUPERSAMPLE = 4
MIN_EDGES_PER_LEVEL = 6


def needs_calibration(profile: CameraProfile) -> bool:
    """Whether the profile has a stage after the PSF that changes an edge's width."""
    return (
        profile.sensor.cfa != "none"
        or profile.processing.sharpen_amount > 0
        or profile.stream.codec != "none"
    )


def marker_sheet(
    shape: tuple[int, int],
    placements: Sequence[tuple[tuple[float, float], float, int]],
    side_px: float,
    levels: tuple[float, float],
    dictionary: str = "4x4_50",
    blur: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Linear radiance (H, W) float32: a sheet at ``levels[1]`` with markers printed at
    ``levels[0]``, each area-sampled from a SUPERSAMPLE x finer grid.

    ``placements``: (centre (x, y) px, rotation deg, marker id) per marker; the caller keeps
    them apart. ``blur(centre)`` may return a kernel at the fine scale, applied to that marker's
    patch before area sampling (a PSF constant over the marker).
    """
    black, white = levels
    image = np.full(shape, white, np.float32)
    for centre, rotation_deg, marker_id in placements:
        cells = black_cells(dictionary, marker_id)
        modules = cells.shape[0]
        kernel = blur(np.asarray(centre, float)) if blur is not None else None
        reach = 0 if kernel is None else kernel.shape[0] // (2 * SUPERSAMPLE)
        half = math.ceil(side_px / math.sqrt(2.0) + reach + 2)
        x0, y0 = (round(c) - half for c in centre)
        size = 2 * half + 1
        if x0 < 0 or y0 < 0 or x0 + size > shape[1] or y0 + size > shape[0]:
            raise ValueError(f"marker at {tuple(centre)} leaves the {shape[1]} x {shape[0]} sheet")
        fine = (np.arange(size * SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5  # fine pixel centres
        dx, dy = np.meshgrid(x0 + fine - centre[0], y0 + fine - centre[1])
        c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
        u = (c * dx + s * dy) / (side_px / modules) + modules / 2
        v = (-s * dx + c * dy) / (side_px / modules) + modules / 2
        inside = (u >= 0) & (u < modules) & (v >= 0) & (v < modules)
        dark = np.zeros(u.shape, bool)
        dark[inside] = cells[v[inside].astype(int), u[inside].astype(int)]
        patch = np.where(dark, black, white).astype(np.float32)
        if kernel is not None:
            patch = cv2.filter2D(patch, -1, kernel, borderType=cv2.BORDER_REPLICATE)
        image[y0 : y0 + size, x0 : x0 + size] = cv2.resize(
            patch, (size, size), interpolation=cv2.INTER_AREA
        )
    return image


def processing_curve(
    profile: CameraProfile, dictionary: str, levels: tuple[float, float], lut: np.ndarray
) -> dict:
    """Measured edge variance (px^2, pixel aperture removed) against the lens's isotropic PSF
    variance, through the profile's stages after the PSF; ``levels`` (black, white) in linear
    light as in the footage, ``lut`` the footage's code -> linear table."""
    lens = profile.lens
    size = min(SHEET_PX, lens.width_px, lens.height_px) // 16 * 16  # on every MJPEG block grid
    per_side = max(1, size // CELL_PX)
    modules = black_cells(dictionary, 0).shape[0]
    placements = [
        (
            ((i + 0.5) * size / per_side, (j + 0.5) * size / per_side),
            7.0 + 83.0 * k / per_side**2,
            k,
        )
        for k, (i, j) in enumerate((i, j) for j in range(per_side) for i in range(per_side))
    ]
    sheet = marker_sheet((size, size), placements, MODULE_PX * modules, levels, dictionary)
    radiance = np.repeat(sheet[..., None], 3, axis=-1)
    downstream = [s for s in STAGES if s != "noise"]
    detector = DetectorConfig(dictionary=dictionary)
    lens_var, measured, edges = [], [], []
    for sigma in LEVELS_PX:
        twin = dataclasses.replace(profile, psf=PsfTable((0.0,), (sigma,), (sigma,)))
        irradiance = optical_image(radiance, twin, stages=["psf"])
        grey = sensor_images(irradiance, twin, np.random.default_rng(0), stages=downstream)[0]
        linear = lut[grey]
        samples = [
            e
            for d in detect_markers(grey, detector)
            for e in edge_samples(linear, grey, d.corners_px, dictionary, d.marker_id)
        ]
        s = np.array([r["s_px"] for r in fit_edges(samples) if r["status"] == "ok"])
        if s.size >= MIN_EDGES_PER_LEVEL:
            lens_var.append(sigma**2)
            measured.append(float(np.mean(s**2 - PIXEL_VARIANCE_PX2)))
            edges.append(int(s.size))
    curve = {
        "lens_variance_px2": lens_var,
        "measured_variance_px2": measured,
        "edges": edges,
        "stages": {
            "cfa": profile.sensor.cfa,
            "demosaic": profile.processing.demosaic,
            "sharpen_amount": profile.processing.sharpen_amount,
            "stream": dataclasses.asdict(profile.stream),
        },
    }
    if len(measured) < 2 or np.any(np.diff(measured) <= 0):
        curve["note"] = "not usable: fewer than 2 probed widths, or not increasing; uncorrected"
    return curve


def lens_variance(measured_px2: np.ndarray, curve: dict) -> np.ndarray:
    """The lens variance behind each measured edge variance: the curve inverted, extended
    linearly beyond the probed widths; unchanged if the curve is not usable."""
    x, y = np.asarray(curve["measured_variance_px2"]), np.asarray(curve["lens_variance_px2"])
    measured = np.asarray(measured_px2, dtype=float)
    if "note" in curve:
        return measured
    out = np.interp(measured, x, y)
    low, high = measured < x[0], measured > x[-1]
    out[low] = y[0] + (measured[low] - x[0]) * (y[1] - y[0]) / (x[1] - x[0])
    out[high] = y[-1] + (measured[high] - x[-1]) * (y[-1] - y[-2]) / (x[-1] - x[-2])
    return out

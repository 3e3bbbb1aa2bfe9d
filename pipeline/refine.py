"""Sub-pixel ArUco corners from the marker's straight border edges, through an exact fisheye.

OpenCV's corner refinements are biased on the outer, L-shaped corners of a marker: on
noise-free anti-aliased renders ``CORNER_REFINE_SUBPIX`` (cornerSubPix) puts them 0.35-0.5 px
inside the true corner at every window size, ``CONTOUR`` and ``APRILTAG`` 0.5-1 px. A corner is
where two straight edges meet, so it is found here from the edges instead:

1. **Virtual view.** The approximate corners are unprojected to rays and a virtual pinhole
   camera is aimed at the marker (:func:`pipeline.pose.virtual_view_rotation` of the sum of the
   rays). The marker's border edges, curved in the fisheye image, are exactly straight there.
   Its focal length is scaled so that the marker's perimeter is as long in virtual pixels as
   in image pixels, so one virtual pixel is about one image pixel.
2. **Edge points.** Along the middle 15%-85% of each of the 4 outer edges, intensity profiles
   are taken along the edge normal, from 0.6 module inside (the black border is one module
   wide; the code bits beyond it may be white) to 1 module outside (the white quiet zone).
   Every profile sample is mapped virtual pixel -> ray -> fisheye pixel and read from the image
   with one bilinear ``cv2.remap`` (the view is rectified only where it is sampled). The edge
   lies where a profile crosses halfway between the edge's black level (median of the inner
   samples) and white level (median of the outer samples), interpolated linearly between
   samples: for any point-symmetric blur (the pixel's area, bilinear sampling, a lens) the
   halfway crossing of a straight step edge is the edge itself.
3. **Lines and corners.** A straight line is fitted to each edge's points (total least
   squares, dropping outliers beyond 3 robust sigmas), adjacent lines are intersected, and the
   4 corners are mapped back to fisheye pixels. Two passes: the second samples around the first
   pass's corners.

Intensities are linearized first (``transfer="srgb"``, the camera response's default transfer
curve): the halfway crossing is only unbiased in linear light; in sRGB codes it would sit about
0.2 of the edge's blur width towards the black side.

If refinement fails (too little contrast, an edge with too few consistent points, nearly
parallel lines, a corner outside the image circle, or a corner moving more than
``max_shift_px`` from where it started) the input corners are returned unchanged; it never
raises for a bad image.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipeline.pose import virtual_view_rotation
from scenes.camera import FisheyeCamera

TRANSFERS = ("srgb", "linear")
EDGE_SPAN = (0.15, 0.85)  # the part of each edge sampled, as fractions of its length
INNER_MODULES = 0.6  # profile depth inside the black border, in modules
OUTER_MODULES = 1.0  # profile length into the white quiet zone, in modules
STEP_PX = 0.25  # profile sample spacing (virtual pixels, about image pixels)
ALONG_STEP_PX = 0.5  # spacing of the profiles along the edge
MIN_PROFILES = 6
MIN_INLIER_FRACTION = 0.6
MIN_CONTRAST = 0.2  # (white - black) / white, in linear light
PASSES = 2


def _srgb_to_linear_lut() -> np.ndarray:
    c = np.arange(256, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return lin.astype(np.float32)


_LUTS = {"srgb": _srgb_to_linear_lut(), "linear": np.arange(256, dtype=np.float32) / 255.0}


class _RefineError(Exception):
    """Internal: refinement failed; the caller keeps the input corners."""


def _to_virtual(
    pixels: np.ndarray, camera: FisheyeCamera, R_virt_cam: np.ndarray, f_v: float
) -> np.ndarray:
    rays, valid = camera.unproject(pixels)
    if not valid.all():
        raise _RefineError("a corner lies outside the image circle")
    q = rays @ R_virt_cam.T
    if np.any(q[..., 2] <= 1e-6):
        raise _RefineError("a corner lies behind the virtual view")
    return f_v * q[..., :2] / q[..., 2:]


def _to_fisheye(
    virt: np.ndarray, camera: FisheyeCamera, R_virt_cam: np.ndarray, f_v: float
) -> np.ndarray:
    """Virtual pixels (..., 2) -> full-image fisheye pixels (..., 2); NaN outside the circle."""
    rays_virt = np.concatenate([virt / f_v, np.ones(virt.shape[:-1] + (1,))], axis=-1)
    return camera.project(rays_virt @ R_virt_cam)


def _fit_line(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Total-least-squares line n . x = d through (m, 2) points; also the residuals."""
    centre = points.mean(axis=0)
    centred = points - centre
    _, vecs = np.linalg.eigh(centred.T @ centred)
    normal = vecs[:, 0]
    return normal, float(normal @ centre), centred @ normal


def _edge_lines(
    image: np.ndarray, x0: int, y0: int, corners_v: np.ndarray, modules: int,
    camera: FisheyeCamera, R_virt_cam: np.ndarray, f_v: float, lut: np.ndarray,
) -> list[tuple[np.ndarray, float]]:
    """One sub-pixel line (normal, d) per outer edge, in virtual pixels."""
    starts, ends = corners_v, np.roll(corners_v, -1, axis=0)
    vec = ends - starts
    length = np.linalg.norm(vec, axis=1)
    if np.any(length < 3.0):
        raise _RefineError("marker too small")
    module = length.mean() / modules
    along = vec / length[:, None]
    normal = np.stack([along[:, 1], -along[:, 0]], axis=1)
    centre = corners_v.mean(axis=0)
    outward = np.sign(np.einsum("ij,ij->i", normal, 0.5 * (starts + ends) - centre))
    normal *= outward[:, None]

    n_along = int(np.clip(np.round((EDGE_SPAN[1] - EDGE_SPAN[0]) * length.max() / ALONG_STEP_PX),
                          MIN_PROFILES, 64))
    t = np.linspace(EDGE_SPAN[0], EDGE_SPAN[1], n_along)
    inner, outer = INNER_MODULES * module, OUTER_MODULES * module
    s = np.arange(-np.ceil(inner / STEP_PX), np.ceil(outer / STEP_PX) + 1) * STEP_PX
    s = s[(s >= -inner - 1e-9)]
    # (4 edges, n_along, n_s, 2) sample positions in the virtual view, then in the fisheye
    base = starts[:, None, :] + t[None, :, None] * vec[:, None, :]
    virt = base[:, :, None, :] + s[None, None, :, None] * normal[:, None, None, :]
    fish = _to_fisheye(virt, camera, R_virt_cam, f_v)
    if np.isnan(fish).any():
        raise _RefineError("edge samples outside the image circle")
    fish -= (x0, y0)
    lo = np.floor(fish.reshape(-1, 2).min(axis=0)).astype(int) - 1
    hi = np.ceil(fish.reshape(-1, 2).max(axis=0)).astype(int) + 2
    if np.any(lo < 0) or hi[0] > image.shape[1] or hi[1] > image.shape[0]:
        raise _RefineError("edge samples leave the image")
    patch = lut[image[lo[1]:hi[1], lo[0]:hi[0]]]
    maps = (fish - lo).astype(np.float32)
    flat = maps.reshape(-1, maps.shape[2], 2)
    values = cv2.remap(patch, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).reshape(4, n_along, len(s))

    inner_cols = s <= -0.5 * inner
    outer_cols = s >= 0.5 * outer
    black = np.median(values[:, :, inner_cols].reshape(4, -1), axis=1)
    white = np.median(values[:, :, outer_cols].reshape(4, -1), axis=1)
    if np.any(white - black < MIN_CONTRAST * np.maximum(white, 1e-6)):
        raise _RefineError("too little contrast across an edge")
    v = (values - black[:, None, None]) / (white - black)[:, None, None]
    # the halfway crossing (rising, inside -> outside) nearest the current edge estimate
    rising = (v[..., :-1] < 0.5) & (v[..., 1:] >= 0.5)
    dist = np.where(rising, np.abs(s[:-1] + 0.5 * STEP_PX), np.inf)
    j = np.argmin(dist, axis=2)
    found = np.isfinite(np.take_along_axis(dist, j[..., None], axis=2)[..., 0])
    v0 = np.take_along_axis(v, j[..., None], axis=2)[..., 0]
    v1 = np.take_along_axis(v, j[..., None] + 1, axis=2)[..., 0]
    offset = s[j] + STEP_PX * (0.5 - v0) / np.where(v1 > v0, v1 - v0, 1.0)
    points = base + offset[..., None] * normal[:, None, :]

    lines = []
    for k in range(4):
        pts = points[k][found[k]]
        if len(pts) < max(MIN_PROFILES, MIN_INLIER_FRACTION * n_along):
            raise _RefineError("edge not found")
        keep = np.ones(len(pts), dtype=bool)
        for _ in range(2):
            n, d, r = _fit_line(pts[keep])
            r_all = pts @ n - d
            sigma = 1.4826 * np.median(np.abs(r_all[keep]))
            keep = np.abs(r_all) <= max(3.0 * sigma, 0.05)
            if keep.sum() < max(MIN_PROFILES, MIN_INLIER_FRACTION * n_along):
                raise _RefineError("edge points do not lie on a line")
        n, d, r = _fit_line(pts[keep])
        if np.sqrt(np.mean(r * r)) > max(0.1 * module, 0.15):
            raise _RefineError("edge points scatter too much")
        lines.append((n, d))
    return lines


def _intersect(lines: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Corner k where edge k - 1 meets edge k (edge k runs from corner k to corner k + 1)."""
    corners = np.empty((4, 2))
    for k in range(4):
        (n1, d1), (n2, d2) = lines[k - 1], lines[k]
        A = np.stack([n1, n2])
        det = np.linalg.det(A)
        if abs(det) < 0.1:  # sine of the angle between the edges
            raise _RefineError("nearly parallel edges")
        corners[k] = np.linalg.solve(A, [d1, d2])
    return corners


def refine_corners_by_edges(
    image: np.ndarray, corners_px: np.ndarray, camera: FisheyeCamera, modules: int,
    offset_px: tuple[int, int] = (0, 0), *, transfer: str = "srgb", max_shift_px: float = 2.0,
) -> np.ndarray:
    """Refine a marker's 4 corners from its straight border edges (see the module docstring).

    ``image``: (H, W) uint8 grey, the full frame or a crop whose top-left pixel is ``offset_px``
    in full-image pixels. ``corners_px``: (4, 2) approximate corners in full-image pixels, ArUco
    order (TL, TR, BR, BL). ``modules``: modules across the black square (markerSize + 2, 6 for
    a 4x4 dictionary). ``transfer``: the curve that encoded the image ("srgb" or "linear").

    Returns (4, 2) float64 corners in full-image pixels, ArUco order. If refinement fails or a
    corner would move more than ``max_shift_px``, returns the input corners unchanged.
    """
    if transfer not in TRANSFERS:
        raise ValueError(f"transfer={transfer!r}: choose from {', '.join(TRANSFERS)}")
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"need an 8-bit grey image, got {image.dtype} of shape {image.shape}")
    start = np.asarray(corners_px, dtype=float).reshape(4, 2)
    if not np.isfinite(start).all() or modules < 3:
        return start.copy()
    x0, y0 = int(offset_px[0]), int(offset_px[1])
    corners = start
    try:
        for _ in range(PASSES):
            rays, valid = camera.unproject(corners)
            if not valid.all():
                raise _RefineError("a corner lies outside the image circle")
            R_virt_cam = virtual_view_rotation(rays.sum(axis=0))
            corners_v = _to_virtual(corners, camera, R_virt_cam, 1.0)
            perimeter_v = np.linalg.norm(corners_v - np.roll(corners_v, 1, axis=0), axis=1).sum()
            perimeter = np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1).sum()
            f_v = perimeter / perimeter_v
            corners_v *= f_v
            lines = _edge_lines(image, x0, y0, corners_v, int(modules), camera, R_virt_cam, f_v,
                                _LUTS[transfer])
            corners = _to_fisheye(_intersect(lines), camera, R_virt_cam, f_v)
            if not np.isfinite(corners).all():
                raise _RefineError("a refined corner lies outside the image circle")
    except (_RefineError, np.linalg.LinAlgError):
        return start.copy()
    if np.any(np.linalg.norm(corners - start, axis=1) > max_shift_px):
        return start.copy()
    return corners

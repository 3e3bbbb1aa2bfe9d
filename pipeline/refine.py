"""Sub-pixel ArUco corners from the marker's straight border edges, through an exact fisheye.

OpenCV's corner refinements are biased on the outer, L-shaped corners of a marker: on
noise-free anti-aliased renders ``CORNER_REFINE_SUBPIX`` (cornerSubPix) puts them 0.35-0.5 px
inside the true corner at every window size, ``CONTOUR`` and ``APRILTAG`` 0.5-1 px. A corner is
where two straight edges meet, so it is found here from the edges instead:

1. **Virtual view.** The approximate corners are unprojected to rays and a virtual pinhole
   camera is aimed at the marker (:func:`pipeline.pose.virtual_view_rotation` of the sum of the
   rays). The marker's border edges, curved in the fisheye image, are exactly straight there.
   Its focal length is scaled so that the marker's perimeter is as long in virtual pixels as
   in image pixels: one virtual pixel is about one image pixel.
2. **Edge profiles.** Along the middle 15%-85% of each of the 4 outer edges, one intensity
   profile per virtual pixel runs across the edge, from 0.6 module inside it (the black border
   is one module wide; the code bits beyond it may be white) to 1 module outside it (the white
   quiet zone). Profiles are laid out in marker modules through the homography of the current
   corners, so the depths hold under perspective, and are sampled every half virtual pixel.
   Only these samples are rectified: each is mapped virtual pixel -> ray -> fisheye pixel and
   read with one bilinear ``cv2.remap`` of the (linearized) image.
3. **Edge points.** Each profile's edge is the centroid of its derivative over a window of +-2
   px re-centred on its own estimate, starting from the halfway crossing nearest the expected
   edge (:mod:`pipeline.refine_edge`): exact for any point-symmetric blur (pixel-area sampling,
   bilinear reading, the lens, sharpening) whatever the edge's sub-pixel phase, nearly so under
   light falling across the edge, without knowing the black or white level. Levels taken further
   from the edge moved corners on real photographs by up to 1.4 px: a quiet zone one module wide
   (a tag on a cube, with the cube's edge beyond it) or paper lit unevenly. The levels (black: a
   low percentile of the inner samples of a profile and its neighbours along the edge; white:
   the mean of its outer half) only place the crossing and decide whether a profile has the
   contrast to be used; an edge whose window holds less than half that contrast is no step (a
   neighbouring edge or noise) and is dropped.
4. **Lines and corners.** A straight line is fitted to each edge's points (total least
   squares; points beyond 3 robust sigmas of a first fit are dropped) and adjacent lines are
   intersected. Steps 2-4 run twice, the second time around the first pass's corners; the
   corners are then mapped back to fisheye pixels.

Intensities are linearized first: the centroid is exact only where the blur was linear.
Blur before encoding (the lens, as in the camera twin) is linear in light (``"srgb"``); blur
after it (resampling, sharpening, JPEG) in the codes (``"linear"``); a wrong curve moves the
corners by 0.1-0.7 px. ``"auto"`` (the default) measures on the marker's own border where
between the two readings its edges lie (:mod:`pipeline.refine_curve`; tests/test_refine_real.py
measures all three).

Accuracy (corner error against ground truth, px): on noise-free 64-spp renders of the
detectability study (lab lighting, 200 mm, alpha 0-85 deg, phi 0-60 deg, where OpenCV finds
the marker) median 0.02 and max 0.25 for 13.2 mm (the max on a marker turned 60 degrees, whose
modules across its long edges are 3.3 px: the window sees the code bits' edges), median 0.02
and max 0.04 for 8.8 mm, where ``subpix`` has median 0.42-0.52 and max 1.1-1.2; on exactly
ray-cast images (no renderer) median 0.01. Cost: with ``"auto"``, which refines under both
curves, about 60% of a ``robust`` frame on the twin's 20-40 px markers (docs/refine_real.md).

If refinement fails (too little contrast across an edge, an edge with too few consistent
points or too much scatter about its line, nearly parallel edges, samples outside the image
or its circle, or a corner moving more than three quarters of a module from where it
started) the input corners are returned unchanged with the reason, one of :data:`FAILURES`:
a bad image never raises.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from pipeline.pose import virtual_view_rotation
from pipeline.refine_curve import choose_curve
from pipeline.refine_edge import ALONG, OUTWARD, SQUARE, WINDOW_PX, edge_centroids
from scenes.camera import FisheyeCamera

TRANSFERS = ("auto", "srgb", "linear")
EDGE_SPAN = (0.15, 0.85)  # the part of each edge that is sampled, as fractions of its length
INNER_MODULES = 0.6  # profile depth inside the black border, in modules
OUTER_MODULES = 1.0  # profile length into the white quiet zone, in modules
STEP_PX, ALONG_STEP_PX = 0.5, 1.0  # sample spacing along a profile, profiles along an edge (px)
MIN_PROFILES, MAX_PROFILES = 6, 64  # per edge
RUN_PROFILES = 7  # profiles (odd) along an edge that share a black level and window ends
BLACK_PERCENTILE = 15.0  # of the samples from 0.6 to 0.3 module inside an edge
MIN_CONTRAST = 0.2  # (white - black) / white, in linear light
#: An edge's window must hold this much of the profile's contrast: less is no step (a blur
#: sigma of 3 px still leaves 0.5 within +-2 px), but a neighbouring edge or noise.
MIN_RISE = 0.5
MIN_INLIER_FRACTION = 0.6  # of an edge's profiles, to accept its line
PASSES = 2
#: A corner moving further has latched onto another edge (the code bits are 1 module inside).
#: Half a module refused OpenCV's corners 3 px off on 35-45 px markers in tests/data/real_markers.
MAX_SHIFT_MODULES = 0.75
MIN_MAX_SHIFT_PX = 1.5  # the input corners' own pixel-level error, whatever the size

_PREV = np.array([3, 0, 1, 2])
_EDGES = np.arange(4)
_DEPTH = np.array([-INNER_MODULES, 0.0, OUTER_MODULES])[:, None, None, None]


def _srgb_to_linear_lut() -> np.ndarray:
    c = np.arange(256, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


#: 8-bit code -> linear light, per transfer curve (the inverse of the camera's curve).
LINEAR_LUTS = {"srgb": _srgb_to_linear_lut(), "linear": np.arange(256, dtype=np.float32) / 255.0}


#: Every reason :func:`refine_corners_by_edges` gives for keeping the input corners: short,
#: stable strings that callers may count.
FAILURES = (
    "bad corners",  # not finite, too few modules, out of order or degenerate
    "too small",  # an edge shorter than 3/4 px per module
    "too wide",  # the marker spans 180 degrees or more
    "outside image",  # samples needed beyond the image or crop given
    "outside image circle",
    "low contrast",  # too few profiles with an edge of enough contrast
    "too few edge points",
    "edge scatter",  # edge points too far from their line
    "parallel edges",
    "moved too far",  # a corner beyond the shift limit
    "curve sensitive",  # "auto": the corners depend on the unknown transfer curve
    "numerical error",
)


class _RefineError(Exception):
    """Internal: refinement failed (the message is one of :data:`FAILURES`); the caller keeps
    the input corners."""


def _to_fisheye(
    virt: np.ndarray, camera: FisheyeCamera, R_virt_cam: np.ndarray, f_v: float
) -> np.ndarray:
    """Virtual pixels (..., 2) -> full-image fisheye pixels (..., 2); NaN outside the circle."""
    rays = virt @ (R_virt_cam[:2] / f_v) + R_virt_cam[2]
    return camera.project(rays)


@lru_cache(maxsize=64)
def _profile_ends(n_along: int, modules: int) -> np.ndarray:
    """(3, 4 edges, n_along, 3) homogeneous marker points (modules): each profile's inner end,
    its point on the edge and its outer end."""
    t = np.linspace(EDGE_SPAN[0], EDGE_SPAN[1], n_along)
    base = (SQUARE[:, None, :] + t[:, None] * ALONG[:, None, :]) * modules
    ends = base + _DEPTH * OUTWARD[:, None, :]
    return np.concatenate([ends, np.ones(ends.shape[:-1] + (1,))], axis=-1)


class _Profiles(NamedTuple):
    """Where a pass reads its profiles: the same for every curve the patch is read in."""

    p_in: np.ndarray  # (4, n_along, 2) inner ends, virtual px
    delta: np.ndarray  # (4, n_along, 2) inner to outer end
    t_edge: np.ndarray  # (4, n_along) where the edge should be, as a fraction of the profile
    maps: tuple[np.ndarray, np.ndarray]  # cv2.remap's x and y maps, (4 n_along, n_s) float32
    ds: np.ndarray  # (4, n_along) sample spacing, virtual px
    max_rms: float  # the edge scatter allowed (px): a tenth of a module, at least 0.15


def _profiles(corners_v: np.ndarray, modules: int, to_patch) -> _Profiles:
    """The profiles across each outer edge of the marker whose corners are ``corners_v``
    (virtual px); ``to_patch`` maps virtual pixels to the patch's pixels."""
    length = np.linalg.norm(corners_v[_PREV] - corners_v, axis=1)
    if length.min() < 3.0 * modules / 4:
        raise _RefineError("too small")
    H = cv2.getPerspectiveTransform(
        (SQUARE * modules).astype(np.float32), corners_v.astype(np.float32)
    )
    n_along = min(
        max(round((EDGE_SPAN[1] - EDGE_SPAN[0]) * length.max() / ALONG_STEP_PX), MIN_PROFILES),
        MAX_PROFILES,
    )
    h = _profile_ends(n_along, modules) @ H.T
    if not (np.isfinite(h).all() and h[..., 2].min() > 0):
        raise _RefineError("bad corners")
    ends = h[..., :2] / h[..., 2:]  # (3, 4, n_along, 2): in, edge and out ends, virtual pixels
    p_in, p_edge, p_out = ends
    delta = p_out - p_in
    span = np.sqrt((delta * delta).sum(axis=-1))  # (4, n_along)
    n_s = int(np.ceil(span.max() / STEP_PX)) + 1
    ds = span / (n_s - 1)
    frac = np.linspace(0.0, 1.0, n_s)
    t_edge = ((p_edge - p_in) * delta).sum(axis=-1) / (span * span)  # where the edge should be
    if not (span.min() > 0 and t_edge.min() > 0.05 and t_edge.max() < 0.95):
        raise _RefineError("bad corners")
    # A profile's image in the fisheye is a smooth curve: the quadratic through the images of
    # its ends and edge point is exact to well under 0.001 px over its few pixels.
    f_in, f_edge, f_out = to_patch(ends)
    bend = (f_edge - f_in - t_edge[..., None] * (f_out - f_in)) / (t_edge * (t_edge - 1.0))[
        ..., None
    ]
    a, b, c = f_in, f_out - f_in, bend  # maps = a + frac * b + frac (frac - 1) * c
    curve = frac * (frac - 1.0)
    mx = a[..., 0, None] + frac * b[..., 0, None] + curve * c[..., 0, None]
    my = a[..., 1, None] + frac * b[..., 1, None] + curve * c[..., 1, None]
    maps = (mx.astype(np.float32).reshape(-1, n_s), my.astype(np.float32).reshape(-1, n_s))
    return _Profiles(p_in, delta, t_edge, maps, ds, max(0.1 * length.min() / modules, 0.15))


def _edge_lines(patch: np.ndarray, profiles: _Profiles) -> tuple[np.ndarray, np.ndarray]:
    """One sub-pixel line n . x = d per outer edge, in virtual pixels: normals (4, 2), d (4,),
    from ``profiles`` read in ``patch``, the linearized image."""
    p_in, delta, t_edge, maps, ds, max_rms = profiles
    n_s = maps[0].shape[1]
    values = cv2.remap(patch, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(
        *t_edge.shape, n_s
    )

    j_edge = t_edge * (n_s - 1)  # sample index of the expected edge
    v, contrast = _normalized(values, j_edge)
    j, found = _crossings(v, contrast > 0, j_edge)
    # start from the halfway crossing, interpolated between the samples about it
    v0, v1 = (np.take_along_axis(v, (j + k)[..., None], axis=2)[..., 0] for k in (0, 1))
    start = j + np.minimum(np.maximum((0.5 - v0) / np.where(v1 > v0, v1 - v0, 1.0), 0.0), 1.0)
    edge, rise = edge_centroids(values, start, WINDOW_PX / ds, _run_median)
    found &= np.isfinite(edge) & (rise >= MIN_RISE * contrast)
    points = p_in + np.where(found, edge / (n_s - 1), t_edge)[..., None] * delta
    return _fit_lines(points, found, max_rms)


def _runs(x: np.ndarray) -> np.ndarray:
    """(4, n, ...) -> (4, n, RUN_PROFILES, ...): each profile with its neighbours along the edge
    (the ends repeat the first and last), so that levels follow light that varies along it."""
    return x[:, _run_index(x.shape[1])]


@lru_cache(maxsize=64)
def _run_index(n: int) -> np.ndarray:
    """(n, RUN_PROFILES) indices of each profile's run along an edge of ``n`` profiles."""
    r = RUN_PROFILES // 2
    index = np.clip(np.arange(n)[:, None] + np.arange(-r, r + 1), 0, n - 1)
    index.setflags(write=False)  # shared by every call
    return index


def _run_median(x: np.ndarray) -> np.ndarray:
    """(..., n): each profile's value replaced by the median over its run along the edge (an odd
    count: the middle value, as ``np.median``, found by a partition)."""
    mid = RUN_PROFILES // 2
    return np.partition(x[..., _run_index(x.shape[-1])], mid, axis=-1)[..., mid]


def _normalized(values: np.ndarray, j_edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Profiles (4, n, n_s) scaled to 0 at their black level and 1 at their white level, and
    each one's contrast (white - black; 0 where it is too low to be used).

    The levels only place the halfway crossing that starts each edge's window and decide
    whether a profile has contrast: the edge itself needs neither (:mod:`pipeline.refine_edge`).
    Black: a low percentile of the inner half of the black part over a run of neighbouring
    profiles (robust to the blur of neighbouring white code bits). White: the mean of the outer
    half of the profile's white part.
    """
    n_s = values.shape[2]
    c_in = int(0.5 * j_edge.min()) + 1
    c_out = min(int(np.ceil((0.5 * (j_edge + n_s - 1)).max())), n_s - 2)
    inner = _runs(values[:, :, :c_in]).reshape(*values.shape[:2], -1)
    k = int(BLACK_PERCENTILE / 100.0 * (inner.shape[2] - 1))
    black = np.partition(inner, k, axis=2)[..., k]
    white = values[:, :, c_out:].mean(axis=2)
    ok = white - black >= MIN_CONTRAST * white
    if np.any(ok.sum(axis=1) < MIN_INLIER_FRACTION * values.shape[1]):
        raise _RefineError("low contrast")
    contrast = np.where(ok, white - black, 0.0)
    return (values - black[..., None]) / np.where(ok, contrast, 1.0)[..., None], contrast


def _crossings(v: np.ndarray, ok: np.ndarray, j_edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The halfway crossing (rising, inside -> outside) of each profile nearest the expected
    edge, as the sample before it (4, n), and whether there is one."""
    n_s = v.shape[2]
    rising = (v[..., :-1] < 0.5) & (v[..., 1:] >= 0.5)
    dist = np.where(rising, np.abs(np.arange(n_s - 1) + 0.5 - j_edge[..., None]), np.inf)
    found = ok & (dist.min(axis=2) < np.inf)
    if not found.any():
        raise _RefineError("low contrast")
    return np.argmin(dist, axis=2), found


def _fit_lines(
    points: np.ndarray, found: np.ndarray, max_rms: float
) -> tuple[np.ndarray, np.ndarray]:
    """Robust total-least-squares lines through (4, m, 2) points: normals (4, 2), offsets (4,).

    Points beyond 3 robust sigmas (at least 0.05 px) of a first fit are dropped.
    """
    need = max(MIN_PROFILES, MIN_INLIER_FRACTION * points.shape[1])
    x, y = points[..., 0], points[..., 1]
    keep = found
    for step in range(2):
        count = keep.sum(axis=1)
        if count.min() < need:
            raise _RefineError("too few edge points")
        w = keep / count[:, None]
        cx, cy = (w * x).sum(axis=1), (w * y).sum(axis=1)
        dx, dy = x - cx[:, None], y - cy[:, None]
        wdx, wdy = w * dx, w * dy
        sxx, syy, sxy = (wdx * dx).sum(axis=1), (wdy * dy).sum(axis=1), (wdx * dy).sum(axis=1)
        angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # direction of the line (major axis)
        nx, ny = -np.sin(angle), np.cos(angle)
        r = np.abs(nx[:, None] * dx + ny[:, None] * dy)
        if step == 1:
            break
        r_sorted = np.sort(np.where(keep, r, np.inf), axis=1)
        sigma = 1.4826 * r_sorted[_EDGES, (count - 1) // 2]
        keep = found & (r <= np.maximum(3.0 * sigma, 0.05)[:, None])
    if ((keep * r * r).sum(axis=1) / count).max() > max_rms**2:
        raise _RefineError("edge scatter")
    return np.stack([nx, ny], axis=1), nx * cx + ny * cy


def _intersect(normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Corner k where edge k - 1 meets edge k."""
    n1, n2, d1, d2 = normal[_PREV], normal, offset[_PREV], offset
    det = n1[:, 0] * n2[:, 1] - n1[:, 1] * n2[:, 0]
    if np.any(np.abs(det) < 0.1):  # sine of the angle between adjacent edges
        raise _RefineError("parallel edges")
    return (
        np.stack([d1 * n2[:, 1] - d2 * n1[:, 1], n1[:, 0] * d2 - n2[:, 0] * d1], axis=1)
        / det[:, None]
    )


def _refine(
    image: np.ndarray,
    start: np.ndarray,
    camera: FisheyeCamera,
    modules: int,
    offset: np.ndarray,
    transfer: str,
) -> np.ndarray:
    rays, valid = camera.unproject(start)
    if not valid.all():
        raise _RefineError("outside image circle")
    R_virt_cam = virtual_view_rotation(rays.sum(axis=0))
    q = rays @ R_virt_cam.T
    if np.any(q[:, 2] <= 1e-6):
        raise _RefineError("too wide")
    corners_v = q[:, :2] / q[:, 2:]
    f_v = (
        np.linalg.norm(start[_PREV] - start, axis=1).sum()
        / np.linalg.norm(corners_v[_PREV] - corners_v, axis=1).sum()
    )
    corners_v *= f_v
    # The image region the passes may sample: the corners' box plus 2 modules and 3 px.
    margin = 2.0 * np.linalg.norm(start[_PREV] - start, axis=1).max() / modules + 3.0
    lo = np.maximum(np.floor(start.min(axis=0) - offset - margin), 0).astype(int)
    hi = np.minimum(
        np.ceil(start.max(axis=0) - offset + margin) + 1, [image.shape[1], image.shape[0]]
    ).astype(int)
    codes = image[lo[1] : hi[1], lo[0] : hi[0]]
    shift = offset + lo

    def to_patch(virt: np.ndarray) -> np.ndarray:
        px = _to_fisheye(virt, camera, R_virt_cam, f_v) - shift
        if not np.isfinite(px).all():
            raise _RefineError("outside image circle")
        if (
            px.min() < 0
            or px[..., 0].max() > codes.shape[1] - 1
            or px[..., 1].max() > codes.shape[0] - 1
        ):
            raise _RefineError("outside image")
        return px

    first = _profiles(corners_v, modules, to_patch)  # every curve's first pass reads these

    def run(patch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = _intersect(*_edge_lines(patch, first))
        for _ in range(PASSES - 1):
            c = _intersect(*_edge_lines(patch, _profiles(c, modules, to_patch)))
        square = (SQUARE * modules).astype(np.float32)
        return c, cv2.getPerspectiveTransform(square, c.astype(np.float32))

    if transfer == "auto":
        corners_v, failure = choose_curve(codes, LINEAR_LUTS, run, modules, to_patch, _RefineError)
        if failure is not None:
            raise _RefineError(failure)
    else:
        corners_v = run(LINEAR_LUTS[transfer][codes])[0]
    corners = _to_fisheye(corners_v, camera, R_virt_cam, f_v)
    if not np.isfinite(corners).all():
        raise _RefineError("outside image circle")
    return corners


class Refinement(NamedTuple):
    """Refined corners (4, 2), or the input corners and why refinement fell back."""

    corners_px: np.ndarray
    failure: str | None  # None: refined; else the reason the input corners were kept


def refine_corners_by_edges(
    image: np.ndarray,
    corners_px: np.ndarray,
    camera: FisheyeCamera,
    modules: int,
    offset_px: tuple[int, int] = (0, 0),
    *,
    transfer: str = "auto",
    max_shift_px: float | None = None,
) -> Refinement:
    """Refine a marker's 4 corners from its straight border edges (see the module docstring).

    ``image``: (H, W) uint8 grey, the full frame or a crop whose top-left pixel is ``offset_px``
    in full-image pixels. ``corners_px``: (4, 2) approximate corners in full-image pixels, ArUco
    order (TL, TR, BR, BL), e.g. OpenCV's with ``CORNER_REFINE_NONE``. ``modules``: modules
    across the black square, markerSize + 2 (6 for a 4x4 dictionary). ``transfer``: the curve
    that encoded the image, "srgb" or "linear", or "auto": measured on the marker.

    Returns the (4, 2) float64 corners in full-image pixels, ArUco order. If refinement fails,
    or a corner would move more than ``max_shift_px`` (None: :data:`MAX_SHIFT_MODULES` of the
    marker's mean module, at least :data:`MIN_MAX_SHIFT_PX`), they are (a copy of) the input
    corners and ``failure`` says why, one of :data:`FAILURES`.
    """
    if transfer not in TRANSFERS:
        raise ValueError(f"transfer={transfer!r}: choose from {', '.join(TRANSFERS)}")
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"need an 8-bit grey image, got {image.dtype} of shape {image.shape}")
    start = np.asarray(corners_px, dtype=float).reshape(4, 2)
    if not np.isfinite(start).all() or int(modules) < 3:
        return Refinement(start.copy(), "bad corners")
    offset = np.asarray(offset_px, dtype=float).reshape(2)
    try:
        with np.errstate(all="ignore"):  # failures are detected explicitly, not by warnings
            corners = _refine(image, start, camera, int(modules), offset, transfer)
    except _RefineError as exc:
        return Refinement(start.copy(), str(exc))
    except (np.linalg.LinAlgError, cv2.error):
        return Refinement(start.copy(), "numerical error")
    if max_shift_px is None:
        module_px = np.linalg.norm(start[_PREV] - start, axis=1).mean() / int(modules)
        max_shift_px = max(MAX_SHIFT_MODULES * module_px, MIN_MAX_SHIFT_PX)
    if np.any(np.linalg.norm(corners - start, axis=1) > max_shift_px):
        return Refinement(start.copy(), "moved too far")
    return Refinement(corners, None)

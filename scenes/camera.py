"""Fisheye camera models, exact past 90 degrees, shared by renderer, labels and pipeline.

Every model is radially symmetric in normalized coordinates ``m``: a ray at angle ``theta`` from
the optical axis and azimuth ``phi`` lands at ``m = d(theta) (cos phi, sin phi)``, and

    pixel = [[fx, shear0], [shear1, fy]] @ m + (cx, cy)

(``shear`` is zero except for OCamCalib's affine stretch). With ``s, c = sin(theta), cos(theta)``
(a unit ray), the radial functions ``d(theta)`` are, as published:

    equidistant      theta
    kannala_brandt   theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)   (k1..k4)
    double_sphere    s / (alpha sqrt(s^2 + (xi + c)^2) + (1 - alpha)(xi + c))         (xi, alpha)
                     Usenko, Demmel, Cremers 2018, "The Double Sphere Camera Model"
    eucm             s / (alpha sqrt(beta s^2 + c^2) + (1 - alpha) c)                  (alpha, beta)
                     Khomutenko, Garcia, Martinet 2016, "An enhanced unified camera model"
    ucm              s / (c + xi)   (Mei and Rives 2007, unified model)                (xi,)
    ocamcalib        rho / -a0, where the ray (rho, -P(rho)) makes the angle theta,
                     P(rho) = a0 + a1 rho + ... + aN rho^N (Scaramuzza 2006, OCamCalib)  (a0..aN)

The Kannala-Brandt form is OpenCV's ``cv2.fisheye`` model, but OpenCV computes
``theta = atan(r / z)`` and so breaks at 90 degrees; here ``theta = atan2(r, z)``.

OCamCalib in these terms (from its ``ocam_functions.c`` ``cam2world``/``world2cam`` and the
Matlab ``export_data.m`` that writes ``calib_results.txt``): a pixel is ``(row, col)`` counted
from 0 (the file's centre ``xc yc`` is row, column, already shifted from Matlab's 1-based
pixels), so pixel centres sit on integers as here. ``[row - xc; col - yc] = [[c, d], [e, 1]] @
(u, v)``, ``rho = |(u, v)|`` and the ray is ``(u, v, P(rho))`` in OCamCalib's frame: x along the
rows (down), y along the columns (right), z backwards (a0 < 0, so forward rays have z < 0).
Ours is x right, y down, z forward: ``(x, y, z) = (v, u, -P(rho))``. Hence, scaling by
``S = -a0`` so that ``d(theta) ~ theta`` near the axis like every other model:
``fx = S, fy = c S, shear = (e S, d S), cx = yc, cy = xc`` and ``rho = S |m|``.

Projection and unprojection are exact: closed forms for the double sphere, EUCM and UCM
unprojection (from the papers), Newton's method to machine precision otherwise (safeguarded by a
bracket, started from a table). Round trips hold to 1e-9 px and 1e-9 rad except within about
1e-6 rad of a fold (where d'(theta) = 0 no inverse is better conditioned).

Each model is valid up to its own limit ``theta_valid_max`` (the first angle where ``d(theta)``
stops strictly increasing or its denominator reaches 0): closed forms for UCM, EUCM and the
double sphere, polynomial roots polished by Newton for Kannala-Brandt and OCamCalib. The
double-sphere limit is the exact one (the second sphere's UCM condition mapped back to the first
sphere): the set Omega published by Usenko et al. (z > -w2 |p|) differs from it, e.g. 125.23 deg
against 126.12 deg for the TUM-VI lens, and allows angles past the pole of the denominator for
xi < 0 with small alpha. ``theta_max_deg`` is the image-circle limit, at most the model's limit.
Frames and pixel centres follow :mod:`scenes.conventions`.
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import cv2
import numpy as np

from scenes import lens_models
from scenes.array_ops import NUMPY
from scenes.lens_models import MODELS

OPENCV_FIT_MAX_DEG = 89.0  # cv2.fisheye computes theta = atan(r / z): it breaks at 90 degrees
#: The narrowest image circle a lens may have, in degrees off axis: a fisheye's is tens of
#: degrees, so one under a degree is a slip (a unit, a typo; 1e-300 made a 0-degree profile).
MIN_THETA_MAX_DEG = 1.0


@dataclass(frozen=True)
class FisheyeCamera:
    """A fisheye camera. Pixels outside the image circle (theta > theta_max) are black."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    theta_max_deg: float = 95.0
    model: str = "equidistant"
    params: tuple[float, ...] = field(default=())
    shear: tuple[float, float] = field(default=(0.0, 0.0))

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            number = isinstance(value, numbers.Real) and not isinstance(value, bool)
            if not (number and math.isfinite(value)) or int(value) != value or value < 1:
                raise ValueError(f"{name}={value!r}: must be a positive integer")
        for name in ("fx_px", "fy_px"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name}={getattr(self, name)!r}: must be a positive number")
        for name in ("cx_px", "cy_px"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name}={getattr(self, name)!r}: must be a finite number")
        if not MIN_THETA_MAX_DEG <= self.theta_max_deg < 180.0:
            low = f"{MIN_THETA_MAX_DEG:g}"
            raise ValueError(f"theta_max_deg={self.theta_max_deg!r}: allowed range is [{low}, 180)")
        if self.model not in MODELS:
            raise ValueError(f"model={self.model!r}: must be one of {', '.join(MODELS)}")
        shear = tuple(float(s) for s in self.shear)
        if len(shear) != 2 or not all(math.isfinite(s) for s in shear):
            raise ValueError(f"shear={self.shear!r}: needs 2 finite numbers (pixels)")
        if self.fx_px * self.fy_px - shear[0] * shear[1] <= 0:
            raise ValueError(f"shear={shear}: fx*fy - shear0*shear1 must be > 0")
        object.__setattr__(self, "shear", shear)
        object.__setattr__(self, "params", lens_models.check_params(self.model, self.params))
        limit = self.theta_valid_max_deg
        if self.theta_max_deg > limit + 1e-9:
            raise ValueError(
                f"theta_max_deg={self.theta_max_deg!r}: beyond the {self.model} model's valid "
                f"limit of {limit:.6f} deg for params {self.params}; allowed range is "
                f"(0, {limit:.6f}]"
            )

    # --- Radial model
    @property
    def theta_max_rad(self) -> float:
        return math.radians(self.theta_max_deg)

    @property
    def theta_valid_max_rad(self) -> float:
        """The model's own limit: the largest ray angle it maps one-to-one."""
        return lens_models.valid_limit(self.model, self.params)

    @property
    def theta_valid_max_deg(self) -> float:
        return math.degrees(self.theta_valid_max_rad)

    def distort(self, theta_rad: np.ndarray, xp=NUMPY) -> np.ndarray:
        """Normalized image radius d(theta) for ray angles up to theta_max.

        ``xp`` here and below: the array namespace (:mod:`scenes.array_ops`), NumPy by default;
        the renderer passes Dr.Jit's, so one implementation serves labels and rays."""
        top = min(self.theta_max_rad, self.theta_valid_max_rad)
        return lens_models.radius_of_theta(self.model, self.params, theta_rad, top, xp)

    def undistort(self, d: np.ndarray, xp=NUMPY) -> np.ndarray:
        """Ray angle theta for a normalized radius d: the exact inverse of :meth:`distort`.

        Radii beyond the model's reach give its limit ``theta_valid_max_rad``."""
        return lens_models.theta_of_radius(self.model, self.params, d, xp)

    def _normalized(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """m = A^-1 (pixel - c) for (..., 2) pixels."""
        uv = np.asarray(pixels, dtype=float)
        return self._normalized_xy(uv[..., 0], uv[..., 1])

    def _normalized_xy(self, x, y):
        """m = A^-1 (pixel - c) for pixel coordinates x, y (any array namespace)."""
        u, v = x - self.cx_px, y - self.cy_px
        if self.shear == (0.0, 0.0):
            return u / self.fx_px, v / self.fy_px
        s0, s1 = self.shear
        det = self.fx_px * self.fy_px - s0 * s1
        return (self.fy_px * u - s0 * v) / det, (self.fx_px * v - s1 * u) / det

    # --- Projection
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project (..., 3) camera-frame points to (..., 2) pixels; NaN beyond theta_max."""
        p = np.asarray(points_cam, dtype=float)
        return np.stack(self.project_xyz(p[..., 0], p[..., 1], p[..., 2]), axis=-1)

    def project_xyz(self, x, y, z, xp=NUMPY):
        """:meth:`project` of points given by their coordinates: (pixel x, pixel y), NaN beyond
        theta_max."""
        rho = xp.hypot(x, y)
        theta = xp.atan2(rho, z)
        outside = (theta > self.theta_max_rad) | ((rho == 0) & (z <= 0))
        d = self.distort(xp.where(outside, 0.0, theta), xp)
        safe_rho = xp.where(rho > 0, rho, 1.0)
        scale = xp.where(rho > 0, d / safe_rho, 0.0)
        mx, my = scale * x, scale * y
        s0, s1 = self.shear
        px = self.fx_px * mx + s0 * my + self.cx_px
        py = s1 * mx + self.fy_px * my + self.cy_px
        return xp.where(outside, math.nan, px), xp.where(outside, math.nan, py)

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit ray directions (..., 3) in the camera frame for (..., 2) pixels.

        Returns ``(directions, valid)``; ``valid`` is False outside the image circle.
        """
        uv = np.asarray(pixels, dtype=float)
        *dirs, valid = self.unproject_xy(uv[..., 0], uv[..., 1])
        return np.stack(dirs, axis=-1), valid

    def unproject_xy(self, x, y, xp=NUMPY):
        """:meth:`unproject` of pixels given by their coordinates: (dx, dy, dz, valid)."""
        mx, my = self._normalized_xy(x, y)
        d = xp.hypot(mx, my)
        d_max = float(self.distort(np.array(self.theta_max_rad)))
        valid = d <= d_max * (1.0 + 1e-12)  # a ray at theta_max rounds to either side of d_max
        theta = self.undistort(xp.minimum(d, d_max), xp)
        safe_d = xp.where(d > 0, d, 1.0)
        scale = xp.where(d > 0, xp.sin(theta) / safe_d, 0.0)
        return scale * mx, scale * my, xp.cos(theta), valid

    def theta_of_pixel(self, pixels: np.ndarray) -> np.ndarray:
        """Ray angle from the optical axis (rad) for (..., 2) pixels; finite everywhere:
        pixels beyond the model's reach give ``theta_valid_max_rad``."""
        mx, my = self._normalized(pixels)
        return self.undistort(np.hypot(mx, my))

    def image_circle_box(self, margin_px: int = 8) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1), x1 and y1 exclusive: the pixels within ``margin_px`` of the image
        circle (theta <= theta_max), clipped to the image. Nothing the model can see lies outside,
        so a detector searching only this box finds what it would in the whole frame."""
        d_max = float(self.distort(np.array(self.theta_max_rad)))
        # the circle |m| = d_max maps to an ellipse whose half-extents are the rows' norms of A
        rx = d_max * math.hypot(self.fx_px, self.shear[0]) + margin_px
        ry = d_max * math.hypot(self.shear[1], self.fy_px) + margin_px
        return (
            max(0, math.floor(self.cx_px - rx)),
            max(0, math.floor(self.cy_px - ry)),
            min(self.width_px, math.ceil(self.cx_px + rx) + 1),
            min(self.height_px, math.ceil(self.cy_px + ry) + 1),
        )

    def fov_in_image_deg(self) -> tuple[float, float, float]:
        """(horizontal, vertical, diagonal) field of view the image records, in degrees: the
        sum of the two half-angles to opposite image edges (corners) through the principal
        point, each capped at theta_max (the image circle)."""
        w, h = self.width_px - 0.5, self.height_px - 0.5
        pairs = [
            [(-0.5, self.cy_px), (w, self.cy_px)],
            [(self.cx_px, -0.5), (self.cx_px, h)],
            [(-0.5, -0.5), (w, h)],
        ]
        theta = np.minimum(self.theta_of_pixel(np.array(pairs)), self.theta_max_rad)
        return tuple(float(v) for v in np.degrees(theta.sum(axis=1)))

    # --- Interchange
    def to_opencv(self) -> dict[str, Any]:
        """OpenCV fisheye form: K (3x3), D (4,), image size (w, h) and ``fit_max_err_px``.

        Exact for Kannala-Brandt and equidistant cameras without shear (below 90 degrees,
        where OpenCV works). Other models get a least-squares Kannala-Brandt fit of d(theta)
        over [0, min(theta_max, 89 deg)]; ``fit_max_err_px`` is the largest distance there
        between OpenCV's own projection (``cv2.fisheye.projectPoints``) and the exact model.
        """
        form = _opencv_form(self)
        return {**form, "K": form["K"].copy(), "D": form["D"].copy()}

    @classmethod
    def from_opencv(
        cls, K: np.ndarray, D: np.ndarray, size: tuple[int, int], theta_max_deg: float = 95.0
    ) -> FisheyeCamera:
        """The exact model behind an OpenCV fisheye calibration (K, D, (width, height))."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3) or K[0, 1] != 0.0 or K[1, 0] != 0.0 or K[2].tolist() != [0, 0, 1]:
            raise ValueError(
                f"K must be a 3x3 camera matrix without skew (cv2.fisheye ignores it), "
                f"got {K.tolist()}"
            )
        k = tuple(float(c) for c in np.asarray(D, dtype=float).ravel())
        if len(k) != 4:
            raise ValueError(f"D={list(k)}: an OpenCV fisheye D has 4 coefficients")
        return cls(
            width_px=int(size[0]),
            height_px=int(size[1]),
            fx_px=float(K[0, 0]),
            fy_px=float(K[1, 1]),
            cx_px=float(K[0, 2]),
            cy_px=float(K[1, 2]),
            theta_max_deg=theta_max_deg,
            model="kannala_brandt" if any(k) else "equidistant",
            params=k if any(k) else (),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the exact model plus its OpenCV fisheye form."""
        cv = self.to_opencv()
        model = asdict(self)
        model["params"], model["shear"] = list(self.params), list(self.shear)
        return {
            "model": model,
            "opencv_fisheye": {
                "K": cv["K"].tolist(),
                "D": cv["D"].tolist(),
                "size": list(cv["size"]),
                "fit_max_err_px": cv["fit_max_err_px"],
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FisheyeCamera:
        """Inverse of :meth:`to_dict`; raises ValueError naming a missing or bad field.

        Reads older files too, whose Kannala-Brandt coefficients are a list ``k``."""
        model = data.get("model")
        if not isinstance(model, dict):
            raise ValueError("camera file: missing the 'model' object")
        _check_opencv_form(data.get("opencv_fisheye", {}))
        missing = [
            f
            for f in ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")
            if f not in model
        ]
        if missing:
            raise ValueError(f"camera file: 'model' lacks field(s) {', '.join(missing)}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(model) - known - {"k"})
        if unknown:
            raise ValueError(
                f"camera file: unknown 'model' field(s) {', '.join(unknown)}; "
                f"allowed: {', '.join(sorted(known))}"
            )
        values = dict(model)
        if "k" in values:
            if "params" in values:
                raise ValueError("camera file: give 'params' or the older 'k', not both")
            k = values.pop("k")
            if not isinstance(k, list | tuple):
                raise ValueError(f"camera file: k={k!r}: must be a list of 4 numbers")
            legacy_equidistant = values.get("model", "equidistant") == "equidistant"
            values["params"] = () if legacy_equidistant and not any(k) else tuple(k)
        for name in ("params", "shear"):
            if name in values:
                if not isinstance(values[name], list | tuple):
                    raise ValueError(f"camera file: {name}={values[name]!r}: must be a list")
                values[name] = tuple(values[name])
        return cls(**values)


def _check_opencv_form(block: Any) -> None:
    """The ``opencv_fisheye`` block :meth:`FisheyeCamera.to_dict` derives from the model: not
    read back (the model is the camera), but a damaged one is refused, not passed over."""
    if not isinstance(block, dict):
        raise ValueError("camera file: 'opencv_fisheye' must be an object")
    shapes = {"K": (3, 3), "D": (4,), "size": (2,), "fit_max_err_px": ()}
    unknown = sorted(set(block) - set(shapes))
    if unknown:
        raise ValueError(f"camera file: unknown 'opencv_fisheye' field(s) {', '.join(unknown)}")
    for name, value in block.items():
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            array = None
        if array is None or array.shape != shapes[name] or not np.isfinite(array).all():
            raise ValueError(
                f"camera file: opencv_fisheye.{name}={value!r}: must be finite numbers of "
                f"shape {shapes[name]} (the form derived from 'model')"
            )


@functools.lru_cache(maxsize=64)
def _opencv_form(camera: FisheyeCamera) -> dict[str, Any]:
    size = (camera.width_px, camera.height_px)
    exact = camera.model in ("equidistant", "kannala_brandt")
    if exact:
        gain, D = 1.0, np.array(camera.params if camera.params else (0.0,) * 4, dtype=float)
    else:  # d(theta) ~ g theta (1 + k1 theta^2 + ... + k4 theta^8): linear in g, g k1, ..., g k4
        theta = np.linspace(0.0, min(camera.theta_max_rad, math.radians(OPENCV_FIT_MAX_DEG)), 400)
        basis = np.stack([theta ** (2 * i + 1) for i in range(5)], axis=-1)
        coeffs = np.linalg.lstsq(basis, camera.distort(theta), rcond=None)[0]
        gain, D = float(coeffs[0]), coeffs[1:] / coeffs[0]
    K = np.array(
        [
            [gain * camera.fx_px, 0.0, camera.cx_px],
            [0.0, gain * camera.fy_px, camera.cy_px],
            [0.0, 0.0, 1.0],
        ]
    )
    return {"K": K, "D": D, "size": size, "fit_max_err_px": _opencv_error_px(camera, K, D)}


def _opencv_error_px(camera: FisheyeCamera, K: np.ndarray, D: np.ndarray) -> float:
    """Largest pixel distance between cv2.fisheye's projection (K, D) and the exact camera,
    over the field below min(theta_max, 89 deg) and every 10 degrees of azimuth (just inside
    theta_max: a ray on it, rounded outward, has no projection and made the error NaN)."""
    top = min(camera.theta_max_rad * (1.0 - 1e-9), math.radians(OPENCV_FIT_MAX_DEG))
    theta, phi = np.meshgrid(np.linspace(0.0, top, 90), np.radians(np.arange(0.0, 360.0, 10.0)))
    rays = np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1
    ).reshape(-1, 1, 3)
    ref, _ = cv2.fisheye.projectPoints(rays, np.zeros(3), np.zeros(3), K, D)
    with np.errstate(over="ignore"):  # absurd intrinsics (1e300 px) give an infinite error
        return float(
            np.max(np.linalg.norm(ref.reshape(-1, 2) - camera.project(rays[:, 0]), axis=-1))
        )


def default_camera() -> FisheyeCamera:
    """The sensor's camera: 2592 x 1944, equidistant, 180 degrees across the image height."""
    width, height = 2592, 1944
    f = (height / 2.0) / (math.pi / 2.0)  # 90 degrees from the axis lands on the top/bottom edge
    return FisheyeCamera(
        width_px=width,
        height_px=height,
        fx_px=f,
        fy_px=f,
        cx_px=(width - 1) / 2.0,
        cy_px=(height - 1) / 2.0,
        theta_max_deg=95.0,
    )


@functools.lru_cache(maxsize=16)
def pinhole_camera(width_px: int, height_px: int) -> FisheyeCamera:
    """A pinhole camera the size of an image, for ``lines`` on images without a camera model.

    ``lines`` needs the marker's edges straight in a virtual pinhole view; any pinhole keeps
    straight lines straight, whatever its focal length. The lens models have no pinhole by name:
    the unified model with xi = 0 is one exactly (d = sin(theta) / cos(theta) = tan(theta)),
    valid below 90 degrees. The focal length is the image's longer side (a 53-degree field).
    """
    f_px = float(max(width_px, height_px))
    corner_deg = math.degrees(math.atan(math.hypot(width_px, height_px) / 2 / f_px))
    return FisheyeCamera(
        width_px=width_px,
        height_px=height_px,
        fx_px=f_px,
        fy_px=f_px,
        cx_px=(width_px - 1) / 2,
        cy_px=(height_px - 1) / 2,
        theta_max_deg=corner_deg + 1.0,  # the whole image, with a margin
        model="ucm",
        params=(0.0,),
    )

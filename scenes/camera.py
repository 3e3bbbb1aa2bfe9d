"""Fisheye camera models, exact past 90 degrees, shared by renderer, labels and pipeline.

Both models are radially symmetric: a ray at angle ``theta`` from the optical axis lands at
normalized radius ``d(theta)`` and is scaled by the focal lengths into pixels:

    equidistant      d(theta) = theta
    kannala_brandt   d(theta) = theta * (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)

The Kannala-Brandt form is OpenCV's ``cv2.fisheye`` model, but OpenCV computes
``theta = atan(r / z)`` and so breaks at 90 degrees; here ``theta = atan2(r, z)``, which is valid
up to ``theta_max``. Frames and pixel centres follow :mod:`scenes.conventions`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

MODELS = ("equidistant", "kannala_brandt")
_NEWTON_STEPS = 30


@dataclass(frozen=True)
class FisheyeCamera:
    """An ideal fisheye camera. Pixels outside the image circle (theta > theta_max) are black."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    theta_max_deg: float = 95.0
    model: str = "equidistant"
    k: tuple[float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ValueError(f"{name}={value!r}: must be a positive integer")
        for name in ("fx_px", "fy_px"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name}={getattr(self, name)!r}: must be a positive number")
        if not 0.0 < self.theta_max_deg < 180.0:
            raise ValueError(f"theta_max_deg={self.theta_max_deg!r}: allowed range is (0, 180)")
        if self.model not in MODELS:
            raise ValueError(f"model={self.model!r}: must be one of {', '.join(MODELS)}")
        k = tuple(float(c) for c in self.k)
        if len(k) != 4 or not all(math.isfinite(c) for c in k):
            raise ValueError(f"k={self.k!r}: needs 4 finite Kannala-Brandt coefficients")
        object.__setattr__(self, "k", k)
        if self.model == "equidistant" and any(k):
            raise ValueError("k must be zero for the equidistant model; use model='kannala_brandt'")
        theta = np.linspace(0.0, self.theta_max_rad, 2001)
        if np.any(np.diff(self.distort(theta)) <= 0):
            raise ValueError(
                f"k={k}: d(theta) is not increasing up to theta_max_deg={self.theta_max_deg}; "
                "the projection would not be invertible"
            )

    # --- Radial model
    @property
    def theta_max_rad(self) -> float:
        return math.radians(self.theta_max_deg)

    def distort(self, theta_rad: np.ndarray) -> np.ndarray:
        """Normalized image radius d(theta) for ray angles from the optical axis."""
        t2 = np.square(theta_rad)
        k1, k2, k3, k4 = self.k
        return theta_rad * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def undistort(self, d: np.ndarray) -> np.ndarray:
        """Ray angle theta for a normalized radius d: the exact inverse of :meth:`distort`."""
        d = np.asarray(d, dtype=float)
        if self.model == "equidistant":
            return d.copy()
        k1, k2, k3, k4 = self.k
        theta = d.copy()
        for _ in range(_NEWTON_STEPS):
            t2 = theta * theta
            f = self.distort(theta) - d
            df = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            step = f / df
            theta -= step
            if np.all(np.abs(step) < 1e-15):
                break
        return theta

    # --- Projection
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project (..., 3) camera-frame points to (..., 2) pixels; NaN beyond theta_max."""
        p = np.asarray(points_cam, dtype=float)
        rho = np.hypot(p[..., 0], p[..., 1])
        theta = np.arctan2(rho, p[..., 2])
        d = self.distort(theta)
        safe_rho = np.where(rho > 0, rho, 1.0)
        scale = np.where(rho > 0, d / safe_rho, 0.0)
        px = np.stack(
            [
                self.fx_px * scale * p[..., 0] + self.cx_px,
                self.fy_px * scale * p[..., 1] + self.cy_px,
            ],
            axis=-1,
        )
        outside = (theta > self.theta_max_rad) | ((rho == 0) & (p[..., 2] <= 0))
        px[outside] = np.nan
        return px

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit ray directions (..., 3) in the camera frame for (..., 2) pixels.

        Returns ``(directions, valid)``; ``valid`` is False outside the image circle.
        """
        uv = np.asarray(pixels, dtype=float)
        mx = (uv[..., 0] - self.cx_px) / self.fx_px
        my = (uv[..., 1] - self.cy_px) / self.fy_px
        d = np.hypot(mx, my)
        valid = d <= self.distort(np.array(self.theta_max_rad))
        theta = self.undistort(np.minimum(d, self.distort(np.array(self.theta_max_rad))))
        sin_t = np.sin(theta)
        safe_d = np.where(d > 0, d, 1.0)
        scale = np.where(d > 0, sin_t / safe_d, 0.0)
        dirs = np.stack([scale * mx, scale * my, np.cos(theta)], axis=-1)
        return dirs, valid

    def theta_of_pixel(self, pixels: np.ndarray) -> np.ndarray:
        """Ray angle from the optical axis (rad) for (..., 2) pixels."""
        uv = np.asarray(pixels, dtype=float)
        d = np.hypot((uv[..., 0] - self.cx_px) / self.fx_px, (uv[..., 1] - self.cy_px) / self.fy_px)
        return self.undistort(d)

    def image_circle_box(self, margin_px: int = 8) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1), x1 and y1 exclusive: the pixels within ``margin_px`` of the image
        circle (theta <= theta_max), clipped to the image. Nothing the model can see lies outside,
        so a detector searching only this box finds what it would in the whole frame."""
        d_max = float(self.distort(np.array(self.theta_max_rad)))
        rx, ry = self.fx_px * d_max + margin_px, self.fy_px * d_max + margin_px
        return (
            max(0, math.floor(self.cx_px - rx)),
            max(0, math.floor(self.cy_px - ry)),
            min(self.width_px, math.ceil(self.cx_px + rx) + 1),
            min(self.height_px, math.ceil(self.cy_px + ry) + 1),
        )

    # --- Interchange
    def to_opencv(self) -> dict[str, Any]:
        """OpenCV fisheye form: K (3x3), D (4,), image size (w, h). Exact below 90 degrees only."""
        K = np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )
        return {"K": K, "D": np.array(self.k), "size": (self.width_px, self.height_px)}

    @classmethod
    def from_opencv(
        cls, K: np.ndarray, D: np.ndarray, size: tuple[int, int], theta_max_deg: float = 95.0
    ) -> FisheyeCamera:
        """The exact model behind an OpenCV fisheye calibration (K, D, (width, height))."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3) or K[0, 1] != 0.0:
            raise ValueError(f"K must be a 3x3 matrix without skew, got {K.tolist()}")
        k = tuple(float(c) for c in np.asarray(D, dtype=float).ravel())
        return cls(
            width_px=int(size[0]),
            height_px=int(size[1]),
            fx_px=float(K[0, 0]),
            fy_px=float(K[1, 1]),
            cx_px=float(K[0, 2]),
            cy_px=float(K[1, 2]),
            theta_max_deg=theta_max_deg,
            model="kannala_brandt" if any(k) else "equidistant",
            k=k,
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the exact model plus its OpenCV fisheye form."""
        cv = self.to_opencv()
        return {
            "model": asdict(self),
            "opencv_fisheye": {
                "K": cv["K"].tolist(),
                "D": cv["D"].tolist(),
                "size": list(cv["size"]),
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FisheyeCamera:
        """Inverse of :meth:`to_dict`; raises ValueError naming a missing or bad field."""
        model = data.get("model")
        if not isinstance(model, dict):
            raise ValueError("camera file: missing the 'model' object")
        missing = [
            f
            for f in ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")
            if f not in model
        ]
        if missing:
            raise ValueError(f"camera file: 'model' lacks field(s) {', '.join(missing)}")
        fields = dict(model)
        if "k" in fields:
            fields["k"] = tuple(fields["k"])
        return cls(**fields)


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

"""Lighting presets as plain data: sky, sun, leaf canopy and the exposure set for them.

Directions are unit vectors in the camera frame (+y is down, so the zenith is (0, -1, 0)).
Radiance is in arbitrary linear units; each preset's ``exposure`` maps it to the sensor's full
scale (1.0 saturates), so presets are comparable as a camera would record them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scenes.array_ops import NUMPY
from scenes.conventions import OPTICAL_AXIS_CAM, UP_CAM

if TYPE_CHECKING:
    import trimesh

RGB = tuple[float, float, float]


def _unit(v: tuple[float, float, float]) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float)
    n = np.linalg.norm(a)
    if not n > 0:
        raise ValueError(f"direction {v!r} has zero length")
    return tuple(float(c) for c in a / n)


@dataclass(frozen=True)
class Sky:
    """A smooth sky dome: zenith-to-horizon gradient, a darker ground, an optional bright backdrop.

    ``backlight_radiance`` is added towards the scene in front of the camera (directions with
    a component along the optical axis above ``backlight_cos_min``, blended over 0.1), the bright
    sky behind the markers of the ``backlit`` preset.
    """

    zenith_radiance: float = 1.0
    horizon_radiance: float = 1.0
    ground_radiance: float = 1.0
    backlight_radiance: float = 0.0
    backlight_cos_min: float = -0.2
    color: RGB = (1.0, 1.0, 1.0)

    def radiance(self, dirs_cam: np.ndarray) -> np.ndarray:
        """(N,) luminance-like radiance seen along (N, 3) unit directions (camera frame)."""
        d = np.asarray(dirs_cam, dtype=float)
        return self.radiance_xyz(d[..., 0], d[..., 1], d[..., 2])

    def radiance_xyz(self, x, y, z, xp=NUMPY):
        """:meth:`radiance` of directions given by their coordinates, in the array namespace
        ``xp`` (:mod:`scenes.array_ops`: the renderer's kernels use the same formula)."""
        up = x * float(UP_CAM[0]) + y * float(UP_CAM[1]) + z * float(UP_CAM[2])
        forward = (
            x * float(OPTICAL_AXIS_CAM[0])
            + y * float(OPTICAL_AXIS_CAM[1])
            + z * float(OPTICAL_AXIS_CAM[2])
        )
        gradient = self.zenith_radiance - self.horizon_radiance
        sky = self.horizon_radiance + gradient * xp.clip(up, 0.0, 1.0)
        base = xp.where(up >= 0.0, sky, self.ground_radiance)
        front = xp.clip((forward - self.backlight_cos_min) / 0.1, 0.0, 1.0)
        return base + self.backlight_radiance * front


@dataclass(frozen=True)
class Sun:
    """A distant sun: direction towards it, irradiance on a surface facing it, angular radius."""

    to_sun_cam: tuple[float, float, float] = (-0.4, -0.7, -0.6)
    irradiance: float = 15.0
    angular_radius_deg: float = 0.27
    color: RGB = (1.0, 0.97, 0.92)

    def __post_init__(self) -> None:
        object.__setattr__(self, "to_sun_cam", _unit(self.to_sun_cam))


@dataclass(frozen=True)
class Canopy:
    """A layer of leaves between the sun and the scene; it only casts shadows (it is out of view).

    The layer is a plane perpendicular to the sun direction at ``distance_mm`` from the camera.
    Each image sees it shifted in its plane by a random offset up to ``max_shift_mm`` (wind and
    the array's own motion): the dappled shadow pattern moves across the marker.
    """

    distance_mm: float = 350.0
    extent_mm: float = 1600.0
    leaf_length_mm: tuple[float, float] = (25.0, 70.0)
    coverage: float = 0.55
    max_shift_mm: float = 250.0
    seed: int = 7


@dataclass(frozen=True)
class Lighting:
    """One lighting preset: what lights the scene and the exposure a camera would use for it."""

    name: str
    sky: Sky
    sun: Sun | None = None
    canopy: Canopy | None = None
    exposure: float = 1.0
    description: str = ""


PRESETS: dict[str, Lighting] = {
    "lab": Lighting(
        name="lab",
        sky=Sky(zenith_radiance=1.0, horizon_radiance=1.0, ground_radiance=0.8),
        exposure=0.9,
        description="soft diffuse room light, no direct light",
    ),
    "sun": Lighting(
        name="sun",
        sky=Sky(
            zenith_radiance=0.8, horizon_radiance=1.4, ground_radiance=0.3, color=(0.85, 0.95, 1.15)
        ),
        sun=Sun(),
        exposure=1.0 / 5.5,
        description="direct sun from above-behind-left of the camera and a clear sky",
    ),
    "canopy": Lighting(
        name="canopy",
        sky=Sky(
            zenith_radiance=0.4, horizon_radiance=0.7, ground_radiance=0.2, color=(0.8, 1.0, 0.85)
        ),
        sun=Sun(),
        canopy=Canopy(),
        exposure=1.0 / 5.0,
        description="sun through a leaf canopy: dappled shadows moving across the marker",
    ),
    "backlit": Lighting(
        name="backlit",
        sky=Sky(
            zenith_radiance=0.5,
            horizon_radiance=0.5,
            ground_radiance=0.2,
            backlight_radiance=12.0,
            color=(0.9, 0.95, 1.1),
        ),
        sun=Sun(to_sun_cam=(0.2, -0.5, 0.85)),
        exposure=1.0 / 4.0,
        description="bright sky and sun behind the marker; exposure set for the sky, so the "
        "marker is dark and the sky saturates",
    ),
}


def lighting_names() -> list[str]:
    return list(PRESETS)


def get_lighting(name: str) -> Lighting:
    """The preset of that name, or ValueError listing the presets."""
    if name not in PRESETS:
        raise ValueError(f"lighting={name!r}: unknown; choose from {', '.join(PRESETS)}")
    return PRESETS[name]


def canopy_frame(sun: Sun, canopy: Canopy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre and in-plane unit axes (u, v) of the canopy layer, camera frame."""
    n = np.asarray(sun.to_sun_cam)
    u = np.cross(n, [0.0, 0.0, 1.0])
    if np.linalg.norm(u) < 1e-6:
        u = np.cross(n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return canopy.distance_mm * n, u, v


def canopy_mesh(sun: Sun, canopy: Canopy, segments: int = 10) -> trimesh.Trimesh:
    """The leaves as one mesh of flat ellipses scattered in the canopy plane (seeded)."""
    import trimesh

    rng = np.random.default_rng(canopy.seed)
    lo, hi = canopy.leaf_length_mm
    mean_area = math.pi * 0.25 * ((lo + hi) / 2) ** 2 * 0.45
    # Overlapping random leaves cover 1 - exp(-n a / A) of the plane: solve for n.
    count = int(-math.log(1.0 - canopy.coverage) * canopy.extent_mm**2 / mean_area)
    centre, u, v = canopy_frame(sun, canopy)
    length = rng.uniform(lo, hi, count)
    width = length * rng.uniform(0.35, 0.55, count)
    angle = rng.uniform(0, math.pi, count)
    pos = rng.uniform(-0.5, 0.5, (count, 2)) * canopy.extent_mm
    t = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    ex = 0.5 * length[:, None] * np.cos(t)  # ellipse in its own axes
    ey = 0.5 * width[:, None] * np.sin(t)
    ca, sa = np.cos(angle)[:, None], np.sin(angle)[:, None]
    a = pos[:, :1] + ca * ex - sa * ey
    b = pos[:, 1:] + sa * ex + ca * ey
    rim = centre + a[..., None] * u + b[..., None] * v  # (count, segments, 3)
    centres = centre + pos[:, :1] * u + pos[:, 1:] * v
    vertices = np.concatenate([centres[:, None, :], rim], axis=1).reshape(-1, 3)
    base = (np.arange(count) * (segments + 1))[:, None]
    k = np.arange(segments)
    faces = np.stack([base + 0 * k, base + 1 + k, base + 1 + (k + 1) % segments], axis=-1)
    return trimesh.Trimesh(vertices, faces.reshape(-1, 3), process=False)

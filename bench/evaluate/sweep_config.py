"""What a sweep is: its axes, levels, base point and pipelines; validated when built.

See :mod:`bench.evaluate.sweeps` for what the axes mean and why the levels are where they are.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from scenes.lighting import get_lighting
from scenes.marker import MarkerSpec, check_dictionary
from scenes.profile import MAX_PSF_SCALE, CameraProfile, ProfileError, load_profile
from scenes.study import MAX_PHI_DEG
from scenes.validation import FieldError

AXES = ("alpha_deg", "phi_deg", "lighting", "blur_px", "read_noise_e", "psf_scale")
NUMERIC_AXES = ("alpha_deg", "phi_deg", "blur_px", "read_noise_e", "psf_scale")
#: The axes whose boundaries are read at the nominal PSF and again at the band's ends: every
#: axis but the lens-sharpness axis, which spans the band itself.
BOUNDARY_AXES = tuple(a for a in AXES if a != "psf_scale")
#: Which levels the lens-sharpness axis takes from the camera's band: its five study levels
#: (:meth:`scenes.profile.Band.psf_levels`) or only its two ends.
PSF_AXIS_CHOICES = ("levels", "ends")
#: Recall at or above this is "detected" (SPEC 4's 95 % of the images).
RECALL_OK = 0.95
#: Margin (px) of the rendered crop around the marker's carrier, as in the detectability study;
#: a motion-blurred crop gets half the blur length more so the smear stays inside it.
CROP_MARGIN_PX = 16


class SweepConfigError(FieldError):
    """A bad sweep setting; ``field`` names the SweepConfig field it concerns."""


@dataclass(frozen=True)
class SweepConfig:
    """The base point, the levels of each axis, and how many seeds and images per level."""

    # --- base point
    base_alpha_deg: float = 40.0
    base_phi_deg: float = 30.0
    base_lighting: str = "sun"
    base_blur_px: float = 0.0
    #: The base point's PSF, times the camera's table as calibrated (the band's own scale).
    base_psf_scale: float = 1.0
    size_mm: float = 13.2
    distance_mm: float = 200.0
    dictionary: str = "4x4_50"
    marker_id: int = 0
    #: The camera twin; its ``sensor.read_noise_e`` is the base point's, the noise axis replaces it.
    camera: CameraProfile = field(default_factory=lambda: load_profile("prototype"))
    # --- axes: each varies one thing from the base point
    alphas_deg: tuple[float, ...] = (
        0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 88.0, 90.0, 91.0, 92.0
    )  # fmt: skip
    alpha_axis_phi_deg: float = 0.0
    phis_deg: tuple[float, ...] = (
        0.0, 10.0, 20.0, 30.0, 35.0, 40.0, 45.0, 50.0, 55.0, 60.0, 70.0
    )  # fmt: skip
    lightings: tuple[str, ...] = ("lab", "sun", "backlit", "canopy")
    blur_px: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)
    read_noise_e: tuple[float, ...] = (3.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0)
    #: The lens-sharpness axis' levels come from ``camera.band`` (:data:`PSF_AXIS_CHOICES`),
    #: never from here: a recalibrated profile moves them.
    psf_axis: str = "levels"
    #: The axes run (a subset of :data:`AXES`): the band ends' reruns take :data:`BOUNDARY_AXES`.
    axes: tuple[str, ...] = AXES
    # --- repetition
    seeds: int = 5
    #: Seeds of each band end's rerun of the boundary axes (:meth:`band_end_sweeps`): fewer than
    #: ``seeds``, since they decide only whether a leader keeps its lead there. At 3 the two
    #: reruns cost about 0.9x the nominal sweep again (paper and locus, default levels, one
    #: worker: 35 s against 39 s; at 5 seeds they would cost 1.5x).
    band_seeds: int = 3
    images: int = 20
    spp: int = 16

    def __post_init__(self) -> None:
        def fail(name: str, message: str) -> None:
            raise SweepConfigError(name, message)

        for name in ("alphas_deg", "phis_deg", "blur_px", "read_noise_e"):
            try:
                values = tuple(float(v) for v in getattr(self, name))
            except (TypeError, ValueError):
                fail(name, f"{getattr(self, name)!r}: must be a sequence of numbers")
            if not values:
                fail(name, "needs at least one level")
            if not all(math.isfinite(v) for v in values):
                fail(name, f"{list(values)}: every level must be finite")
            if len(set(values)) != len(values):
                fail(name, f"{list(values)}: levels must be distinct")
            object.__setattr__(self, name, values)
        lightings = (self.lightings,) if isinstance(self.lightings, str) else self.lightings
        object.__setattr__(self, "lightings", tuple(lightings))
        if not self.lightings:
            fail("lightings", "needs at least one lighting")
        if len(set(self.lightings)) != len(self.lightings):
            fail("lightings", f"{list(self.lightings)}: lightings must be distinct")
        for name, value in [("lightings", n) for n in self.lightings] + [
            ("base_lighting", self.base_lighting)
        ]:
            try:
                get_lighting(value)
            except ValueError as exc:
                fail(name, str(exc))
        axes = (self.axes,) if isinstance(self.axes, str) else tuple(self.axes)
        object.__setattr__(self, "axes", axes)
        if not axes or len(set(axes)) != len(axes) or not set(axes) <= set(AXES):
            fail("axes", f"{list(axes)}: distinct axes among {', '.join(AXES)}, at least one")
        if self.psf_axis not in PSF_AXIS_CHOICES:
            fail("psf_axis", f"{self.psf_axis!r}: choose from {', '.join(PSF_AXIS_CHOICES)}")
        for name in (
            "base_alpha_deg", "base_phi_deg", "base_blur_px", "base_psf_scale", "alpha_axis_phi_deg"
        ):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                fail(name, f"{value!r}: must be a number")
            object.__setattr__(self, name, float(value))

        if not isinstance(self.camera, CameraProfile):
            fail("camera", f"{self.camera!r}: must be a CameraProfile")
        if not 0 <= self.base_psf_scale <= MAX_PSF_SCALE:
            fail("base_psf_scale", f"{self.base_psf_scale:g}: allowed range is 0..10")
        try:  # every PSF scale is set against the table as calibrated
            self.camera.at_psf_scale(self.base_psf_scale)
        except ProfileError as exc:
            fail("camera", str(exc))
        theta_max = self.camera.lens.theta_max_deg
        for name, values in (
            ("alphas_deg", self.alphas_deg),
            ("base_alpha_deg", (self.base_alpha_deg,)),
        ):
            if any(not 0 <= a <= theta_max for a in values):
                fail(name, f"{_show(values)}: allowed range is 0..{theta_max:g} deg (theta_max)")
        for name, values in (
            ("phis_deg", self.phis_deg),
            ("base_phi_deg", (self.base_phi_deg,)),
            ("alpha_axis_phi_deg", (self.alpha_axis_phi_deg,)),
        ):
            if any(not 0 <= p <= MAX_PHI_DEG for p in values):
                fail(name, f"{_show(values)}: allowed range is 0..{MAX_PHI_DEG:g} deg")
        for name, values in (
            ("blur_px", self.blur_px),
            ("base_blur_px", (self.base_blur_px,)),
            ("read_noise_e", self.read_noise_e),
        ):
            if any(not (math.isfinite(v) and v >= 0) for v in values):
                fail(name, f"{_show(values)}: every value must be a finite number >= 0")
        for name in ("size_mm", "distance_mm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                fail(name, f"{value!r}: must be a number > 0 mm")
        for name in ("seeds", "band_seeds", "images", "spp"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                fail(name, f"{value!r}: must be an integer >= 1")
        try:
            object.__setattr__(self, "dictionary", check_dictionary(self.dictionary))
            MarkerSpec(self.dictionary, self.marker_id, self.size_mm)
        except ValueError as exc:
            fail("dictionary", str(exc))

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["camera"] = self.camera.to_json()
        return out

    @property
    def psf_scales(self) -> tuple[float, ...]:
        """The lens-sharpness axis' levels: the camera's band (all its study levels, or its
        ends), in the scale of the table as calibrated, ascending."""
        levels = self.camera.band.psf_levels()
        return levels if self.psf_axis == "levels" else tuple(sorted(set(self.band_ends)))

    @property
    def band_ends(self) -> tuple[float, float]:
        """The camera band's (low, high) PSF scale, as its study levels name them."""
        levels = self.camera.band.psf_levels()
        return levels[0], levels[-1]

    def band_end_sweeps(self) -> tuple[SweepConfig, ...]:
        """The boundary axes rerun with the base point's PSF at each end of the camera's band
        (``band_seeds`` seeds each): where a leader at the nominal PSF must still lead. None
        where the band is the nominal point itself (a profile without a band)."""
        ends = [e for e in dict.fromkeys(self.band_ends) if e != self.base_psf_scale]
        return tuple(
            dataclasses.replace(self, base_psf_scale=e, axes=BOUNDARY_AXES, seeds=self.band_seeds)
            for e in ends
        )

    def points(self) -> list[SweepPoint]:
        """Every (axis, level) of the sweep's axes as the scene and sensor it describes."""
        base = {
            "lighting": self.base_lighting,
            "alpha_deg": self.base_alpha_deg,
            "phi_deg": self.base_phi_deg,
            "blur_px": self.base_blur_px,
            "read_noise_e": float(self.camera.sensor.read_noise_e),
            "psf_scale": self.base_psf_scale,
        }
        # A blurred crop is wider by half the smear; the blur axis renders one crop big enough
        # for its longest smear, shared by its levels.
        base_margin = CROP_MARGIN_PX + math.ceil(self.base_blur_px / 2)
        blur_margin = CROP_MARGIN_PX + math.ceil(max(self.blur_px) / 2)
        levels_of = {
            "alpha_deg": self.alphas_deg,
            "phi_deg": self.phis_deg,
            "lighting": self.lightings,
            "blur_px": self.blur_px,
            "read_noise_e": self.read_noise_e,
            "psf_scale": self.psf_scales,
        }
        points = []
        for axis in self.axes:
            for level in levels_of[axis]:
                values = dict(base, **{axis: level})
                if axis == "alpha_deg":
                    values["phi_deg"] = self.alpha_axis_phi_deg
                margin = blur_margin if axis == "blur_px" else base_margin
                points.append(SweepPoint(axis, level, margin_px=margin, **values))
        return points


#: A smoke-test sweep (``whiskerbench compare --quick``): two or three levels per axis (the
#: band's ends on the lens-sharpness axis), 2 seeds, 1 at the band's ends.
QUICK_SWEEP = SweepConfig(
    alphas_deg=(0.0, 60.0, 90.0),
    phis_deg=(0.0, 40.0, 60.0),
    lightings=("sun", "canopy"),
    blur_px=(0.0, 4.0),
    read_noise_e=(3.0, 200.0),
    psf_axis="ends",
    seeds=2,
    band_seeds=1,
    images=6,
    spp=4,
)


def sweep_options(sweep: SweepConfig) -> list[str]:
    """How ``sweep`` differs from the default, for the comparison's figure titles: ``--quick``
    or ``--seeds N`` as the command line spells them, and the camera and marker family where
    they are not the defaults (``compare`` takes them from the dataset)."""
    default = SweepConfig()
    fitted = {
        "camera": sweep.camera,
        "alphas_deg": sweep.alphas_deg,
        "dictionary": sweep.dictionary,
    }
    options = []
    if sweep.camera != default.camera:
        options.append(f"camera {sweep.camera.name}")
    if sweep.dictionary != default.dictionary:
        options.append(f"family {sweep.dictionary}")
    if sweep == dataclasses.replace(QUICK_SWEEP, **fitted, seeds=sweep.seeds):
        options.append("--quick")
        if sweep.seeds != QUICK_SWEEP.seeds:  # --quick --seeds N
            options.append(f"--seeds {sweep.seeds}")
    elif sweep.seeds != default.seeds:
        options.append(f"--seeds {sweep.seeds}")
    return options


@dataclass(frozen=True)
class SweepPoint:
    """One (axis, level): the marker pose, lighting, blur, noise and lens PSF it is rendered
    with (``psf_scale`` times the camera's table as calibrated)."""

    axis: str
    level: float | str
    lighting: str
    alpha_deg: float
    phi_deg: float
    blur_px: float
    read_noise_e: float
    psf_scale: float
    margin_px: int

    @property
    def render_key(self) -> tuple:
        """Points with the same key share one clean render (per seed)."""
        return (self.lighting, self.alpha_deg, self.phi_deg, self.margin_px)


def _show(values: Iterable[float]) -> str:
    values = list(values)
    return f"{values[0]:g}" if len(values) == 1 else str(values)

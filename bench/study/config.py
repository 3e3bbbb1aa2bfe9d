"""What a detectability study is: its grid, camera, detector and draws (SPEC section 4).

A :class:`StudyConfig` is validated when built, so every later stage can trust it; a
:class:`Cell` is one (lighting, size, alpha, phi) point of the grid with its own seeds.
"""

from __future__ import annotations

import dataclasses
import json
import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from bench.common.manifest import json_sha256
from pipeline.backends import BackendUnavailableError, check_family, get_backend, require
from pipeline.detect import DetectorConfig
from scenes.lighting import get_lighting
from scenes.marker import MarkerSpec, check_dictionary
from scenes.profile import CameraProfile, ProfileError, load_profile
from scenes.study import MAX_PHI_DEG
from scenes.validation import MAX_SEED, FieldError

DEFAULT_SIZES_MM = (8.8, 11.0, 13.2, 17.6)
DEFAULT_ALPHAS_DEG = (0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 90.0)
DEFAULT_PHIS_DEG = tuple(float(p) for p in range(0, 80, 10))
#: Cumulative image counts at which a cell's Wilson interval is checked against 0.95 (report's
#: THRESHOLD). All-detected cells are settled at 80 (the first step whose Wilson lower bound,
#: 80/83.8 = 0.954, clears 0.95), never-detected ones at 10; cells near 0.95 go on to the cap.
IMAGE_STEPS = (10, 30, 80, 160, 240, 400, 800)
#: Corners and poses are computed on a cell's first images only: the images drawn beyond them
#: (near-threshold cells, up to the cap) serve its detection rate, and 80 pose errors per cell
#: already give its median, 95th percentile and maximum.
POSE_IMAGES = 80
#: Farthest marker: 10 m, fifty times the array's 200 mm (a marker there is a few pixels wide).
MAX_DISTANCE_MM = 10_000.0


def alphas_within(alphas: tuple[float, ...], camera: CameraProfile) -> tuple[float, ...]:
    """A default alpha grid fitted to ``camera``: each alpha past its theta_max becomes
    theta_max itself (once), so a lens whose image circle is under 90 deg is studied up to its
    edge, as the default grid studies the prototype's, instead of refused for an option the user
    never gave. A grid within the lens is returned unchanged."""
    theta_max = camera.lens.theta_max_deg
    return tuple(dict.fromkeys(min(a, theta_max) for a in alphas))


class StudyConfigError(FieldError):
    """A bad study setting; ``field`` names the StudyConfig field it concerns."""


@dataclass(frozen=True)
class StudyConfig:
    """Everything that determines the study's numbers (and nothing that does not)."""

    sizes_mm: tuple[float, ...] = DEFAULT_SIZES_MM
    alphas_deg: tuple[float, ...] = DEFAULT_ALPHAS_DEG
    phis_deg: tuple[float, ...] = DEFAULT_PHIS_DEG
    images: int = 240  # cap per cell; fewer once the Wilson interval excludes 0.95
    distance_mm: float = 200.0
    lightings: tuple[str, ...] = ("sun",)
    dictionary: str = "4x4_50"
    marker_id: int = 0
    seed: int = 0
    spp: int = 16
    camera: CameraProfile = field(default_factory=lambda: load_profile("prototype"))
    psf_scales: tuple[float, ...] = (1.0,)
    #: Linear radiance to sensor full scale, times the lighting preset's own exposure.
    exposure: float = 1.0
    #: Tilts are added between the last passing and first failing one until they are this close.
    phi_resolution_deg: float = 2.5
    detector: DetectorConfig = field(default_factory=lambda: DetectorConfig("4x4_50", "subpix"))

    def __post_init__(self) -> None:
        def fail(name: str, message: str) -> None:
            raise StudyConfigError(name, message)

        for name in ("sizes_mm", "alphas_deg", "phis_deg", "lightings", "psf_scales"):
            values = tuple(getattr(self, name))
            if not values:
                fail(name, "needs at least one value")
            if len(set(values)) != len(values):
                fail(name, f"{list(values)}: a value is listed twice")
            object.__setattr__(self, name, values)
        if any(not (math.isfinite(s) and s > 0) for s in self.sizes_mm):
            fail("sizes_mm", f"{list(self.sizes_mm)}: every size must be > 0 mm")
        if any(not (math.isfinite(s) and 0 <= s <= 10) for s in self.psf_scales):
            fail("psf_scales", f"{list(self.psf_scales)}: allowed range is 0..10")
        if len(self.psf_scales) > 1 and 1.0 not in self.psf_scales:
            fail(
                "psf_scales",
                f"{list(self.psf_scales)}: a band needs 1 (the profile's own PSF) among its scales",
            )
        if not isinstance(self.camera, CameraProfile):
            fail("camera", f"{self.camera!r}: must be a CameraProfile")
        theta_max = self.camera.lens.theta_max_deg
        if any(not 0 <= a <= theta_max for a in self.alphas_deg):
            fail(
                "alphas_deg",
                f"{list(self.alphas_deg)}: allowed range is 0..{theta_max:g} deg "
                "(the camera's theta_max)",
            )
        if any(not 0 <= p <= MAX_PHI_DEG for p in self.phis_deg):
            fail("phis_deg", f"{list(self.phis_deg)}: allowed range is 0..{MAX_PHI_DEG:g} deg")
        if (
            isinstance(self.images, bool)  # True is no count (it equals 1)
            or int(self.images) != self.images
            or not 1 <= self.images <= IMAGE_STEPS[-1]
        ):
            fail("images", f"{self.images}: must be an integer in 1..{IMAGE_STEPS[-1]}")
        if not (math.isfinite(self.distance_mm) and 0 < self.distance_mm <= MAX_DISTANCE_MM):
            fail("distance_mm", f"{self.distance_mm}: allowed range is (0, {MAX_DISTANCE_MM:g}] mm")
        if max(self.sizes_mm) > self.distance_mm:
            if self.sizes_mm == DEFAULT_SIZES_MM:  # the default sizes: the distance moved
                fail(
                    "distance_mm",
                    f"{self.distance_mm:g}: closer than the largest marker, "
                    f"{max(self.sizes_mm):g} mm, which would fill the image; allowed range is "
                    f"[{max(self.sizes_mm):g}, {MAX_DISTANCE_MM:g}] mm",
                )
            fail(
                "sizes_mm",
                f"{max(self.sizes_mm):g}: larger than the {self.distance_mm:g} mm distance, the "
                f"marker would fill the image; allowed range is (0, {self.distance_mm:g}] mm",
            )
        if not (isinstance(self.seed, int | np.integer) and 0 <= self.seed <= MAX_SEED):
            fail("seed", f"{self.seed!r}: allowed range is 0..{MAX_SEED}")
        if not (math.isfinite(self.exposure) and 0 < self.exposure <= 1e6):
            fail("exposure", f"{self.exposure}: allowed range is (0, 1e6]")
        if not (math.isfinite(self.phi_resolution_deg) and 0.1 <= self.phi_resolution_deg <= 90):
            fail("phi_resolution_deg", f"{self.phi_resolution_deg}: allowed range is 0.1..90 deg")
        for name in self.lightings:
            try:
                get_lighting(name)
            except ValueError as exc:
                fail("lightings", str(exc))
        try:
            object.__setattr__(self, "dictionary", check_dictionary(self.dictionary))
            MarkerSpec(self.dictionary, self.marker_id, self.sizes_mm[0])
        except ValueError as exc:
            fail("dictionary", str(exc))
        if self.spp < 1:
            fail("spp", f"{self.spp}: must be >= 1")
        try:
            check_family(self.detector.backend, self.dictionary)
        except ValueError as exc:
            fail("dictionary", str(exc))
        if self.detector.dictionary != self.dictionary:
            object.__setattr__(
                self, "detector", dataclasses.replace(self.detector, dictionary=self.dictionary)
            )

    @property
    def detector_label(self) -> str:
        """What found the markers, for titles and messages: ``"locus (apriltag_36h11)"``."""
        return f"{self.detector.backend} ({self.dictionary})"

    def cells(self, phis_deg: tuple[float, ...] | None = None) -> list[Cell]:
        return [
            Cell(lighting, size, alpha, phi)
            for lighting in self.lightings
            for size in self.sizes_mm
            for alpha in self.alphas_deg
            for phi in (self.phis_deg if phis_deg is None else phis_deg)
        ]

    @property
    def nominal_psf_scale(self) -> float:
        """The scale whose images are also refined and posed: 1, or the only scale given."""
        return 1.0 if 1.0 in self.psf_scales else self.psf_scales[0]

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["camera"] = self.camera.to_json()
        return out

    def settings_hash(self) -> str:
        """The hash of the config's JSON, as written: the folder's, and each cell's record's."""
        return json_sha256(json.loads(json.dumps(self.to_json(), default=str)))


@dataclass(frozen=True)
class Cell:
    """One tested geometry; its images exist once per PSF scale."""

    lighting: str
    size_mm: float
    alpha_deg: float
    phi_deg: float

    @property
    def key(self) -> str:
        return f"{self.lighting}_s{self.size_mm:g}_a{self.alpha_deg:g}_p{self.phi_deg:g}"

    def output_name(self, psf_scale: float) -> str:
        return f"{self.key}_x{psf_scale:g}"

    def seed_sequence(self, seed: int, psf_scale: float | None = None) -> np.random.SeedSequence:
        """Seeds depend on the cell itself, not on the grid around it: a cell gives the same
        images whatever else the study contains. The render seed takes no scale (one render
        serves every scale); each scale's noise has its own stream."""
        key = (
            zlib.crc32(self.lighting.encode()),
            *(round(v * 1000) for v in (self.size_mm, self.alpha_deg, self.phi_deg)),
        )
        if psf_scale is not None:
            key = (*key, round(psf_scale * 1000) + 1)
        return np.random.SeedSequence(seed, spawn_key=key)


def detector_from_option(
    cell_px: int, backend: str = "opencv", family: str = "4x4_50"
) -> DetectorConfig:
    """``--detector``, ``--family`` and ``--cell-px``: the study's detector. OpenCV's defaults
    with its ``subpix`` corners (what the original system used) and that bit sampling; a peer
    with its own corners (``"none"``). Refused (StudyConfigError naming the option) in this
    order: an unknown backend, a family it cannot decode, ``--cell-px`` for a peer, a peer that
    is not installed (the message says how to get it)."""
    try:
        get_backend(backend)
    except ValueError as exc:
        raise StudyConfigError("detector", str(exc)) from None
    try:
        family = check_dictionary(family)
        check_family(backend, family)
    except ValueError as exc:
        raise StudyConfigError("dictionary", str(exc)) from None
    if backend != "opencv" and cell_px != DetectorConfig.cell_px:
        raise StudyConfigError("cell_px", f"{cell_px}: applies to --detector opencv only")
    refinement = "subpix" if backend == "opencv" else "none"
    try:
        config = DetectorConfig(family, refinement, cell_px=cell_px, backend=backend)
    except ValueError as exc:
        raise StudyConfigError("cell_px", str(exc)) from None
    try:
        require(backend)
    except BackendUnavailableError as exc:
        raise StudyConfigError("detector", str(exc)) from None
    return config


def profile_from_option(text: str) -> CameraProfile:
    """``--camera``: a shipped profile name or a JSON file; errors name the option."""
    try:
        return load_profile(text)
    except ProfileError as exc:
        raise StudyConfigError("camera", exc.option_detail) from None
    except OSError as exc:  # a name too long for a file, a link loop: the argument's fault
        shown = text if len(text) <= 40 else f"{text[:40]}..."
        raise StudyConfigError("camera", f"{shown}: {exc.strerror or exc}") from None


def nondefault_options(config: StudyConfig) -> list[str]:
    """The command-line options in which ``config`` differs from the default study, as a reader
    would type them (``--sizes 8.8,13.2``), for the figures' titles. The PSF scales and the
    detector are named by the titles themselves; the alphas are default when they are the
    default grid fitted to the camera (:func:`alphas_within`)."""
    default = StudyConfig()

    def nums(values: tuple[float, ...]) -> str:
        return ",".join(f"{v:g}" for v in values)

    differs = (
        ("--camera", config.camera != default.camera, config.camera.name),
        ("--sizes", config.sizes_mm != default.sizes_mm, nums(config.sizes_mm)),
        (
            "--alphas",
            config.alphas_deg != alphas_within(DEFAULT_ALPHAS_DEG, config.camera),
            nums(config.alphas_deg),
        ),
        ("--phis", config.phis_deg != default.phis_deg, nums(config.phis_deg)),
        ("--images", config.images != default.images, str(config.images)),
        ("--distance", config.distance_mm != default.distance_mm, f"{config.distance_mm:g}"),
        ("--lighting", config.lightings != default.lightings, ",".join(config.lightings)),
        ("--family", config.dictionary != default.dictionary, config.dictionary),
        ("--seed", config.seed != default.seed, str(config.seed)),
        ("--spp", config.spp != default.spp, str(config.spp)),
        ("--exposure", config.exposure != default.exposure, f"{config.exposure:g}"),
        (
            "--cell-px",
            config.detector.cell_px != default.detector.cell_px,
            str(config.detector.cell_px),
        ),
    )
    return [f"{flag} {value}" for flag, changed, value in differs if changed]

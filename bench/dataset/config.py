"""What a dataset is: its sample grid, camera, array, sampling and seeds; validated when built."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from pipeline.backends import BACKENDS
from renderers.frame_sampling import FrameSampling, marker_region
from scenes.array import ArraySpec
from scenes.branch_reach import branch_reach_error
from scenes.dynamics import MECHANICS
from scenes.foliage_meshes import DETAIL_LEVELS
from scenes.lighting import lighting_names
from scenes.marker import check_dictionary
from scenes.motion import MotionSpec, MotionSpecError, get_protocol
from scenes.profile import MAX_PSF_SCALE, CameraProfile, load_profile
from scenes.validation import MAX_SEED, FieldError, shown_value
from scenes.vegetation import (
    FOLIAGE_KINDS,
    SAMPLING_PENETRATION_MM,
)

DEFAULT_FOLIAGE = ("soft", "stiff", "sparse", "dense")
DEFAULT_DISTANCES = ("far", "intermediate", "close")
DEFAULT_BRANCHES: tuple[tuple[float, ...], ...] = (
    (),
    (0.0,),
    (50.0,),
    (100.0,),
    (150.0,),
    (0.0, 50.0),
    (0.0, 100.0),
)
DEFAULT_PROTOCOLS = ("indoor", "outdoor")
SAMPLE_FILES = ("video.mp4", "labels.parquet", "camera.json", "preview.mp4")
SEED_NAMES = ("render", "vegetation", "noise")
#: The lead-in holds the array this far (mm) short of the foliage front: no contact.
APPROACH_CLEARANCE_MM = 15.0
#: The camera twin a dataset is recorded through unless the config names another.
DEFAULT_PROFILE = "prototype"
#: Largest exposure multiplier accepted (the study's bound: linear radiance to full scale).
MAX_EXPOSURE = 1e6
#: Largest whisking amplitude: 1 m each side, several times the array's own width.
MAX_AMPLITUDE_MM = 1000.0


def default_profile() -> CameraProfile:
    return load_profile(DEFAULT_PROFILE)


class DatasetConfigError(FieldError):
    """An invalid dataset option; ``field`` names the config field."""


def branches_name(branches_mm: tuple[float, ...]) -> str:
    """'none', '0', '0+50': how a branch configuration appears in ids and on the command line."""
    return "+".join(f"{b:g}" for b in branches_mm) if branches_mm else "none"


def detected_families() -> tuple[str, ...]:
    """The marker families some detector backend decodes (:data:`pipeline.backends.BACKENDS`)."""
    return tuple(sorted({f for backend in BACKENDS.values() for f in backend.families}))


def array_of_family(family: str, array: ArraySpec | None = None) -> ArraySpec:
    """``--family``: the array (default :class:`ArraySpec`) with its markers in ``family``; the
    array itself where that is its family already, so equal settings keep one settings hash.
    DatasetConfigError on ``family`` for one no backend decodes or without the array's ids."""
    array = ArraySpec() if array is None else array
    try:
        name = check_dictionary(family)
    except ValueError as exc:
        raise DatasetConfigError("family", str(exc)) from None
    families = detected_families()
    if name not in families:
        raise DatasetConfigError(
            "family", f"{name}: no detector decodes it; choose from {', '.join(families)}"
        )
    if name == check_dictionary(array.dictionary):
        return array
    try:
        return dataclasses.replace(array, dictionary=name)
    except ValueError as exc:  # an id of the array beyond the family's
        raise DatasetConfigError("family", f"{name}: {exc}") from None


@dataclass(frozen=True)
class SampleSpec:
    """One cell of the grid."""

    foliage: str
    distance: str
    branches_mm: tuple[float, ...]
    protocol: str
    lighting: str

    @property
    def sample_id(self) -> str:
        parts = (self.foliage, self.distance, branches_name(self.branches_mm), self.protocol)
        return "-".join((*parts, self.lighting))

    def seeds(self, seed: int) -> dict[str, int]:
        """The sample's seeds: render jitter and sensor noise its own (from the dataset seed and
        the sample id: independent of which other samples run), the vegetation's the layout
        seed it shares with every sample of its foliage (:meth:`layout_seed`)."""
        sequence = np.random.SeedSequence(seed, spawn_key=(zlib.crc32(self.sample_id.encode()),))
        state = sequence.generate_state(3)
        own = {name: int(v) % 2**31 for name, v in zip(SEED_NAMES, state, strict=True)}
        return {**own, "vegetation": self.layout_seed(seed)}

    def layout_seed(self, seed: int) -> int:
        """The seed that places the strips, leaves and twigs: one per foliage kind and dataset
        seed. As in the lab, one piece of foliage is sampled at every distance, under every
        protocol and lighting, with and without branches, so a branch sample and its no-branch
        twin differ only in the branches (SPEC 3 step 4's threshold comes from the twin)."""
        key = (zlib.crc32(f"layout:{self.foliage}".encode()),)
        return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1)[0]) % 2**31

    def foliage_group(self, seed: int) -> str:
        """The name of the foliage this sample shares with others: ``soft@<layout seed>``."""
        return f"{self.foliage}@{self.layout_seed(seed)}"


@dataclass(frozen=True)
class DatasetConfig:
    """The grid and every rendering choice; validated on construction."""

    foliage: tuple[str, ...] = DEFAULT_FOLIAGE
    distances: tuple[str, ...] = DEFAULT_DISTANCES
    branches: tuple[tuple[float, ...], ...] = DEFAULT_BRANCHES
    protocols: tuple[str, ...] = DEFAULT_PROTOCOLS
    lightings: tuple[str, ...] = ("sun",)
    frames_step: int = 1
    seed: int = 0
    #: The whiskers' mechanics (:data:`scenes.dynamics.MECHANICS`): ``dynamic`` rings after a
    #: release (what SPEC 3's contact rule must reject); ``quasi-static`` is equilibrium only.
    mechanics: str = "dynamic"
    #: How finely the foliage is meshed (:data:`scenes.foliage_meshes.DETAIL_LEVELS`): the
    #: rendered shapes only, never the contacts the mechanics get.
    foliage_detail: str = "default"
    #: Protocol overrides (None keeps the protocol's own value).
    speed_mm_s: float | None = None
    amplitude_mm: float | None = None
    passes: int | None = None
    fps: float | None = None
    exposure_ms: float = 8.0
    #: Linear radiance to sensor full scale, times the lighting preset's own exposure.
    exposure: float = 1.0
    sampling: FrameSampling = field(default_factory=FrameSampling)
    array: ArraySpec = field(default_factory=ArraySpec)
    #: The camera twin: lens geometry (renderer and labels), optics, sensor and stream.
    camera: CameraProfile = field(default_factory=default_profile)
    #: Factor on the twin's PSF widths (1: the table as calibrated): one point of the lens
    #: blur's uncertain band (``camera.band``) per dataset, so a result can be shown at its ends.
    psf_scale: float = 1.0

    def __post_init__(self) -> None:
        for name, allowed in (
            ("foliage", FOLIAGE_KINDS),
            ("distances", tuple(SAMPLING_PENETRATION_MM)),
            ("protocols", ("indoor", "outdoor")),
            ("lightings", tuple(lighting_names())),
        ):
            values = getattr(self, name)
            if not values:
                raise DatasetConfigError(name, "needs at least one value")
            if len(set(values)) != len(values):
                raise DatasetConfigError(name, f"{list(values)}: a value is listed twice")
            bad = [v for v in values if v not in allowed]
            if bad:
                raise DatasetConfigError(
                    name, f"unknown {', '.join(map(repr, bad))}; choose from {', '.join(allowed)}"
                )
        if not self.branches:
            raise DatasetConfigError("branches", "needs at least one configuration")
        if self.foliage_detail not in DETAIL_LEVELS:
            raise DatasetConfigError(
                "foliage_detail",
                f"{self.foliage_detail!r}: unknown; choose from {', '.join(DETAIL_LEVELS)}",
            )
        if self.mechanics not in MECHANICS:
            raise DatasetConfigError(
                "mechanics", f"{self.mechanics!r}: unknown; choose from {', '.join(MECHANICS)}"
            )
        if len({tuple(sorted(b)) for b in self.branches}) != len(self.branches):
            raise DatasetConfigError(
                "branches", f"{list(self.branches)}: a configuration is listed twice"
            )
        a = self.amplitude_mm
        if a is not None and not (isinstance(a, int | float) and 0 < a <= MAX_AMPLITUDE_MM):
            raise DatasetConfigError(
                "amplitude_mm", f"{a!r}: allowed range is (0, {MAX_AMPLITUDE_MM:g}] mm"
            )
        if not (isinstance(self.seed, int | np.integer) and 0 <= self.seed <= MAX_SEED):
            raise DatasetConfigError("seed", f"{self.seed!r}: allowed range is 0..{MAX_SEED}")
        if not isinstance(self.camera, CameraProfile):
            raise DatasetConfigError("camera", f"{self.camera!r}: must be a CameraProfile")
        e = self.exposure
        if not (isinstance(e, int | float) and math.isfinite(e) and 0 < e <= MAX_EXPOSURE):
            raise DatasetConfigError("exposure", f"{e!r}: allowed range is (0, {MAX_EXPOSURE:g}]")
        s = self.psf_scale
        if isinstance(s, bool) or not (
            isinstance(s, int | float) and math.isfinite(s) and 0 < s <= MAX_PSF_SCALE
        ):
            raise DatasetConfigError("psf_scale", f"{s!r}: allowed range is (0, {MAX_PSF_SCALE:g}]")
        object.__setattr__(self, "psf_scale", float(s))
        self._check_lens()
        if not (isinstance(self.frames_step, int) and self.frames_step >= 1):
            raise DatasetConfigError(
                "frames_step", f"must be an integer >= 1, got {self.frames_step}"
            )
        for protocol in self.protocols:
            motion = self.motion(protocol)  # validates the overrides
            if not 0 < self.exposure_ms <= 1000.0 / motion.fps:
                raise DatasetConfigError(
                    "exposure_ms",
                    f"must be in (0, {1000.0 / motion.fps:g}] (one frame at {motion.fps:g} fps), "
                    f"got {self.exposure_ms}",
                )
            for branches in self.branches:
                for distance in self.distances:
                    if not all(math.isfinite(b) for b in branches):
                        raise DatasetConfigError("branches", f"{branches} is not finite")
                    error = branch_reach_error(branches, distance, self.array, motion.amplitude_mm)
                    if error:
                        raise DatasetConfigError(self._reach_culprit(branches, distance), error)

    def _reach_culprit(self, branches: tuple[float, ...], distance: str) -> str:
        """The field to blame for a branch out of reach: a sweep narrowed by ``amplitude_mm``
        when the protocol's own sweep would reach the branch, else the branches."""
        if self.amplitude_mm is None:
            return "branches"
        for protocol in self.protocols:
            own = get_protocol(protocol).amplitude_mm
            if branch_reach_error(branches, distance, self.array, own) is None:
                return "amplitude_mm"
        return "branches"

    def _check_lens(self) -> None:
        """The profile's lens must see every marker at any deflection and make even-sized
        frames (4:2:0 video)."""

        lens = self.camera.lens
        if lens.width_px % 2 or lens.height_px % 2:
            raise DatasetConfigError(
                "camera", f"{lens.width_px}x{lens.height_px} px: the video needs an even size"
            )
        try:
            marker_region(lens, self.array, margin_px=0)
        except ValueError as exc:
            raise DatasetConfigError("camera", f"{self.camera.name}: {exc}") from None

    @property
    def twin(self) -> CameraProfile:
        """The profile the frames are recorded through: ``camera`` with its PSF widths times
        ``psf_scale`` (the profile's own ``psf_scale`` records it in each ``camera.json``)."""
        return self.camera if self.psf_scale == 1 else self.camera.with_psf_scale(self.psf_scale)

    def motion(self, protocol: str, distance: str = "close") -> MotionSpec:
        """The protocol with this config's overrides, withdrawn just clear of the foliage."""
        overrides = {
            "approach_mm": SAMPLING_PENETRATION_MM[distance] + APPROACH_CLEARANCE_MM,
            "speed_mm_s": self.speed_mm_s,
            "amplitude_mm": self.amplitude_mm,
            "passes": self.passes,
            "fps": self.fps,
        }
        own = get_protocol(protocol)
        try:
            return dataclasses.replace(own, **{k: v for k, v in overrides.items() if v is not None})
        except MotionSpecError as exc:
            if exc.field == "lead_in_s" and self.fps is not None:  # the lead-in is no option
                raise DatasetConfigError("fps", self._fps_range(own.lead_in_s)) from None
            raise DatasetConfigError(exc.field, exc.detail) from None

    def _fps_range(self, lead_in_s: float) -> str:
        """Why ``fps`` is too low: the lead-in (the no-contact pose) must hold a frame; the top
        of the range, one exposure a frame, where the exposure is a valid one."""
        e = self.exposure_ms
        valid = isinstance(e, int | float) and math.isfinite(e) and e > 0
        low = f"{1.0 / lead_in_s:g}"
        bound = f"allowed range is {low}..{1000.0 / e:g}" if valid else f"must be at least {low}"
        return (
            f"{shown_value(self.fps)}: {bound} fps (at least one frame in the "
            f"{lead_in_s:g} s lead-in, the no-contact pose"
            + (f"; at most one {e:g} ms exposure a frame)" if valid else ")")
        )

    def samples(self) -> list[SampleSpec]:
        return [
            SampleSpec(f, d, tuple(float(x) for x in b), p, light)
            for light in self.lightings
            for p in self.protocols
            for f in self.foliage
            for d in self.distances
            for b in self.branches
        ]

    def to_json(self) -> dict:
        """Every field as JSON; ``camera`` is the profile's own JSON (name and every stage).
        ``psf_scale`` only where it is not 1 and ``sampling.adaptive`` only where true: a dataset
        made before the option keeps its settings hash and resumes."""
        out = dataclasses.asdict(self)
        out["camera"] = self.camera.to_json()
        if self.psf_scale == 1:
            del out["psf_scale"]
        if not self.sampling.adaptive:
            del out["sampling"]["adaptive"]
        return out

    def settings_hash(self) -> str:
        """Hash of everything but the grid selection: samples made with equal settings match."""
        grid = ("foliage", "distances", "branches", "protocols", "lightings")
        settings = {k: v for k, v in self.to_json().items() if k not in grid}
        return hashlib.sha256(
            json.dumps(settings, sort_keys=True, default=str).encode()
        ).hexdigest()

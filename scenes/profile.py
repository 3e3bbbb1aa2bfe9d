"""A camera profile: everything between the scene's light and the grey image the detector sees.

One versioned JSON format holds the lens geometry (a :class:`~scenes.camera.FisheyeCamera`), the
optics over field angle (relative illumination, an anisotropic point-spread function, lateral
colour), the sensor (colour filter array, full well, read noise, dark signal), the camera's
processing (demosaicing, transfer curve, sharpening) and the stream (MJPEG quality and chroma
subsampling). The renderers read it as plain data; ``renderers.camera_twin`` applies it.

Field tables are sampled at increasing field angles ``theta_deg`` from the optical axis and
interpolated linearly in between (held constant past the ends). Shipped profiles live in
``scenes/profiles/<name>.json``; every number in them carries its source in the ``sources``
map, keyed by the dotted field name (a section name covers every field of that section).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from scenes.bounded_read import input_problem
from scenes.camera import FisheyeCamera, default_camera
from scenes.input_limits import SETTINGS_BYTES
from scenes.validation import FieldError, read_small_json

FORMAT = "whiskerbench-camera-profile"
VERSION = 1
PROFILES_DIR = Path(__file__).with_name("profiles")
CFA_PATTERNS = ("none", "RGGB", "BGGR", "GRBG", "GBRG")
DEMOSAIC_METHODS = ("bilinear", "edge_aware", "vng")
TRANSFER_CURVES = ("srgb", "linear")
CODECS = ("none", "mjpeg")
CHROMA_SUBSAMPLING = ("4:4:4", "4:2:2", "4:2:0")
#: Largest factor on a PSF table (:meth:`PsfTable.scaled`, the band's high end).
MAX_PSF_SCALE = 10.0


class ProfileError(FieldError):
    """A bad camera-profile value; ``field`` is the dotted JSON path (e.g. ``psf.theta_deg``),
    or ``camera`` when the file itself cannot be read."""

    @property
    def option_detail(self) -> str:
        """The message after a ``--camera`` option's name: the profile field where one is at
        fault, else what is wrong with the file."""
        return self.detail if self.field == "camera" else str(self)


def _number(path: str, value: Any, lo: float, hi: float, lo_open: bool = False) -> float:
    """``value`` as a float in [lo, hi] (or (lo, hi] with ``lo_open``), else ProfileError."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise ProfileError(path, f"{value!r}: allowed range is {left}{lo:g}, {hi:g}]")
    return float(value)


def _choice(path: str, value: Any, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ProfileError(path, f"{value!r}: must be one of {', '.join(allowed)}")
    return value


def _table(
    section: str, theta: Any, columns: dict[str, Any], lo: float, hi: float
) -> tuple[tuple[float, ...], dict[str, tuple[float, ...]]]:
    """Validate a field table: strictly increasing angles in [0, 180) and one value per angle."""
    if not isinstance(theta, list | tuple) or not theta:
        raise ProfileError(f"{section}.theta_deg", "needs a non-empty list of angles")
    angles = tuple(_number(f"{section}.theta_deg", t, 0.0, 179.999) for t in theta)
    if any(b <= a for a, b in zip(angles, angles[1:], strict=False)):
        raise ProfileError(f"{section}.theta_deg", f"{list(angles)}: must be strictly increasing")
    out = {}
    for name, values in columns.items():
        path = f"{section}.{name}"
        if not isinstance(values, list | tuple) or len(values) != len(angles):
            raise ProfileError(path, f"needs {len(angles)} values, one per theta_deg")
        out[name] = tuple(_number(path, v, lo, hi) for v in values)
    return angles, out


class _FieldTable:
    """Columns of values over field angle ``theta_deg``: validated, interpolated linearly.

    A subclass is a frozen dataclass naming its JSON section, its value columns, their allowed
    range and the value that means "this stage is off"."""

    SECTION: ClassVar[str]
    COLUMNS: ClassVar[tuple[str, ...]]
    RANGE: ClassVar[tuple[float, float]]
    NEUTRAL: ClassVar[float]

    def __post_init__(self) -> None:
        columns = {name: getattr(self, name) for name in self.COLUMNS}
        angles, values = _table(self.SECTION, self.theta_deg, columns, *self.RANGE)
        object.__setattr__(self, "theta_deg", angles)
        for name, column in values.items():
            object.__setattr__(self, name, column)

    def columns_at(self, theta_deg: np.ndarray) -> tuple[np.ndarray, ...]:
        """Each column at the given field angles (held constant past the table's ends)."""
        at = np.asarray(theta_deg, dtype=float)
        return tuple(np.interp(at, self.theta_deg, getattr(self, c)) for c in self.COLUMNS)

    @property
    def on(self) -> bool:
        return any(v != self.NEUTRAL for c in self.COLUMNS for v in getattr(self, c))


# --- Optics ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RelativeIllumination(_FieldTable):
    """Image irradiance relative to the axis, over field angle (1 = no fall-off)."""

    SECTION, COLUMNS, RANGE, NEUTRAL = "relative_illumination", ("value",), (0.0, 1.0), 1.0
    theta_deg: tuple[float, ...] = (0.0,)
    value: tuple[float, ...] = (1.0,)

    def at(self, theta_deg: np.ndarray) -> np.ndarray:
        return self.columns_at(theta_deg)[0]


@dataclass(frozen=True)
class PsfTable(_FieldTable):
    """Gaussian point-spread widths over field angle, in pixels.

    ``sigma_radial_px`` is the spread along the line from the image centre through the point
    (the meridional or tangential-plane direction of lens design), ``sigma_tangential_px`` the
    spread across it (sagittal). Zero means a sharp (pixel-integrated only) image.
    """

    SECTION, COLUMNS = "psf", ("sigma_radial_px", "sigma_tangential_px")
    RANGE, NEUTRAL = (0.0, 20.0), 0.0
    theta_deg: tuple[float, ...] = (0.0,)
    sigma_radial_px: tuple[float, ...] = (0.0,)
    sigma_tangential_px: tuple[float, ...] = (0.0,)

    def at(self, theta_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sigma_radial_px, sigma_tangential_px) at the given field angles."""
        return self.columns_at(theta_deg)

    def scaled(self, factor: float) -> PsfTable:
        """Every width times ``factor``: the sensitivity band's lever on the uncertain optics."""
        factor = _number("psf_scale", factor, 0.0, MAX_PSF_SCALE)
        return dataclasses.replace(
            self,
            sigma_radial_px=tuple(s * factor for s in self.sigma_radial_px),
            sigma_tangential_px=tuple(s * factor for s in self.sigma_tangential_px),
        )


@dataclass(frozen=True)
class LateralColour(_FieldTable):
    """Red and blue image scale relative to green over field angle (1 = no lateral colour).

    A red scale of 1.001 at 80 degrees puts red light from that field 0.1% farther from the
    image centre than green light from the same point.
    """

    SECTION, COLUMNS = "lateral_colour", ("red_scale", "blue_scale")
    RANGE, NEUTRAL = (0.9, 1.1), 1.0
    theta_deg: tuple[float, ...] = (0.0,)
    red_scale: tuple[float, ...] = (1.0,)
    blue_scale: tuple[float, ...] = (1.0,)

    def at(self, theta_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(red_scale, blue_scale) at the given field angles."""
        return self.columns_at(theta_deg)


# --- Sensor, processing, stream ----------------------------------------------------------------


@dataclass(frozen=True)
class Sensor:
    """The photosites: colour filter pattern (``none``: a grey sensor), well, noise.

    The pattern names the 2 x 2 tile whose top-left photosite is pixel (0, 0) of the full frame
    (OpenCV's naming, e.g. ``RGGB``: row 0 is R G R G ..., row 1 is G B G B ...).
    """

    pixel_pitch_um: float = 2.2
    cfa: str = "none"
    full_well_e: float = 6000.0
    read_noise_e: float = 3.0
    dark_signal_e: float = 0.0

    def __post_init__(self) -> None:
        _number("sensor.pixel_pitch_um", self.pixel_pitch_um, 0.0, 100.0, lo_open=True)
        _choice("sensor.cfa", self.cfa, CFA_PATTERNS)
        _number("sensor.full_well_e", self.full_well_e, 0.0, 1e7, lo_open=True)
        _number("sensor.read_noise_e", self.read_noise_e, 0.0, 1e4)
        _number("sensor.dark_signal_e", self.dark_signal_e, 0.0, 1e6)


@dataclass(frozen=True)
class Processing:
    """What the camera's image processor does after read-out."""

    demosaic: str = "bilinear"
    transfer: str = "srgb"
    sharpen_amount: float = 0.0  # unsharp mask: out = in + amount * (in - blur(in))
    sharpen_sigma_px: float = 1.0

    def __post_init__(self) -> None:
        _choice("processing.demosaic", self.demosaic, DEMOSAIC_METHODS)
        _choice("processing.transfer", self.transfer, TRANSFER_CURVES)
        _number("processing.sharpen_amount", self.sharpen_amount, 0.0, 10.0)
        _number("processing.sharpen_sigma_px", self.sharpen_sigma_px, 0.0, 20.0, lo_open=True)


@dataclass(frozen=True)
class Stream:
    """How frames leave the camera: raw (``none``) or MJPEG at an IJG quality."""

    codec: str = "none"
    quality: int = 90
    chroma_subsampling: str = "4:2:2"

    def __post_init__(self) -> None:
        _choice("stream.codec", self.codec, CODECS)
        q = self.quality
        if not (isinstance(q, int) and not isinstance(q, bool) and 1 <= q <= 100):
            raise ProfileError("stream.quality", f"{q!r}: must be an integer in 1..100")
        _choice("stream.chroma_subsampling", self.chroma_subsampling, CHROMA_SUBSAMPLING)

    @property
    def block_px(self) -> int:
        """Edge of the encoder's MCU: crops start on multiples of it to match a full frame."""
        if self.codec == "none":
            return 1
        return 8 if self.chroma_subsampling == "4:4:4" else 16


# --- The band: what is still uncertain ---------------------------------------------------------


@dataclass(frozen=True)
class Band:
    """The range of the PSF scale the profile's evidence leaves open, as ``[low, high]`` around
    the nominal 1 (the table as written). ``make study``, the comparison's lens-sharpness sweep
    and ``bench pipeline`` run across it; ``whiskerbench camera calibrate`` writes it."""

    psf_scale: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self) -> None:
        ends = self.psf_scale
        if not isinstance(ends, list | tuple) or len(ends) != 2:
            raise ProfileError("band.psf_scale", f"{ends!r}: needs [low, high]")
        low = _number("band.psf_scale", ends[0], 0.0, 1.0)
        high = _number("band.psf_scale", ends[1], 1.0, MAX_PSF_SCALE)
        object.__setattr__(self, "psf_scale", (low, high))

    def psf_levels(self) -> tuple[float, ...]:
        """The band's study levels: low, halfway to 1, 1, halfway to high, high (distinct
        values only, rounded to 4 decimals so they name cell files stably)."""
        low, high = self.psf_scale
        levels = (low, (low + 1) / 2, 1.0, (1 + high) / 2, high)
        return tuple(sorted({round(v, 4) for v in levels}))

    @property
    def psf_ends(self) -> tuple[float, float]:
        return self.psf_scale


# --- The profile -------------------------------------------------------------------------------

_SECTIONS = {
    "relative_illumination": RelativeIllumination,
    "psf": PsfTable,
    "lateral_colour": LateralColour,
    "sensor": Sensor,
    "processing": Processing,
    "stream": Stream,
    "band": Band,
}


@dataclass(frozen=True)
class CameraProfile:
    """A camera twin: lens geometry plus every optics, sensor and stream stage, as plain data."""

    name: str = "ideal"
    description: str = ""
    lens: FisheyeCamera = field(default_factory=default_camera)
    relative_illumination: RelativeIllumination = field(default_factory=RelativeIllumination)
    psf: PsfTable = field(default_factory=PsfTable)
    lateral_colour: LateralColour = field(default_factory=LateralColour)
    sensor: Sensor = field(default_factory=Sensor)
    processing: Processing = field(default_factory=Processing)
    stream: Stream = field(default_factory=Stream)
    band: Band = field(default_factory=Band)
    sources: dict[str, str] = field(default_factory=dict)
    #: The factor ``psf`` carries over the table the band is stated around, so a scaled profile
    #: written out (a dataset's ``camera.json`` at ``--psf-scale``) still says where its band
    #: lies; left out of the JSON at 1 (files and hashes as before).
    psf_scale: float = 1.0

    def __post_init__(self) -> None:
        scale = _number("psf_scale", self.psf_scale, 0.0, MAX_PSF_SCALE**2)
        object.__setattr__(self, "psf_scale", scale)

    @property
    def crop_grid_px(self) -> int:
        """Crops start and end on this grid: the MJPEG blocks and the 2 x 2 Bayer tile, so a
        crop sees the full frame's blocks and colour phase."""
        tile = 2 if self.sensor.cfa != "none" else 1
        return math.lcm(self.stream.block_px, tile)

    def with_psf_scale(self, factor: float) -> CameraProfile:
        """Every PSF width times ``factor`` (0..10), on top of any scale the profile carries."""
        psf = self.psf.scaled(factor)
        return dataclasses.replace(self, psf=psf, psf_scale=self.psf_scale * factor)

    def at_psf_scale(self, scale: float) -> CameraProfile:
        """The profile with its PSF ``scale`` times the table as calibrated: the scale the
        band's levels are stated in, whatever scale this profile already carries."""
        if scale == self.psf_scale:
            return self
        if self.psf_scale == 0:
            raise ProfileError("psf_scale", "0: a zero PSF cannot be scaled back to the table")
        psf = self.psf.scaled(scale / self.psf_scale)
        return dataclasses.replace(self, psf=psf, psf_scale=float(scale))

    def with_lens(self, lens: FisheyeCamera) -> CameraProfile:
        return dataclasses.replace(self, lens=lens)

    # --- JSON
    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": FORMAT,
            "version": VERSION,
            "name": self.name,
            "description": self.description,
            "lens": self.lens.to_dict(),
        }
        for key in _SECTIONS:
            section = dataclasses.asdict(getattr(self, key))
            out[key] = {k: list(v) if isinstance(v, tuple) else v for k, v in section.items()}
        out["sources"] = dict(self.sources)
        if self.psf_scale != 1:
            out["psf_scale"] = self.psf_scale
        return out

    @classmethod
    def from_json(cls, data: Any) -> CameraProfile:
        """Parse and validate a profile; ProfileError names the first bad field.

        A bare camera file (``{"model": {...}}``, what ``FisheyeCamera.to_dict`` writes) is read
        as a profile with that lens and ideal optics, sensor and stream.
        """
        if not isinstance(data, dict):
            raise ProfileError("profile", "must be a JSON object")
        if "format" not in data and "model" in data:
            return cls(name="camera", lens=_lens(data))
        if data.get("format") != FORMAT:
            raise ProfileError("format", f"{data.get('format')!r}: must be {FORMAT!r}")
        if data.get("version") != VERSION:
            raise ProfileError(
                "version", f"{data.get('version')!r}: this whiskerbench reads version {VERSION}"
            )
        known = {"format", "version", "name", "description", "lens", "sources", "psf_scale"}
        known |= set(_SECTIONS)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ProfileError(unknown[0], f"unknown field; allowed: {', '.join(sorted(known))}")
        if "lens" not in data:
            raise ProfileError("lens", "missing: a profile needs its lens geometry")
        kwargs: dict[str, Any] = {"lens": _lens(data["lens"])}
        for key, section_cls in _SECTIONS.items():
            if key in data:
                kwargs[key] = _section(key, section_cls, data[key])
        name = data.get("name", "camera")
        if not isinstance(name, str) or not name:
            raise ProfileError("name", f"{name!r}: must be a non-empty string")
        description = data.get("description", "")
        if not isinstance(description, str):
            raise ProfileError("description", f"{description!r}: must be a string")
        sources = data.get("sources", {})
        if not isinstance(sources, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in sources.items()
        ):
            raise ProfileError("sources", "must map field names to source strings")
        scale = data.get("psf_scale", 1.0)
        return cls(
            name=name, description=str(description), sources=sources, psf_scale=scale, **kwargs
        )


def _lens(data: Any) -> FisheyeCamera:
    if not isinstance(data, dict):
        raise ProfileError("lens", "must be a JSON object")
    try:
        return FisheyeCamera.from_dict(data)
    except (ValueError, TypeError) as exc:
        raise ProfileError("lens", str(exc)) from None


def _section(key: str, section_cls: type, data: Any):
    if not isinstance(data, dict):
        raise ProfileError(key, "must be a JSON object")
    names = {f.name for f in dataclasses.fields(section_cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        allowed = ", ".join(sorted(names))
        raise ProfileError(f"{key}.{unknown[0]}", f"unknown field; allowed: {allowed}")
    try:
        return section_cls(**data)
    except ProfileError:
        raise
    except (ValueError, TypeError) as exc:
        raise ProfileError(key, str(exc)) from None


def shipped_profiles() -> tuple[str, ...]:
    """The names :func:`load_profile` accepts for the profiles shipped in ``PROFILES_DIR``."""
    return tuple(sorted(p.stem for p in PROFILES_DIR.glob("*.json")))


#: Largest profile file read: real ones are a few kB; this bounds memory on a hostile input.
MAX_PROFILE_BYTES = SETTINGS_BYTES


def profile_path(name_or_path: str | Path) -> Path:
    """The file a shipped profile's name or a profile/camera JSON path stands for."""
    text = str(name_or_path)
    path = PROFILES_DIR / f"{text}.json" if text in shipped_profiles() else Path(text)
    if not path.is_file():  # a named pipe or a link loop is there, not missing: say so
        why, names = input_problem(path), ", ".join(shipped_profiles())
        missing = f" is neither a shipped profile ({names}) nor a readable JSON file"
        raise ProfileError("camera", f"{text!r}: {why}" if why else f"{text!r}{missing}")
    return path


def load_profile(name_or_path: str | Path) -> CameraProfile:
    """A shipped profile by name (``ideal``, ``prototype``) or a profile/camera JSON file."""
    path = profile_path(name_or_path)
    return CameraProfile.from_json(read_small_json(path, MAX_PROFILE_BYTES, ProfileError, "camera"))

"""What a real sensor is known to have done, as plain data: the evidence a camera twin's uncertain
numbers are calibrated against (``whiskerbench camera calibrate``).

One versioned JSON format (:data:`FORMAT`, :data:`VERSION`). Each observation names where it
comes from (``source``: the sentence of the record it encodes), what was looked at and by which
detector, and the outcome that was seen. Three kinds:

``marker``
    single markers of one size and family at a region of the study's cells (``alpha_deg`` x
    ``phi_deg`` at ``distance_mm`` in a ``lighting``), detected in at least ``min_rate`` (and,
    optionally, at most ``max_rate``) of the images, as the detectability study measures it;
``array_rest``
    the whole array, still, before contact: every marker read in at least ``min_rate`` of the
    frames (the pipeline takes each whisker's no-contact pose there);
``array_sampling``
    the array sampling foliage (``sample``: protocol, foliage, distance, branches): every marker
    read in at least ``min_rate`` of the frames spread over the sample.

Where the record is silent (a rig's light, a distance, what "read" means as a rate) the value
used is an assumption: ``assumptions`` names the field, why that value was taken and the
alternatives the calibration reruns with, so its report shows how far the answer moves.
Validation names the observation and field at fault (:class:`ObservationError`); a region is
checked against a lens with :func:`check_against_lens` once the camera is known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from scenes.bounded_read import input_problem
from scenes.camera import FisheyeCamera
from scenes.input_limits import SETTINGS_BYTES
from scenes.marker import check_dictionary
from scenes.study import MAX_PHI_DEG
from scenes.validation import FieldError, read_small_json

FORMAT = "whiskerbench-observations"
VERSION = 1
OBSERVATIONS_DIR = Path(__file__).with_name("observations")
KINDS = ("marker", "array_rest", "array_sampling")
#: Largest observations file read: real ones are a few kB.
MAX_BYTES = SETTINGS_BYTES
#: Most observations, alternatives and region cells: each one costs renders in calibration.
MAX_OBSERVATIONS = 32
MAX_ALTERNATIVES = 4
MAX_CELLS = 64
#: Most frames an array observation looks at (each is rendered once).
MAX_FRAMES = 200
#: Fields an assumption may name, per kind (the fields a calibration can rerun with another value).
ASSUMABLE = {
    "marker": ("lighting", "distance_mm", "min_rate"),
    "array_rest": ("lighting", "min_rate"),
    "array_sampling": ("lighting", "min_rate", "foliage", "distance"),
}
_COMMON = {"id", "kind", "source", "detector", "lighting", "min_rate", "max_rate", "assumptions"}
_FIELDS = {
    "marker": _COMMON | {"size_mm", "family", "distance_mm", "alpha_deg", "phi_deg"},
    "array_rest": _COMMON | {"protocol", "frames"},
    "array_sampling": _COMMON | {"protocol", "foliage", "distance", "branches_mm", "frames"},
}


class ObservationError(FieldError):
    """A bad observations file; ``field`` is ``observations[i].name`` or the top-level key."""


@dataclass(frozen=True)
class Assumption:
    """A value the record does not give: what was taken, why, and what else to try."""

    field: str
    why: str
    alternatives: tuple[Any, ...]


@dataclass(frozen=True)
class Observation:
    """One thing the real sensor did; fields a kind does not use keep their defaults."""

    id: str
    kind: str
    source: str
    detector: str
    lighting: str
    min_rate: float
    max_rate: float = 1.0
    assumptions: tuple[Assumption, ...] = ()
    # marker
    size_mm: float = 0.0
    family: str = "4x4_50"
    distance_mm: float = 200.0
    alpha_deg: tuple[float, ...] = ()
    phi_deg: tuple[float, ...] = ()
    # array
    protocol: str = "indoor"
    foliage: str = "soft"
    distance: str = "intermediate"
    branches_mm: tuple[float, ...] = ()
    frames: int = 30

    def with_value(self, name: str, value: Any) -> Observation:
        """This observation with one assumed field replaced (validated as in the file)."""
        data = self.to_json()
        data[name] = value
        return parse_observation(data, f"{self.id}.{name}")

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "id": self.id,
            "kind": self.kind,
            "source": self.source,
            "detector": self.detector,
            "lighting": self.lighting,
            "min_rate": self.min_rate,
        }
        if self.max_rate < 1.0:
            out["max_rate"] = self.max_rate
        for name in sorted(_FIELDS[self.kind] - set(out) - {"assumptions", "max_rate"}):
            value = getattr(self, name)
            out[name] = list(value) if isinstance(value, tuple) else value
        out["assumptions"] = [
            {"field": a.field, "why": a.why, "alternatives": list(a.alternatives)}
            for a in self.assumptions
        ]
        return out


@dataclass(frozen=True)
class Observations:
    """A sensor's observations, in file order."""

    sensor: str
    description: str
    observations: tuple[Observation, ...] = field(default_factory=tuple)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "sensor": self.sensor,
            "description": self.description,
            "observations": [o.to_json() for o in self.observations],
        }

    def replaced(self, index: int, observation: Observation) -> Observations:
        items = list(self.observations)
        items[index] = observation
        return replace(self, observations=tuple(items))


def _text(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ObservationError(where, f"{value!r}: must be a non-empty string")
    return value


def _description(value: Any) -> str:
    """Free text, optional (empty when absent), but text: not a number passed off as one."""
    if not isinstance(value, str):
        raise ObservationError("description", f"{value!r}: must be a string")
    return value


def _number(where: str, value: Any, lo: float, hi: float, lo_open: bool = False) -> float:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise ObservationError(where, f"{value!r}: allowed range is {left}{lo:g}, {hi:g}]")
    return float(value)


def _numbers(where: str, value: Any, lo: float, hi: float) -> tuple[float, ...]:
    if not isinstance(value, list) or not value or len(value) > MAX_CELLS:
        raise ObservationError(where, f"needs a list of 1..{MAX_CELLS} numbers")
    out = tuple(_number(where, v, lo, hi) for v in value)
    if len(set(out)) != len(out):
        raise ObservationError(where, f"{list(out)}: a value is listed twice")
    return out


def _lighting(where: str, value: Any) -> str:
    from scenes.lighting import get_lighting

    try:
        get_lighting(_text(where, value))
    except ValueError as exc:
        raise ObservationError(where, str(exc)) from None
    return value


def _choice(where: str, value: Any, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ObservationError(where, f"{value!r}: must be one of {', '.join(allowed)}")
    return value


def _assumption(where: str, data: Any, kind: str) -> Assumption:
    if not isinstance(data, dict) or set(data) - {"field", "why", "alternatives"}:
        raise ObservationError(where, "must be an object with field, why and alternatives only")
    name = _choice(f"{where}.field", data.get("field"), ASSUMABLE[kind])
    alternatives = data.get("alternatives")
    if not isinstance(alternatives, list) or not 1 <= len(alternatives) <= MAX_ALTERNATIVES:
        raise ObservationError(f"{where}.alternatives", f"needs 1..{MAX_ALTERNATIVES} values")
    return Assumption(name, _text(f"{where}.why", data.get("why")), tuple(alternatives))


def parse_observation(data: Any, where: str) -> Observation:
    """One observation from its JSON object; ObservationError names ``where`` and the field."""
    from scenes.vegetation import FOLIAGE_KINDS, SAMPLING_PENETRATION_MM

    if not isinstance(data, dict):
        raise ObservationError(where, "must be a JSON object")
    kind = _choice(f"{where}.kind", data.get("kind"), KINDS)
    unknown = sorted(set(data) - _FIELDS[kind])
    if unknown:
        allowed = ", ".join(sorted(_FIELDS[kind]))
        raise ObservationError(f"{where}.{unknown[0]}", f"unknown field; allowed: {allowed}")
    for name in ("id", "source", "detector", "lighting", "min_rate"):
        if name not in data:
            raise ObservationError(f"{where}.{name}", "missing")
    min_rate = _number(f"{where}.min_rate", data["min_rate"], 0.0, 1.0, lo_open=True)
    max_rate = _number(f"{where}.max_rate", data.get("max_rate", 1.0), 0.0, 1.0)
    if max_rate < min_rate:
        raise ObservationError(f"{where}.max_rate", f"{max_rate:g}: below min_rate {min_rate:g}")
    kwargs: dict[str, Any] = {
        "id": _text(f"{where}.id", data["id"]),
        "kind": kind,
        "source": _text(f"{where}.source", data["source"]),
        "detector": _text(
            f"{where}.detector", data["detector"]
        ),  # a pipeline name: bench checks it
        "lighting": _lighting(f"{where}.lighting", data["lighting"]),
        "min_rate": min_rate,
        "max_rate": max_rate,
    }
    if kind == "marker":
        for name in ("size_mm", "alpha_deg", "phi_deg"):
            if name not in data:
                raise ObservationError(f"{where}.{name}", "missing")
        distance = _number(
            f"{where}.distance_mm", data.get("distance_mm", 200.0), 0.0, 10_000.0, lo_open=True
        )
        kwargs["distance_mm"] = distance
        kwargs["size_mm"] = _number(f"{where}.size_mm", data["size_mm"], 0.0, distance, True)
        try:
            kwargs["family"] = check_dictionary(data.get("family", "4x4_50"))
        except ValueError as exc:
            raise ObservationError(f"{where}.family", str(exc)) from None
        kwargs["alpha_deg"] = _numbers(f"{where}.alpha_deg", data["alpha_deg"], 0.0, 180.0)
        kwargs["phi_deg"] = _numbers(f"{where}.phi_deg", data["phi_deg"], 0.0, MAX_PHI_DEG)
    else:
        kwargs["protocol"] = _choice(
            f"{where}.protocol", data.get("protocol", "indoor"), ("indoor", "outdoor")
        )
        frames = data.get("frames", 30)
        if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= MAX_FRAMES:
            raise ObservationError(
                f"{where}.frames", f"{frames!r}: must be an integer in 1..{MAX_FRAMES}"
            )
        kwargs["frames"] = frames
    if kind == "array_sampling":
        kwargs["foliage"] = _choice(f"{where}.foliage", data.get("foliage"), tuple(FOLIAGE_KINDS))
        kwargs["distance"] = _choice(
            f"{where}.distance", data.get("distance"), tuple(SAMPLING_PENETRATION_MM)
        )
        branches = data.get("branches_mm", [])
        if not isinstance(branches, list) or len(branches) > 4:
            raise ObservationError(f"{where}.branches_mm", "needs a list of at most 4 offsets")
        kwargs["branches_mm"] = tuple(
            _number(f"{where}.branches_mm", b, -1000.0, 1000.0) for b in branches
        )
    assumptions = data.get("assumptions", [])
    if not isinstance(assumptions, list) or len(assumptions) > len(ASSUMABLE[kind]):
        raise ObservationError(f"{where}.assumptions", "needs a list, one entry per field at most")
    parsed = tuple(
        _assumption(f"{where}.assumptions[{i}]", a, kind) for i, a in enumerate(assumptions)
    )
    if len({a.field for a in parsed}) != len(parsed):
        raise ObservationError(f"{where}.assumptions", "a field is assumed twice")
    observation = Observation(**kwargs, assumptions=parsed)
    for i, assumption in enumerate(parsed):  # every alternative must itself be valid
        for value in assumption.alternatives:
            data_alt = dict(data, **{assumption.field: value}, assumptions=[])
            parse_observation(data_alt, f"{where}.assumptions[{i}].alternatives")
    return observation


def parse_observations(data: Any) -> Observations:
    """A whole file's JSON; ObservationError names the first bad field."""
    if not isinstance(data, dict):
        raise ObservationError("observations", "the file must hold a JSON object")
    if data.get("format") != FORMAT:
        raise ObservationError("format", f"{data.get('format')!r}: must be {FORMAT!r}")
    if data.get("version") != VERSION:
        raise ObservationError(
            "version", f"{data.get('version')!r}: this whiskerbench reads version {VERSION}"
        )
    known = {"format", "version", "sensor", "description", "observations"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ObservationError(unknown[0], f"unknown field; allowed: {', '.join(sorted(known))}")
    items = data.get("observations")
    if not isinstance(items, list) or not 1 <= len(items) <= MAX_OBSERVATIONS:
        raise ObservationError(
            "observations", f"needs a list of 1..{MAX_OBSERVATIONS} observations"
        )
    parsed = tuple(parse_observation(o, f"observations[{i}]") for i, o in enumerate(items))
    ids = [o.id for o in parsed]
    if len(set(ids)) != len(ids):
        raise ObservationError("observations", f"ids must be distinct: {ids}")
    return Observations(
        _text("sensor", data.get("sensor")), _description(data.get("description", "")), parsed
    )


def observations_path(name_or_path: str | Path) -> Path:
    """A shipped file by sensor name (``prototype``) or a path."""
    text = str(name_or_path)
    shipped = OBSERVATIONS_DIR / f"{text}.json"
    path = shipped if shipped.is_file() else Path(text)
    if not path.is_file():
        why = input_problem(path) or "not a readable file"  # a named pipe is there, not missing
        raise ObservationError("observations", f"{text!r}: {why}")
    return path


def load_observations(name_or_path: str | Path) -> Observations:
    """Read and validate an observations file, bounded before it is parsed."""
    path = observations_path(name_or_path)
    return parse_observations(read_small_json(path, MAX_BYTES, ObservationError, "observations"))


def check_against_lens(observations: Observations, lens: FisheyeCamera) -> None:
    """Refuse a region the lens cannot see: alpha beyond its image circle."""
    for i, o in enumerate(observations.observations):
        if o.kind == "marker" and max(o.alpha_deg) > lens.theta_max_deg:
            raise ObservationError(
                f"observations[{i}].alpha_deg",
                f"{list(o.alpha_deg)}: allowed range is 0..{lens.theta_max_deg:g} deg "
                "(the camera's theta_max)",
            )

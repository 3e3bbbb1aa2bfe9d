"""Calibrate a camera twin's estimated numbers against what the real sensor is known to do.

For one parameter the profile marks as an estimate (:data:`PARAMS`), each observation's
interval of consistent values is found by bisection: a few probes over the search range find a
consistent value and bracket its edges, then each edge is halved to ``tolerance``. The
profile's interval is the intersection over observations. A side that no observation bounds
stays at the search range's end and says which limit closed it (for the PSF scale: diffraction
at the lens's f-number below, the search cap above). An empty intersection is reported as
such, never widened. Each assumption an observation makes is rerun with its alternatives, and
the report shows how the interval moves.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from scenes.observations import Observation, Observations
from scenes.profile import CameraProfile

#: Wavelength (um) of the diffraction limit: the middle of the visible band, where the green
#: channel that dominates the grey image peaks.
WAVELENGTH_UM = 0.55
#: Gaussian sigma of an Airy pattern: 0.42 lambda N (Zhang, Zerubia & Olivo-Marin, "Gaussian
#: approximations of fluorescence microscope point-spread function models", Appl. Opt. 2007:
#: sigma = 0.21 lambda / NA, NA = 1 / 2N).
AIRY_SIGMA_PER_LAMBDA_N = 0.42
#: The lens's f-number where the profile has none: F/2 is the fast end of the F/2-F/2.8 range
#: of small fisheyes (docs/prototype_camera.md section 3), the smaller (more permissive) limit.
DEFAULT_F_NUMBER = 2.0
#: Probes per search range before bisection, and the default resolution of an edge.
PROBES = 5
DEFAULT_TOLERANCE = 0.02
#: The rule that places the nominal value inside the interval.
NOMINAL_RULE = "centre"


class CalibrationInputError(ValueError):
    """A parameter that cannot be calibrated on this profile; the message names it."""


@dataclass(frozen=True)
class Param:
    """A calibratable number: the profile source key that must mark it an estimate, how a trial
    value is applied, its search range's upper end and what closes the range at each end."""

    name: str
    source_key: str
    apply: Callable[[CameraProfile, float], CameraProfile]
    search_high: float
    low_limit: str
    high_limit: str


def _with_read_noise(profile: CameraProfile, value: float) -> CameraProfile:
    return dataclasses.replace(
        profile, sensor=dataclasses.replace(profile.sensor, read_noise_e=value)
    )


def _with_dark_signal(profile: CameraProfile, value: float) -> CameraProfile:
    return dataclasses.replace(
        profile, sensor=dataclasses.replace(profile.sensor, dark_signal_e=value)
    )


PARAMS = {
    "psf_scale": Param(
        "psf_scale",
        "psf",
        CameraProfile.with_psf_scale,
        3.0,
        "diffraction at the lens's f-number",
        "the search cap (3x the table, twice the literature range's 1.49x)",
    ),
    "read_noise_e": Param(
        "read_noise_e",
        "sensor.read_noise_e",
        _with_read_noise,
        400.0,
        "zero noise",
        "the search cap (400 e-, where the sweeps lose every marker)",
    ),
    "dark_signal_e": Param(
        "dark_signal_e",
        "sensor.dark_signal_e",
        _with_dark_signal,
        1000.0,
        "zero dark signal",
        "the search cap (1000 e-)",
    ),
}
#: Source texts that mark a number as open to calibration.
ESTIMATE_PREFIXES = ("Estimate", "Calibrated")


def check_param(profile: CameraProfile, name: str) -> Param:
    """The parameter, if the profile marks it as an estimate; CalibrationInputError otherwise."""
    if name not in PARAMS:
        raise CalibrationInputError(f"{name!r}: unknown; calibratable: {', '.join(PARAMS)}")
    param = PARAMS[name]
    source = profile.sources.get(param.source_key, "")
    if not source.startswith(ESTIMATE_PREFIXES):
        said = f"its source says {source[:60]!r}..." if source else "it has no source"
        raise CalibrationInputError(
            f"{name!r}: profile {profile.name!r} does not mark {param.source_key} as an "
            f"estimate ({said}); only estimates are calibrated, sourced numbers stay sourced"
        )
    return param


def diffraction_scale(profile: CameraProfile, f_number: float) -> float:
    """The PSF scale at which the table's sharpest width equals diffraction's at ``f_number``."""
    sigma_px = AIRY_SIGMA_PER_LAMBDA_N * WAVELENGTH_UM * f_number / profile.sensor.pixel_pitch_um
    sharpest = min(min(profile.psf.sigma_radial_px), min(profile.psf.sigma_tangential_px))
    if sharpest <= 0:
        raise CalibrationInputError("psf_scale: the profile's PSF table is zero (a sharp lens)")
    return sigma_px / sharpest


def search_range(profile: CameraProfile, param: Param, f_number: float) -> tuple[float, float]:
    low = diffraction_scale(profile, f_number) if param.name == "psf_scale" else 0.0
    return low, param.search_high


@dataclass(frozen=True)
class Interval:
    """Values consistent with one observation (or all): ``None`` ends mean empty."""

    low: float | None
    high: float | None
    low_open: bool = False  # True: consistent down to the search range's end
    high_open: bool = False
    notes: tuple[str, ...] = ()
    trials: tuple[tuple[float, bool, str], ...] = field(default=(), compare=False)

    @property
    def empty(self) -> bool:
        return self.low is None or self.high is None or self.low > self.high

    def __and__(self, other: Interval) -> Interval:
        if self.empty or other.empty:
            return Interval(None, None, notes=self.notes + other.notes)
        low, high = max(self.low, other.low), min(self.high, other.high)
        low_open = self.low_open and other.low_open
        high_open = self.high_open and other.high_open
        if low > high:
            return Interval(None, None, notes=self.notes + other.notes)
        return Interval(low, high, low_open, high_open, self.notes + other.notes)

    def to_json(self) -> dict:
        return {
            "low": self.low,
            "high": self.high,
            "low_open": self.low_open,
            "high_open": self.high_open,
            "empty": self.empty,
            "notes": list(self.notes),
        }


Checker = Callable[[float], tuple[bool, str]]


def bisect_interval(
    check: Checker, low: float, high: float, tolerance: float = DEFAULT_TOLERANCE
) -> Interval:
    """The interval of values ``check`` accepts in [low, high].

    Probes :data:`PROBES` evenly spaced values, takes the span from the lowest to the highest
    accepted probe, and bisects each edge against its rejected neighbour until the two are
    ``tolerance`` apart (the accepted side is reported). No accepted probe: empty. A rejected
    probe between accepted ones is noted (the observation is not monotone there)."""
    trials: list[tuple[float, bool, str]] = []

    def test(value: float) -> bool:
        ok, detail = check(value)
        trials.append((value, ok, detail))
        return ok

    probes = [low + (high - low) * i / (PROBES - 1) for i in range(PROBES)]
    results = [test(v) for v in probes]
    accepted = [i for i, ok in enumerate(results) if ok]
    if not accepted:
        return Interval(None, None, notes=("no probe consistent",), trials=tuple(trials))
    first, last = accepted[0], accepted[-1]
    notes = []
    if len(accepted) != last - first + 1:
        gaps = [f"{probes[i]:.3g}" for i in range(first, last) if not results[i]]
        notes.append(f"not monotone: rejected at {', '.join(gaps)} between accepted values")

    def edge(good: float, bad: float) -> float:
        while abs(bad - good) > tolerance:
            middle = (good + bad) / 2
            good, bad = (middle, bad) if test(middle) else (good, middle)
        return good

    lo = probes[first] if first == 0 else edge(probes[first], probes[first - 1])
    hi = probes[last] if last == PROBES - 1 else edge(probes[last], probes[last + 1])
    return Interval(lo, hi, first == 0, last == PROBES - 1, tuple(notes), tuple(trials))


@dataclass(frozen=True)
class Calibration:
    """The answer: per observation its interval, the intersection, the nominal, and how each
    assumption's alternatives move the intersection."""

    param: str
    search: tuple[float, float]
    per_observation: dict[str, Interval]
    interval: Interval
    nominal: float | None
    alternatives: list[dict]
    limits: dict[str, str]

    def to_json(self) -> dict:
        return {
            "param": self.param,
            "search_range": list(self.search),
            "limits": self.limits,
            "per_observation": {k: v.to_json() for k, v in self.per_observation.items()},
            "trials": {
                k: [{"value": t[0], "consistent": t[1], "worst": t[2]} for t in v.trials]
                for k, v in self.per_observation.items()
            },
            "interval": self.interval.to_json(),
            "nominal": self.nominal,
            "nominal_rule": NOMINAL_RULE,
            "assumptions": self.alternatives,
        }


def nominal_of(interval: Interval) -> float | None:
    """The rule: the interval's centre."""
    return None if interval.empty else (interval.low + interval.high) / 2


def calibrate(
    profile: CameraProfile,
    observations: Observations,
    param_name: str,
    checker_of: Callable[[Observation], Checker],
    f_number: float = DEFAULT_F_NUMBER,
    tolerance: float = DEFAULT_TOLERANCE,
    assumptions: bool = True,
    progress: Callable[[str], None] = lambda text: None,
) -> Calibration:
    """Every observation's interval, their intersection and the assumptions' effect.

    ``checker_of(observation)`` gives the function that tells whether a trial value is
    consistent with that observation (:func:`bench.twin.run.checker_of` renders once)."""
    param = check_param(profile, param_name)
    low, high = search_range(profile, param, f_number)
    per: dict[str, Interval] = {}
    for observation in observations.observations:
        progress(f"observation {observation.id}")
        per[observation.id] = bisect_interval(checker_of(observation), low, high, tolerance)
    interval = _intersect(per.values())
    moved = []
    for observation in observations.observations if assumptions else ():
        for assumption in observation.assumptions:
            for value in assumption.alternatives:
                progress(f"observation {observation.id}: {assumption.field} = {value}")
                changed = observation.with_value(assumption.field, value)
                alone = bisect_interval(checker_of(changed), low, high, tolerance)
                others = [v for k, v in per.items() if k != observation.id]
                moved.append(
                    {
                        "observation": observation.id,
                        "field": assumption.field,
                        "assumed": getattr(observation, assumption.field),
                        "alternative": value,
                        "why": assumption.why,
                        "observation_interval": alone.to_json(),
                        "interval": _intersect([alone, *others]).to_json(),
                    }
                )
    limits = {
        "low": param.low_limit
        + (f" (F/{f_number:g}: {low:.3g})" if param.name == "psf_scale" else ""),
        "high": param.high_limit,
    }
    return Calibration(param.name, (low, high), per, interval, nominal_of(interval), moved, limits)


def _intersect(intervals) -> Interval:
    items = list(intervals)
    out = items[0]
    for item in items[1:]:
        out = out & item
    return out


def calibrated_profile(
    profile: CameraProfile, result: Calibration, observations_file: str
) -> CameraProfile:
    """The profile with the parameter at its nominal and (for the PSF scale) the band set to
    the interval, both relative to the new table; the sources say how."""
    if result.nominal is None:
        raise CalibrationInputError(f"{result.param}: the interval is empty, nothing to write")
    low, high, nominal = result.interval.low, result.interval.high, result.nominal
    param = PARAMS[result.param]
    out = param.apply(profile, nominal)
    if result.param == "psf_scale":  # the new table is the one the band is stated around
        out = dataclasses.replace(out, psf_scale=1.0)
    sources = dict(out.sources)
    closed = {
        end: f"closed by {result.limits[end]}" if is_open else "bounded by the observations"
        for end, is_open in (("low", result.interval.low_open), ("high", result.interval.high_open))
    }
    how = (
        f"Calibrated against {observations_file} by whiskerbench camera calibrate: "
        f"{result.param} consistent with every observation over [{low:.3g}, {high:.3g}] of the "
        f"previous value (low end {closed['low']}; high end {closed['high']}); "
        f"nominal = the {NOMINAL_RULE}, {nominal:.3g}."
    )
    if result.param == "psf_scale":
        band = (_round_down(low / nominal), _round_up(high / nominal))
        out = dataclasses.replace(out, band=dataclasses.replace(out.band, psf_scale=band))
        sources["psf"] = f"{how} Before: {sources.get('psf', '')}"
        sources["band"] = (
            f"Calibrated: the interval above relative to the new table, [{band[0]:g}, {band[1]:g}]."
        )
    else:
        sources[param.source_key] = f"{how} Before: {sources.get(param.source_key, '')}"
    return dataclasses.replace(out, sources=sources)


def _round_down(value: float) -> float:
    return math.floor(value * 1000) / 1000


def _round_up(value: float) -> float:
    return math.ceil(value * 1000) / 1000

"""``camera calibrate``'s work: each observation's renders made once, its checker, the result.

The renders of an observation depend on its scene (kind, size, region, lighting, sample), not on
its rates, so an assumption that only changes ``min_rate`` reuses them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from bench.twin.calibrate import PARAMS, Calibration, Checker, calibrate
from bench.twin.evidence import evidence_of
from scenes.observations import Observation, Observations
from scenes.profile import CameraProfile

#: Observation fields that do not change what is rendered.
_RATE_FIELDS = ("id", "source", "min_rate", "max_rate", "assumptions")


def detector_of(name: str):
    """The detector of a pipeline preset or variant name (ValueError, one line, otherwise)."""
    from pipeline.presets import get_pipeline

    return get_pipeline(name).detector


class Checkers:
    """Checkers for one base profile and parameter, sharing renders between observations
    whose scenes are the same."""

    def __init__(self, base: CameraProfile, param: str) -> None:
        self.base, self.param = base, PARAMS[param]
        self._evidence: dict[tuple, object] = {}

    def __call__(self, observation: Observation) -> Checker:
        scene = dataclasses.replace(observation, **{f: None for f in _RATE_FIELDS})
        if scene not in self._evidence:
            detector = detector_of(observation.detector)
            self._evidence[scene] = evidence_of(observation, self.base, detector)
        evidence = self._evidence[scene]

        def check(value: float) -> tuple[bool, str]:
            verdict = evidence.check(self.param.apply(self.base, value), value, observation)
            worst = verdict.worst
            return verdict.consistent, f"{worst.label}: {worst.k}/{worst.n}"

        return check


def run_calibration(
    base: CameraProfile,
    observations: Observations,
    param: str,
    f_number: float,
    tolerance: float,
    assumptions: bool = True,
    progress: Callable[[str], None] = lambda text: None,
) -> Calibration:
    return calibrate(
        base, observations, param, Checkers(base, param), f_number, tolerance, assumptions, progress
    )

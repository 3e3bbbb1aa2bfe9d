"""``camera calibrate``'s work: each observation's renders made once, its checker, the result.

The renders of an observation depend on its scene (kind, size, region, lighting, sample), not on
its rates, so an assumption that only changes ``min_rate`` reuses them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from bench.twin.calibrate import (
    DEFAULT_F_NUMBER,
    DEFAULT_TOLERANCE,
    Calibration,
    Checker,
    calibrate,
    check_param,
)
from bench.twin.evidence import evidence_of
from renderers.variant import init_worker
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
        self.base, self.param = base, check_param(base, param)
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
    param: str = "psf_scale",
    f_number: float = DEFAULT_F_NUMBER,
    tolerance: float = DEFAULT_TOLERANCE,
    assumptions: bool = True,
    progress: Callable[[str], None] = lambda text: None,
    variant: str | None = None,
) -> Calibration:
    """Calibrate ``param`` of ``base`` against ``observations``: each observation's interval
    (bisected to ``tolerance``), their intersection, its nominal and how each assumption's
    alternatives move it (``assumptions``). Renders, so it selects the Mitsuba ``variant``
    (None: the fastest here) first; ``progress`` is told each step. ``f_number`` bounds the PSF
    search (:func:`~bench.twin.calibrate.search_range`); CalibrationInputError (one line) for a
    parameter this profile cannot calibrate."""
    checkers = Checkers(base, param)  # a bad parameter is refused before anything renders
    init_worker(variant)
    return calibrate(
        base, observations, param, checkers, f_number, tolerance, assumptions, progress
    )

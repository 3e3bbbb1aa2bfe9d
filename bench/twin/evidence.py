"""Whether a camera twin does what an observation says the real sensor did.

An :class:`Evidence` holds an observation's renders, made once: the clean radiance does not
depend on the parameters a calibration varies (the PSF scale, the sensor's noise), so every
trial value only reruns the camera twin's optics and sensor and the detector. ``check(profile)``
answers with the counts behind the answer (:class:`Verdict`).

A rate is *consistent* with an observation of "at least ``min_rate``" (and "at most
``max_rate``") when its Wilson interval (the study's, :func:`bench.study.report.wilson_interval`)
reaches ``min_rate`` and does not lie wholly above ``max_rate``: the twin is refused only where
the images rule the observation out. Images are drawn in the study's steps
(:data:`bench.study.config.IMAGE_STEPS`) until each unit is decided or the cap is reached.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass

import numpy as np

from bench.common.marker_score import MarkerTruth, find_marker
from bench.study.config import Cell, StudyConfig
from bench.study.report import wilson_interval
from scenes.observations import Observation
from scenes.profile import CameraProfile

#: Images per study cell at most (the study's default cap).
MAX_CELL_IMAGES = 240
#: The render seed of every evidence render (fixed: the renders are not what is calibrated).
RENDER_SEED = 0


@dataclass(frozen=True)
class Unit:
    """One counted thing: a study cell or a marker of the array; ``k`` of ``n`` images read it."""

    label: str
    k: int
    n: int

    @property
    def interval(self) -> tuple[float, float]:
        lo, hi = wilson_interval(self.k, self.n)
        return float(lo), float(hi)


@dataclass(frozen=True)
class Verdict:
    """An observation checked at one trial profile: consistent, and the counts behind it."""

    consistent: bool
    units: tuple[Unit, ...]

    @property
    def worst(self) -> Unit:
        """The unit with the lowest read rate (the one that decides a success observation)."""
        return min(self.units, key=lambda u: u.k / u.n if u.n else 1.0)


def _unit_consistent(unit: Unit, observation: Observation) -> bool:
    lo, hi = unit.interval
    return hi >= observation.min_rate and lo <= observation.max_rate


def _unit_decided(unit: Unit, observation: Observation) -> bool:
    """Whether more images could not change the unit's answer."""
    lo, hi = unit.interval
    if hi < observation.min_rate or lo > observation.max_rate:
        return True  # ruled out
    above_min = lo >= observation.min_rate
    below_max = observation.max_rate >= 1.0 or hi <= observation.max_rate
    return above_min and below_max


def _trial_rng(*key: object) -> np.random.Generator:
    """One noise stream per (observation, unit, trial value): reproducible, independent."""
    words = [zlib.crc32(repr(k).encode()) for k in key]
    return np.random.default_rng(np.random.SeedSequence(words))


class MarkerEvidence:
    """A ``marker`` observation: the study's cells of its region, rendered once each."""

    def __init__(self, observation: Observation, base: CameraProfile, detector) -> None:
        from bench.study.cells import render_cell, study_renderer

        self.detector, o = detector, observation
        self.config = StudyConfig(
            sizes_mm=(o.size_mm,),
            alphas_deg=o.alpha_deg,
            phis_deg=o.phi_deg,
            distance_mm=o.distance_mm,
            lightings=(o.lighting,),
            dictionary=o.family,
            camera=base,
            detector=dataclasses.replace(detector, dictionary=o.family),
        )
        renderer = study_renderer(self.config)
        self.renderer = renderer
        self.renders = {
            cell: render_cell(renderer, cell, RENDER_SEED, o.distance_mm, base.crop_grid_px)
            for cell in self.config.cells()
        }

    def check(self, profile: CameraProfile, trial: float, observation: Observation) -> Verdict:
        """The observation (whose scene these renders are) checked at the trial profile."""
        from bench.study.cells import CellDraws, next_count

        config = dataclasses.replace(self.config, camera=profile)
        lens, o = profile.lens, observation
        units = []
        for cell, render in self.renders.items():
            rng = _trial_rng(o.id, cell.key, trial)
            draws = CellDraws(config, self.renderer, render, cell, 1.0, rng)
            origin = (render.window.x0, render.window.y0)
            truth = MarkerTruth.of(lens, config.marker_id, cell.size_mm, render.T_cam_marker)
            unit = Unit(_cell_label(cell), 0, 0)
            while unit.n < MAX_CELL_IMAGES and not (unit.n and _unit_decided(unit, o)):
                images = draws.draw(next_count(unit.n, MAX_CELL_IMAGES) - unit.n)
                k = sum(
                    bool(find_marker(im, config.detector, origin, truth, lens)[1]) for im in images
                )
                unit = Unit(unit.label, unit.k + k, unit.n + len(images))
            units.append(unit)
        return Verdict(all(_unit_consistent(u, o) for u in units), tuple(units))


def _cell_label(cell: Cell) -> str:
    return f"alpha {cell.alpha_deg:g} phi {cell.phi_deg:g}"


class ArrayEvidence:
    """An ``array_rest`` or ``array_sampling`` observation: the array's frames rendered once
    through the dataset's own simulation and renderer; each marker of the array is a unit."""

    def __init__(self, observation: Observation, base: CameraProfile, detector) -> None:
        from bench.dataset.config import DatasetConfig
        from bench.dataset.sample import sample_recorder, simulate_sample

        o = observation
        self.detector = detector
        rest = o.kind == "array_rest"
        fields = dict(
            protocols=(o.protocol,),
            foliage=("soft",) if rest else (o.foliage,),
            distances=("far",) if rest else (o.distance,),
            branches=((),) if rest else (o.branches_mm,),
            lightings=(o.lighting,),
            camera=base,
        )
        # Simulate only the frames looked at: the first for the lead-in, some 4 per pick else.
        total = len(
            DatasetConfig(**fields).motion(o.protocol, fields["distances"][0]).frame_times()
        )
        step = total if rest else max(1, total // (4 * o.frames))
        config = DatasetConfig(**fields, frames_step=step)
        sample = config.samples()[0]
        sim = simulate_sample(config, sample)
        recorder = sample_recorder(config, sample, sim)
        self.marker_ids = tuple(config.array.marker_ids)
        self.region, self.band = recorder.renderer.region, recorder.renderer.band
        self.exposure = recorder.exposure
        if rest:  # the still lead-in: one render, every image its own noise
            picks = np.zeros(o.frames, int)
        else:  # frames spread over the motion after the lead-in
            start = int(np.searchsorted(sim.times_s, sim.motion.lead_in_s))
            picks = np.linspace(start, len(sim.times_s) - 1, o.frames).round().astype(int)
        #: each distinct frame's radiance once, and which one each image shows
        self.radiances = {f: recorder.radiance(f) for f in sorted(set(picks.tolist()))}
        self.picks = picks.tolist()

    def check(self, profile: CameraProfile, trial: float, observation: Observation) -> Verdict:
        """The observation (whose scene these renders are) checked at the trial profile."""
        from pipeline.detect import detect_markers
        from renderers.twin_recorder import TwinRecorder

        o = observation
        seed = int(_trial_rng(o.id, trial).integers(1 << 31))
        twin = TwinRecorder(profile, self.region, self.band, self.exposure, seed)
        counts = dict.fromkeys(self.marker_ids, 0)
        irradiance = {f: twin.optics(r) for f, r in self.radiances.items()}  # lens once a frame
        for f in self.picks:
            image = twin.expose(irradiance[f])
            for marker_id in {
                d.marker_id for d in detect_markers(image, self.detector, camera=profile.lens)
            }:
                if marker_id in counts:
                    counts[marker_id] += 1
        n = len(self.picks)
        units = tuple(
            Unit(f"whisker {i} (id {m})", counts[m], n) for i, m in enumerate(self.marker_ids)
        )
        return Verdict(all(_unit_consistent(u, o) for u in units), units)


def evidence_of(observation: Observation, base: CameraProfile, detector):
    """The observation's renders, ready to check trial profiles against."""
    kind = MarkerEvidence if observation.kind == "marker" else ArrayEvidence
    return kind(observation, base, detector)

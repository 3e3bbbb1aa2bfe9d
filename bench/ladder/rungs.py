"""The ladder's rungs: the reference and every one-choice-at-a-time departure from it.

A rung is plain data: which part (study or video), which axis it moves along, and the
rendering settings it uses; everything else is the reference's. Camera stages are turned off
through the profile (its neutral value: no fall-off, no PSF, a grey sensor, no noise, a linear
transfer, a raw stream), so one route serves the study's crops and the video's frames alike.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from bench.dataset.config import DatasetConfig
from bench.ladder.config import VIDEO_BACKGROUND_SPP, LadderConfig
from bench.study.config import StudyConfig
from renderers.frame_sampling import FrameSampling
from scenes.foliage_meshes import DETAIL_LEVELS
from scenes.profile import (
    CameraProfile,
    LateralColour,
    PsfTable,
    RelativeIllumination,
    Stream,
)

#: The video reference's foliage detail: the finest tessellation on offer.
FINEST_DETAIL = "fine"

#: Camera stages a profile can turn off, in the twin's order (renderers.camera_twin.STAGES);
#: ``mosaic`` off is a grey sensor, so it takes ``demosaic`` with it.
STAGE_RUNGS = (
    "relative_illumination",
    "psf",
    "lateral_colour",
    "mosaic",
    "noise",
    "transfer",
    "stream",
)


def stage_off(profile: CameraProfile, stage: str) -> CameraProfile:
    """``profile`` with one camera stage set to its neutral value (ValueError on an unknown)."""
    replace = dataclasses.replace
    changes = {
        "relative_illumination": lambda p: replace(p, relative_illumination=RelativeIllumination()),
        "psf": lambda p: replace(p, psf=PsfTable()),
        "lateral_colour": lambda p: replace(p, lateral_colour=LateralColour()),
        "mosaic": lambda p: replace(p, sensor=replace(p.sensor, cfa="none")),
        "noise": lambda p: replace(
            p, sensor=replace(p.sensor, read_noise_e=0.0, dark_signal_e=0.0, full_well_e=1e7)
        ),
        "transfer": lambda p: replace(p, processing=replace(p.processing, transfer="linear")),
        "stream": lambda p: replace(p, stream=Stream(codec="none")),
    }
    if stage not in changes:
        raise ValueError(f"stage: unknown {stage!r}; allowed: {', '.join(STAGE_RUNGS)}")
    return changes[stage](profile)


def stage_is_on(profile: CameraProfile, stage: str) -> bool:
    """Whether turning ``stage`` off changes the profile (a stage already off has no rung)."""
    return stage_off(profile, stage) != profile


@dataclass(frozen=True)
class Rung:
    """One point of the ladder: ``settings`` are the reference's with one choice changed."""

    part: str  # "study" or "video"
    axis: str  # "reference", "spp", "background_spp", "integrator", "region", "stage",
    # "foliage_detail"
    name: str
    settings: tuple[tuple[str, object], ...]

    @property
    def key(self) -> str:
        """Folder name: unique within a part."""
        return "reference" if self.axis == "reference" else f"{self.axis}-{self.name}"

    @property
    def options(self) -> dict:
        return dict(self.settings)

    def render_key(self) -> tuple:
        """What the render depends on: rungs that differ only in the camera share one."""
        return tuple((k, v) for k, v in self.settings if k != "stage_off")


def render_groups(rungs: list[Rung]) -> list[list[Rung]]:
    """The rungs grouped by :meth:`Rung.render_key`, in order: each group is rendered once."""
    groups: dict[tuple, list[Rung]] = {}
    for rung in rungs:
        groups.setdefault(rung.render_key(), []).append(rung)
    return list(groups.values())


def _rung(part: str, axis: str, name: str, reference: dict, **change) -> Rung:
    return Rung(part, axis, name, tuple(sorted({**reference, **change}.items())))


#: Rungs that are not a choice: the reference drawn with other random numbers (its own spread,
#: which sets how close a rung must come), and the project's defaults all together.
CHECKS = ("control", "defaults")


#: The controls' seed offsets: two draws of the reference's spread.
CONTROL_SEEDS = (1, 2)


def project_defaults(part: str) -> dict:
    """The project's own setting on every rendering axis of ``part``: the study's (its spp,
    exact sky, the marker's crop) or the dataset's (:class:`FrameSampling`, foliage detail)."""
    if part == "study":
        return {
            "spp": StudyConfig.spp,
            "integrator": "direct",
            "path_depth": 0,
            "full_frame": False,
        }
    sampling = FrameSampling()
    return {
        "marker_spp": sampling.marker_spp,
        "background_spp": sampling.background_spp,
        "integrator": sampling.integrator,
        "path_depth": 0,
        "full_frame": sampling.full_frame,
        "foliage_detail": DatasetConfig.foliage_detail,
    }


def current_default(part: str, axis: str) -> str:
    """The rung name the project's default has on ``axis`` (``defaults.csv``'s column)."""
    d = project_defaults(part)
    names = {
        "spp": str(d.get("spp", d.get("marker_spp"))),
        "background_spp": str(d.get("background_spp", "")),
        "integrator": d["integrator"] if d["path_depth"] == 0 else f"path{d['path_depth']}",
        "region": "frame" if d["full_frame"] else ("crop" if part == "study" else "band"),
        "foliage_detail": d.get("foliage_detail", ""),
        "stage": "all on",
    }
    return names.get(axis, "")


def _checks(part: str, reference: dict) -> list[Rung]:
    controls = [
        _rung(part, "control", "other-seed" if k == 1 else f"seed+{k}", reference, seed_offset=k)
        for k in CONTROL_SEEDS
    ]
    return [*controls, _rung(part, "defaults", "project", reference, **project_defaults(part))]


def _integrator_rungs(part: str, reference: dict, depth: int) -> list[Rung]:
    rungs = [_rung(part, "integrator", "direct", reference, integrator="direct", path_depth=0)]
    rungs += [
        _rung(part, "integrator", f"path{d}", reference, path_depth=d) for d in range(1, depth)
    ]
    return rungs


def study_rungs(config: LadderConfig, profile: CameraProfile) -> list[Rung]:
    """Reference (reference spp, path tracing, full frame, every stage) and its rungs; a crop
    reference (``--quick``) has no region rung."""
    depth = config.path_depth
    ref = {
        "spp": config.reference_spp,
        "integrator": "path",
        "path_depth": depth,
        "full_frame": config.study_full_frame,
        "stage_off": "",
        "seed_offset": 0,
    }
    rungs = [_rung("study", "reference", "reference", ref), *_checks("study", ref)]
    rungs += [_rung("study", "spp", str(s), ref, spp=s) for s in config.spps if s != ref["spp"]]
    rungs += _integrator_rungs("study", ref, depth)
    if config.study_full_frame:
        rungs.append(_rung("study", "region", "crop", ref, full_frame=False))
    return rungs + _stage_rungs("study", ref, profile)


def video_rungs(config: LadderConfig, profile: CameraProfile) -> list[Rung]:
    """Reference: reference spp on the markers, :data:`VIDEO_BACKGROUND_SPP` elsewhere, path
    tracing, full frame, the finest foliage, every stage; its rungs one change each."""
    depth = config.path_depth
    spp = config.reference_spp
    ref = {
        "marker_spp": spp,
        "background_spp": min(spp, VIDEO_BACKGROUND_SPP),
        "integrator": "path",
        "path_depth": depth,
        "full_frame": config.video_full_frame,
        "foliage_detail": FINEST_DETAIL,
        "stage_off": "",
        "seed_offset": 0,
    }
    rungs = [_rung("video", "reference", "reference", ref), *_checks("video", ref)]
    rungs += [_rung("video", "spp", str(s), ref, marker_spp=s) for s in config.spps if s != spp]
    if ref["background_spp"] > 1:
        rungs.append(_rung("video", "background_spp", "1", ref, background_spp=1))
    rungs += _integrator_rungs("video", ref, depth)
    if config.video_full_frame:
        rungs.append(_rung("video", "region", "band", ref, full_frame=False))
    rungs += [
        _rung("video", "foliage_detail", d, ref, foliage_detail=d)
        for d in DETAIL_LEVELS
        if d != FINEST_DETAIL
    ]
    rungs += _stage_rungs("video", ref, profile)
    return [r for r in rungs if r.axis in ("reference", *CHECKS, *config.video_axes)]


def _stage_rungs(part: str, ref: dict, profile: CameraProfile) -> list[Rung]:
    stages = [s for s in STAGE_RUNGS if stage_is_on(profile, s)]
    return [_rung(part, "stage", s, ref, stage_off=s) for s in stages]

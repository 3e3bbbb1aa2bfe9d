"""What a ladder run measures: its cells, image and frame counts, reference and pipeline.

:class:`LadderConfig` is validated when built (LadderConfigError names the field, hence the
option); everything that changes a number is in it, so its JSON is the run's settings hash.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from bench.common.manifest import json_sha256
from bench.study.config import IMAGE_STEPS, Cell
from scenes.profile import shipped_profiles
from scenes.validation import MAX_SEED, FieldError

#: Cells near the 95 % boundary of results/detectability/default at PSF x 1 (sun, 200 mm):
#: measured rates 0.963, 0.971, 0.950 and 0.929 over 240 images, each interval straddling 0.95.
SENSITIVE_CELLS = (
    Cell("sun", 11.0, 40.0, 10.0),
    Cell("sun", 13.2, 85.0, 0.0),
    Cell("sun", 17.6, 60.0, 30.0),
    Cell("sun", 17.6, 0.0, 37.5),
)
#: The default run's two (the renders of a path-traced full-frame study cell cost minutes):
#: the one at 0.950 and the smaller marker at 0.963.
DEFAULT_CELLS = (SENSITIVE_CELLS[0], SENSITIVE_CELLS[2])
SPP_RUNGS = (1, 2, 4, 8, 16, 64)
#: The default run's spp rungs below the reference (``--spp 1,2,4,8,16`` for all of them).
DEFAULT_SPPS = (1, 4, 16)
REFERENCE_SPP = 64
#: The video reference's spp off the markers: 64 over a full frame is out of reach (> 3 min
#: and 9 GB a frame), 4 is the reference, 1 (the dataset default) its rung.
VIDEO_BACKGROUND_SPP = 4
REFERENCE_DEPTH = 2
PARTS = ("study", "video")
#: The video's axes, each a render of both samples (``stage``: records of the reference's).
VIDEO_AXES = ("spp", "background_spp", "integrator", "region", "foliage_detail", "stage")
MAX_FRAMES_STEP = 30


class LadderConfigError(FieldError):
    """A bad ladder setting; ``field`` names the LadderConfig field (and its option)."""


@dataclass(frozen=True)
class LadderConfig:
    """The ladder's size; defaults are the ``make ladder`` run, :meth:`quick` the tests'."""

    parts: tuple[str, ...] = PARTS
    cells: tuple[Cell, ...] = DEFAULT_CELLS
    #: Images per study cell and rung (the cap: a cell settled off 0.95 stops earlier).
    images: int = 40
    #: The study reference's region: the full frame, or (``--quick``) the marker's crop.
    study_full_frame: bool = True
    #: The video reference's region: the full frame, or (``--quick``) the markers' band.
    video_full_frame: bool = True
    #: Every ``frames_step``-th frame of the video samples (the same for every rung).
    frames_step: int = 8
    video_axes: tuple[str, ...] = VIDEO_AXES
    #: The video's camera profile (``scenes/profiles``).
    profile: str = "prototype"
    pipeline: str = "paper"
    seed: int = 0
    spps: tuple[int, ...] = DEFAULT_SPPS
    #: The reference's samples per pixel (study spp; video marker and background spp).
    reference_spp: int = REFERENCE_SPP
    path_depth: int = REFERENCE_DEPTH
    #: The video's sample: natural foliage (paper strips are boxes at every foliage detail),
    #: close, one branch; with its no-branch twin, which sets the pipeline's threshold.
    foliage: str = "sparse"
    distance: str = "close"
    branch_mm: float = 0.0

    def __post_init__(self) -> None:
        def fail(name: str, message: str) -> None:
            raise LadderConfigError(name, message)

        if not self.parts or any(p not in PARTS for p in self.parts):
            fail("parts", f"{list(self.parts)}: choose from {', '.join(PARTS)}")
        if not self.cells:
            fail("cells", "needs at least one cell")
        if not (isinstance(self.images, int) and 1 <= self.images <= IMAGE_STEPS[-1]):
            fail("images", f"{self.images!r}: allowed range is 1..{IMAGE_STEPS[-1]}")
        if not self.video_axes or any(a not in VIDEO_AXES for a in self.video_axes):
            fail("video_axes", f"{list(self.video_axes)}: choose from {', '.join(VIDEO_AXES)}")
        step = self.frames_step
        if not (isinstance(step, int) and 1 <= step <= MAX_FRAMES_STEP):
            fail("frames_step", f"{step!r}: allowed range is 1..{MAX_FRAMES_STEP}")
        if self.profile not in shipped_profiles():
            fail("profile", f"{self.profile!r}: choose from {', '.join(shipped_profiles())}")
        if not (isinstance(self.seed, int) and 0 <= self.seed <= MAX_SEED):
            fail("seed", f"{self.seed!r}: allowed range is 0..{MAX_SEED}")
        if not (isinstance(self.reference_spp, int) and 1 <= self.reference_spp <= 1024):
            fail("reference_spp", f"{self.reference_spp!r}: allowed range is 1..1024")
        if not (isinstance(self.path_depth, int) and 1 <= self.path_depth <= 8):
            fail("path_depth", f"{self.path_depth!r}: allowed range is 1..8")
        spps = tuple(self.spps)
        if not spps or any(not (isinstance(s, int) and 1 <= s <= self.reference_spp) for s in spps):
            fail("spps", f"{list(spps)}: each an integer in 1..{self.reference_spp}")
        object.__setattr__(self, "spps", tuple(sorted(set(spps))))

    @classmethod
    def quick(cls, **changes) -> LadderConfig:
        """Seconds, for tests: one cell's crop, 3 images; a video of a few band frames on the
        ideal camera, its reference and stage rungs; low spp, path depth 1."""
        base = {
            "cells": SENSITIVE_CELLS[2:3],
            "images": 3,
            "study_full_frame": False,
            "video_full_frame": False,
            "frames_step": MAX_FRAMES_STEP,
            "video_axes": ("stage",),
            "profile": "ideal",
            "spps": (1,),
            "reference_spp": 2,
            "path_depth": 1,
        }
        return cls(**{**base, **changes})

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["cells"] = [dataclasses.asdict(c) for c in self.cells]
        return out

    def settings_hash(self) -> str:
        """The hash of the config's JSON: the folder's, and each rung's record's."""
        return json_sha256(self.to_json())


#: The command-line option that sets each field (``whiskerbench ladder``).
OPTION_OF_FIELD = {
    "parts": "--parts",
    "images": "--images",
    "frames_step": "--frames-step",
    "profile": "--profile",
    "video_axes": "--video-axes",
    "seed": "--seed",
    "reference_spp": "--reference-spp",
    "path_depth": "--path-depth",
    "spps": "--spp",
    "pipeline": "--pipeline",
}


def ladder_options(config: LadderConfig) -> list[str]:
    """The options that make ``config`` differ from the default ladder, as the command line
    spells them (``--quick --spp 1,2``), for the chart's title."""
    given = {name: getattr(config, name) for name in OPTION_OF_FIELD}
    quick = config == LadderConfig.quick(**given)
    base = LadderConfig.quick() if quick else LadderConfig()
    options = ["--quick"] if quick else []
    for name, flag in OPTION_OF_FIELD.items():
        value = getattr(config, name)
        if value != getattr(base, name):
            shown = ",".join(map(str, value)) if isinstance(value, tuple) else str(value)
            options.append(f"{flag} {shown}")
    return options

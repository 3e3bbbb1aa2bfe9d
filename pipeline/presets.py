"""Pipeline variants as data: named choices composed into a config, and the shipped presets.

A variant is a :class:`PipelineConfig`; ``dataclasses.replace(PRESETS["paper"], ...)`` makes
another, and so does a variant name on the command line: a preset followed by ``/choice=value``
changes, for example ``paper/refine=contour/aruco3=on`` or ``fast/window=3-23-10``
(:func:`get_pipeline`; the choices are :data:`CHOICES`). The presets:

``paper``
    SPEC 3 as published: full-frame detection with OpenCV's sub-pixel corners, OpenCV fisheye
    undistortion then IPPE_SQUARE, integration, the fixed foliage threshold.
``fast``
    ROI tracking (the full frame only to (re)acquire), one adaptive-threshold window of 15 px
    instead of OpenCV's three (3, 13, 23 px), no corner refinement, the virtual-view pose,
    integration, fixed threshold. Thresholding is the detector's main cost and one window cuts
    it about threefold. 15 px was chosen from the ``compare`` sweeps: it fails at the same tilt,
    lighting, blur and noise as the three windows (a 23 px window lost tilts past 40 deg and
    ``canopy``; 31 px also ``backlit``).
``robust``
    Full frame, this project's edge-line corners, the virtual-view pose (valid past 90 degrees),
    integration, and the threshold inferred from the sample itself when none is given.
``naive``
    Full frame, no refinement, a pinhole pose that ignores the lens, per-whisker maximum.
``hybrid``
    The fastest finder with this project's tracking and corners: locus-tag detects (in the
    ROI, the full frame only to (re)acquire), AprilTag 3 looks again where a tracked marker was
    lost (``recover``), ``lines`` refines, then the virtual-view pose, integration, fixed
    threshold. Built to be on or beyond every peer's Pareto front (frames/s,
    marker recall, corner error; docs/pipelines.md, the comparison). Needs the peers extra.
``locus``, ``apriltag``
    The peers (:mod:`pipeline.backends`) as their authors ship them: the full frame, their own
    corners, then this project's virtual-view pose, integration and fixed threshold (the pose
    and branch steps are the robot's; only the detector differs). ``/detector=`` puts any
    preset on another backend, e.g. ``robust/detector=locus`` (locus finds, ``lines`` refines).
``plugin:SPEC``
    A user's own detector (:mod:`pipeline.backends.plugin`, ``docs/plugins.md``), run as the
    peers are: the full frame (the whole of it), its own corners, then the virtual-view pose,
    integration and fixed threshold; ``/CHOICE=VALUE`` parts follow the SPEC
    (``plugin:mine:detect/refine=lines``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pipeline.backends import PLUGIN_PREFIX, check_family
from pipeline.branches import AGGREGATIONS
from pipeline.detect import DetectorConfig, constant_problem, window_problem
from pipeline.pose import POSE_METHODS
from pipeline.track import Search

THRESHOLDS = ("fixed", "online")
#: Largest tracking margin (px): the full frame's width.
MAX_MARGIN_PX = 4096


@dataclass(frozen=True)
class PipelineConfig:
    """One branch-finding pipeline, every choice from detector to threshold; a preset
    (:data:`PRESETS`) or a variant of one (:func:`get_pipeline`). Validated on construction."""

    name: str
    detector: DetectorConfig
    search: Search = Search()
    pose_method: str = "virtual"
    aggregation: str = "integration"
    threshold: str = "fixed"
    baseline_frames: int = 10

    def __post_init__(self) -> None:
        if self.pose_method not in POSE_METHODS:
            raise ValueError(f"pose_method={self.pose_method!r}: choose from {POSE_METHODS}")
        if self.aggregation not in AGGREGATIONS:
            raise ValueError(f"aggregation={self.aggregation!r}: choose from {AGGREGATIONS}")
        if self.threshold not in THRESHOLDS:
            raise ValueError(f"threshold={self.threshold!r}: choose from {THRESHOLDS}")
        if self.baseline_frames < 1:
            raise ValueError(f"baseline_frames={self.baseline_frames}: must be >= 1")
        if self.search.recover != "none":
            check_family(self.search.recover, self.detector.dictionary)

    def with_family(self, family: str) -> PipelineConfig:
        """This pipeline with its detector on the marker ``family``; ValueError (one line) when
        a backend it runs cannot detect it."""
        detector = dataclasses.replace(self.detector, dictionary=family)
        return dataclasses.replace(self, detector=detector)

    @property
    def backends(self) -> tuple[str, ...]:
        """The detector backends this pipeline runs: its detector's, and the recovery's."""
        recover = self.search.recover
        return (self.detector.backend,) + (() if recover == "none" else (recover,))

    @property
    def folder_name(self) -> str:
        """The name as a folder name: ``paper/refine=contour`` -> ``paper~refine=contour``."""
        return self.name.replace("/", "~")

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


#: The shipped pipelines by name (the module docstring says what each one is for).
PRESETS: dict[str, PipelineConfig] = {
    "paper": PipelineConfig(
        "paper", DetectorConfig(corner_refinement="subpix"), Search("full"), "fisheye"
    ),
    "fast": PipelineConfig(
        "fast",
        DetectorConfig(
            corner_refinement="none",
            adaptive_thresh_win_size_min=15,
            adaptive_thresh_win_size_max=15,
        ),
        Search("roi"),
        "virtual",
    ),
    "robust": PipelineConfig(
        "robust",
        DetectorConfig(corner_refinement="lines"),
        Search("full"),
        "virtual",
        threshold="online",
    ),
    "naive": PipelineConfig(
        "naive", DetectorConfig(corner_refinement="none"), Search("full"), "pinhole", "max"
    ),
    "hybrid": PipelineConfig(
        "hybrid",
        DetectorConfig(corner_refinement="lines", backend="locus"),
        Search("roi", recover="apriltag"),
    ),
    **{
        peer: PipelineConfig(
            peer, DetectorConfig(corner_refinement="none", backend=peer), Search("full"), "virtual"
        )
        for peer in ("locus", "apriltag")
    },
}
#: Choices that set OpenCV's own parameters: refused with a peer detector, which ignores them.
OPENCV_CHOICES = ("aruco3", "window", "constant", "cell")


def _window(text: str) -> dict:
    """``MIN[-MAX[-STEP]]`` adaptive-threshold window sizes (px); one size means MIN = MAX."""
    sizes = [_integer(v) for v in text.split("-")]
    if not 1 <= len(sizes) <= 3:
        raise ValueError("window=MIN[-MAX[-STEP]]")
    lo, hi, step = (sizes + sizes[:1] + [10])[:3] if len(sizes) == 1 else (sizes + [10])[:3]
    problem = window_problem(lo, hi, step)
    if problem:
        raise ValueError(f"window=MIN[-MAX[-STEP]]: {problem}")
    return {
        "adaptive_thresh_win_size_min": lo,
        "adaptive_thresh_win_size_max": hi,
        "adaptive_thresh_win_size_step": step,
    }


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{text!r} is not an integer") from None


def _constant(text: str) -> dict:
    """The adaptive threshold's constant, in grey levels: finite, within +/-255."""
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None
    problem = constant_problem(value)
    if problem:
        raise ValueError(f"{text}: {problem}")
    return {"adaptive_thresh_constant": value}


def _margin(text: str) -> dict:
    value = _integer(text)
    if not 0 <= value <= MAX_MARGIN_PX:
        raise ValueError(f"{value}: allowed range is 0..{MAX_MARGIN_PX} px")
    return {"margin_px": value}


def _on_off(text: str) -> bool:
    if text not in ("on", "off"):
        raise ValueError(f"{text!r}: choose on or off")
    return text == "on"


#: The ``/choice=value`` changes a variant name may make: choice -> (what it sets, parser).
CHOICES = {
    "detector": ("detector", lambda v: {"backend": v}),
    "refine": ("detector", lambda v: {"corner_refinement": v}),
    "transfer": ("detector", lambda v: {"transfer": v}),
    "aruco3": ("detector", lambda v: {"use_aruco3_detection": _on_off(v)}),
    "window": ("detector", _window),
    "constant": ("detector", _constant),
    "cell": ("detector", lambda v: {"cell_px": _integer(v)}),
    "search": ("search", lambda v: {"mode": v}),
    "margin": ("search", _margin),
    "recover": ("search", lambda v: {"recover": v}),
    "pose": ("pipeline", lambda v: {"pose_method": v}),
    "aggregation": ("pipeline", lambda v: {"aggregation": v}),
    "threshold": ("pipeline", lambda v: {"threshold": v}),
}


def plugin_pipeline(backend: str) -> PipelineConfig:
    """The pipeline of a detector plugin ``plugin:SPEC``: as the peers' presets (its own corners
    on the full frame, virtual-view pose, integration, fixed threshold); ValueError (one line)
    if the plugin cannot be resolved."""
    return PipelineConfig(
        backend, DetectorConfig(corner_refinement="none", backend=backend), Search("full")
    )


def _base(name: str) -> tuple[PipelineConfig, list[str]]:
    """The preset (or plugin) a variant name starts from, and its ``choice=value`` parts."""
    if name.startswith(PLUGIN_PREFIX):
        from pipeline.backends.plugin import split_name

        backend, rest = split_name(name)
        return plugin_pipeline(backend), rest.split("/")[1:]
    preset, *changes = name.split("/")
    if preset not in PRESETS:
        raise ValueError(
            f"pipeline {name!r}: unknown preset {preset!r}; choose from {', '.join(PRESETS)}, "
            "or plugin:SPEC (docs/plugins.md)"
        )
    return PRESETS[preset], changes


def get_pipeline(name: str) -> PipelineConfig:
    """The preset, a plugin's pipeline (``plugin:SPEC``), or the variant a
    ``PRESET/choice=value/...`` name describes; ValueError (one line, naming the bad part)
    otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"pipeline {name!r}: a pipeline is named by a string")
    base, changes = _base(name)
    config = dataclasses.replace(base, name=name)
    detector: dict = {}  # applied together: a backend and its refinement are one choice
    detector_changes: list[str] = []
    for change in changes:
        key, _, value = change.partition("=")
        if key not in CHOICES or not value:
            raise ValueError(
                f"pipeline {name!r}: {change!r} is not CHOICE=VALUE with CHOICE one of "
                f"{', '.join(CHOICES)}"
            )
        part, parse = CHOICES[key]
        try:
            fields = parse(value)
            if part == "detector":
                detector.update(fields)
                detector_changes.append(change)
            elif part == "search":
                config = dataclasses.replace(
                    config, search=dataclasses.replace(config.search, **fields)
                )
            else:
                config = dataclasses.replace(config, **fields)
        except ValueError as exc:
            raise ValueError(f"pipeline {name!r}: {change}: {exc}") from None
    try:
        config = dataclasses.replace(
            config, detector=dataclasses.replace(config.detector, **detector)
        )
    except ValueError as exc:
        raise ValueError(f"pipeline {name!r}: {'/'.join(detector_changes)}: {exc}") from None
    peer_only = [c for c in detector_changes if c.partition("=")[0] in OPENCV_CHOICES]
    if config.detector.backend != "opencv" and peer_only:
        raise ValueError(
            f"pipeline {name!r}: {peer_only[0]} sets an OpenCV parameter, which detector "
            f"{config.detector.backend} does not have"
        )
    return config

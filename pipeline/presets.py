"""Pipeline variants as data: named choices composed into a config, and the shipped presets.

A variant is a :class:`PipelineConfig`; ``dataclasses.replace(PRESETS["paper"], ...)`` makes
another. The presets:

``paper``
    SPEC 3 as published: full-frame detection with OpenCV's sub-pixel corners, OpenCV fisheye
    undistortion then IPPE_SQUARE, integration, the fixed foliage threshold.
``fast``
    ROI tracking (the full frame only to (re)acquire), no corner refinement, the virtual-view
    pose, integration, fixed threshold.
``robust``
    Full frame, this project's edge-line corners, the virtual-view pose (valid past 90 degrees),
    integration, and the threshold inferred from the sample itself when none is given.
``naive``
    Full frame, no refinement, a pinhole pose that ignores the lens, per-whisker maximum.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pipeline.branches import AGGREGATIONS
from pipeline.detect import DetectorConfig
from pipeline.pose import POSE_METHODS
from pipeline.track import Search

THRESHOLDS = ("fixed", "online")


@dataclass(frozen=True)
class PipelineConfig:
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

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


PRESETS: dict[str, PipelineConfig] = {
    "paper": PipelineConfig(
        "paper", DetectorConfig(corner_refinement="subpix"), Search("full"), "fisheye"
    ),
    "fast": PipelineConfig(
        "fast", DetectorConfig(corner_refinement="none"), Search("roi"), "virtual"
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
}


def get_pipeline(name: str) -> PipelineConfig:
    """The preset of that name, or ValueError listing them."""
    if name not in PRESETS:
        raise ValueError(f"pipeline {name!r}: unknown; choose from {', '.join(PRESETS)}")
    return PRESETS[name]

"""Plugins for tests/test_plugins.py: one that works and one for each way a plugin can fail.

Named by ``tests.plugin_samples:NAME`` (importable from the project root, where the tests run
and where the backend's worker process starts). The detectors take an image and answer
``[(marker_id, corners), ...]``; the branch finders take a sample's frames, camera and facts.
"""

from __future__ import annotations

import ctypes
import os
import time

import numpy as np

from pipeline.backends import opencv
from pipeline.detect import DetectorConfig

NOT_CALLABLE = 3
_CONFIG = DetectorConfig(corner_refinement="none")


def good(image: np.ndarray) -> list:
    """OpenCV's default detector (the project's own adapter): what ``naive`` finds."""
    found = opencv.detect(image, _CONFIG, max(image.shape), None)
    return list(zip(found.ids.tolist(), found.corners_px, strict=True))


def with_pose(image: np.ndarray) -> list:
    """As ``good``, each with an identity pose of its own."""
    return [(i, c, np.eye(4)) for i, c in good(image)]


def raises(image: np.ndarray) -> list:
    raise ZeroDivisionError("planted")


def wrong_shape(image: np.ndarray) -> list:
    return [(0, np.zeros((3, 2)))]


def nan_corners(image: np.ndarray) -> list:
    return [(0, np.full((4, 2), np.nan))]


def not_a_list(image: np.ndarray) -> dict:
    return {0: np.zeros((4, 2))}


def hangs(image: np.ndarray) -> list:
    time.sleep(3600)
    return []


def crashes(image: np.ndarray) -> list:
    """A segmentation fault, as native code ends."""
    ctypes.string_at(0)
    return []


def crashes_on_black(image: np.ndarray) -> list:
    if not image.any():
        os.abort()
    return good(image)


# -- branch finders ---------------------------------------------------------------------------


def gap_six(frames, camera, meta: dict) -> list:
    """Reads every frame (told no truth); finds a branch between whiskers 6 and 7."""
    assert meta["frames"] == sum(1 for _ in frames) and "branch_gaps" not in meta
    assert camera.width_px > 0 and meta["array"]["n_whiskers"] == 13
    return [(6, 7)]


def bad_gap(frames, camera, meta: dict) -> list:
    return [(6, 8)]


def branch_raises(frames, camera, meta: dict) -> list:
    raise RuntimeError("planted")


def crashes_on_short(frames, camera, meta: dict) -> list:
    """Crashes on samples of under 10 frames; finds nothing elsewhere."""
    if meta["frames"] < 10:
        ctypes.string_at(0)
    return []

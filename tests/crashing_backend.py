"""A detector backend that aborts its worker process on an all-black image, for crash tests.

Its registry row names it by module path (:data:`MODULE`): the backend's worker process imports
it from the project root (:mod:`pipeline.backends.isolated`). Otherwise it finds markers as
OpenCV does.
"""

from __future__ import annotations

import os

import numpy as np

from pipeline.backends import Found, PoseRequest, opencv

#: The adapter's module path, as a registry row names it.
MODULE = "tests.crashing_backend"


def load() -> None:
    """Nothing to install."""


def detect(image: np.ndarray, config, frame_side_px: int, pose: PoseRequest | None) -> Found:
    """OpenCV's ids and corners; on an all-black image, the death of this process (SIGABRT, as
    a heap corruption in native code ends)."""
    if not image.any():
        os.abort()
    return opencv.detect(image, config, frame_side_px, pose)

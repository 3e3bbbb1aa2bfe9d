"""A detector backend whose worker process dies on about one image in three: the study's crash
isolation test (tests/test_study_detectors.py).

Its registry row names it by module path (:data:`MODULE`): the backend's worker process imports
it from the project root (:mod:`pipeline.backends.isolated`). It finds markers as OpenCV does and
calls ``os.abort()`` (SIGABRT, as a heap corruption in native code ends) on the images
:func:`crashes` picks, so the test can count them. (tests/crashing_backend.py dies on all-black
frames only, which a study never draws.)
"""

from __future__ import annotations

import os

import numpy as np

from pipeline.backends import Found, PoseRequest, opencv

#: The adapter's module path, as a registry row names it.
MODULE = "tests.crashing_study_backend"


def crashes(image: np.ndarray) -> bool:
    """Whether this backend dies on ``image``: about one image in three, by its pixels."""
    return int(image.sum(dtype=np.int64)) % 3 == 0


def load() -> None:
    """Nothing to install."""


def detect(image: np.ndarray, config, frame_side_px: int, pose: PoseRequest | None) -> Found:
    """OpenCV's ids and corners, or the death of this process."""
    if crashes(image):
        os.abort()
    return opencv.detect(image, config, frame_side_px, pose)

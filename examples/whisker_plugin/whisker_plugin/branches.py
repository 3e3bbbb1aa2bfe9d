"""A branch-finder plugin: the gap between the two neighbouring whiskers whose markers move most.

``find_branches(frames, camera, meta)`` gets a sample's frames (an iterator of (H, W) uint8
grey images, in order), its camera model and facts about it (``meta["array"]["marker_ids"]``:
the markers in whisker order), and returns the gaps it believes hold a branch as
``[(i, i + 1), ...]`` (an empty list: no branch). This one is deliberately simple: it measures
how far each marker moves from its first position (px) on every ``step``-th frame and names the
neighbouring pair that moves most, if that is more than ``MIN_MOTION_PX``.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from whisker_plugin.detector import detect

MIN_MOTION_PX = 4.0
FRAMES_LOOKED_AT = 30


def find_branches(frames: Iterable[np.ndarray], camera, meta: dict) -> list[tuple[int, int]]:
    """The gap next to the most-moved pair of whiskers, or none."""
    marker_ids = list(meta["array"]["marker_ids"])
    step = max(1, int(meta["frames"]) // FRAMES_LOOKED_AT)
    first: dict[int, np.ndarray] = {}
    moved = np.zeros(len(marker_ids))
    for k, frame in enumerate(frames):
        if k % step:
            continue
        for marker_id, corners in detect(frame):
            if marker_id not in marker_ids:
                continue
            centre = corners.mean(axis=0)
            start = first.setdefault(marker_id, centre)
            w = marker_ids.index(marker_id)
            moved[w] = max(moved[w], float(np.linalg.norm(centre - start)))
    pairs = moved[:-1] + moved[1:]
    best = int(np.argmax(pairs))
    return [(best, best + 1)] if pairs[best] > 2 * MIN_MOTION_PX else []

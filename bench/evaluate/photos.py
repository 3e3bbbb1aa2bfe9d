"""Corner refinements on real photographs of printed markers, against a consensus of detectors.

The set (``tests/data/real_markers``, its ``SOURCES.md`` names each file's origin and licence)
is public photographs only: no truth is known, so the reference is the **consensus** of
independent detectors. Each marker's corners come from OpenCV (``CORNER_REFINE_SUBPIX``) and
from each peer that decodes its family (locus, AprilTag 3: their own edge-fitted corners); the
consensus is the mean of the largest group of references whose corners lie within
:data:`AGREE_PX` of each other, at least two of them, and markers without such a group are left
out. :func:`consensus_table` computes it; ``consensus.csv`` beside the images stores it and
``tests/test_refine_photos.py`` recomputes it.

:func:`measure` then starts a refinement from a detector's corners (OpenCV's unrefined ones, as
``lines`` gets them in the pipelines, or a peer's) and reports, per marker: whether it fell
back and why, each corner's distance to the consensus before and after, and its signed
outward offset along the marker's diagonal (+: away from the centre). The photographs' lenses
are unknown and their markers are small against the frame, so each image is taken through an
exact pinhole (:func:`pinhole`) centred on it.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pandas as pd

from pipeline.backends import available, get_backend
from pipeline.detect import DetectorConfig, detect_markers
from pipeline.refine import refine_corners_by_edges
from scenes.camera import FisheyeCamera
from scenes.marker import get_dictionary
from scenes.tables import CORNER_COLUMNS

#: Where the set lives, from the project's root.
PHOTOS_DIR = Path(__file__).resolve().parents[2] / "tests" / "data" / "real_markers"
CONSENSUS_FILE = "consensus.csv"
#: Each photograph and the dictionary of its markers (the project's names).
PHOTOS: tuple[tuple[str, str], ...] = (
    ("fiducials_tag_01.png", "5x5_1000"),
    ("fiducials_tag_245_246.png", "5x5_1000"),
    ("fiducials_403.png", "5x5_1000"),
    ("opencv_singlemarkersoriginal.jpg", "6x6_250"),
    ("opencv_charuco_img_00.jpg", "6x6_250"),
    ("opencv_chocclusion_original.jpg", "6x6_250"),
    ("apriltag_34139872896.jpg", "apriltag_36h11"),
    ("apriltag_33369213973.jpg", "apriltag_36h11"),
)
REFERENCES = ("opencv", "locus", "apriltag")
#: References agree on a marker when every pair's corners are this close (px).
AGREE_PX = 1.0
#: A marker this long a side (px) or more is "large": the outward bias is measured on these.
LARGE_SIDE_PX = 100.0


def pinhole(image: np.ndarray) -> FisheyeCamera:
    """An exact pinhole (the unified model with xi = 0) with a 60-degree field across the image
    and its principal point at the centre: straight edges stay straight."""
    h, w = image.shape
    f = 0.5 * max(w, h) / np.tan(np.radians(30.0))
    return FisheyeCamera(
        width_px=w, height_px=h, fx_px=f, fy_px=f, cx_px=(w - 1) / 2, cy_px=(h - 1) / 2,
        theta_max_deg=80.0, model="ucm", params=(0.0,),
    )  # fmt: skip


def load(name: str, folder: Path = PHOTOS_DIR) -> np.ndarray:
    """The photograph as 8-bit grey (OpenCV's BGR -> grey weights)."""
    image = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise OSError(f"{folder / name}: cannot read the image")
    return image


def modules(dictionary: str) -> int:
    """Modules across a marker's black square."""
    return int(get_dictionary(dictionary).markerSize) + 2


def detector_corners(
    image: np.ndarray, dictionary: str, backend: str, refinement: str
) -> list[tuple[int, np.ndarray]]:
    """One detector's markers: (id, (4, 2) corners) each (ids may repeat)."""
    config = DetectorConfig(dictionary=dictionary, backend=backend, corner_refinement=refinement)
    return [(d.marker_id, d.corners_px) for d in detect_markers(image, config)]


def match(
    found: list[tuple[int, np.ndarray]], marker_id: int, corners: np.ndarray
) -> np.ndarray | None:
    """The corners in ``found`` of the same marker (same id, centre within a quarter side)."""
    centre = corners.mean(axis=0)
    side = np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1).mean()
    for other_id, other in found:
        if other_id == marker_id and np.linalg.norm(other.mean(axis=0) - centre) < side / 4:
            return other
    return None


def references(image: np.ndarray, dictionary: str) -> dict[str, list[tuple[int, np.ndarray]]]:
    """Each reference detector's markers (OpenCV's sub-pixel corners, the peers' own), for
    those that decode the family and are installed."""
    out = {}
    for name in REFERENCES:
        if dictionary in get_backend(name).families and available(name):
            refinement = "subpix" if name == "opencv" else "none"
            out[name] = detector_corners(image, dictionary, name, refinement)
    return out


def agreeing(corners: dict[str, np.ndarray]) -> tuple[str, ...]:
    """The largest group (at least two) of references whose corners agree pairwise."""
    names = sorted(corners)
    for size in range(len(names), 1, -1):
        for group in itertools.combinations(names, size):
            if all(
                np.linalg.norm(corners[a] - corners[b], axis=1).max() <= AGREE_PX
                for a, b in itertools.combinations(group, 2)
            ):
                return group
    return ()


def consensus_table(folder: Path = PHOTOS_DIR) -> pd.DataFrame:
    """One row per marker with an agreeing group: file, dictionary, marker id, the consensus
    corners, the references that agree and their largest distance from the consensus (px)."""
    rows = []
    for name, dictionary in PHOTOS:
        refs = references(load(name, folder), dictionary)
        seen: list[tuple[int, np.ndarray]] = []
        for marker_id, first in (m for found in refs.values() for m in found):
            if match(seen, marker_id, first) is not None:
                continue  # already taken from an earlier reference
            seen.append((marker_id, first))
            corners = {r: match(found, marker_id, first) for r, found in refs.items()}
            corners = {r: c for r, c in corners.items() if c is not None}
            group = agreeing(corners)
            if not group:
                continue
            mean = np.mean([corners[r] for r in group], axis=0)
            spread = max(np.linalg.norm(corners[r] - mean, axis=1).max() for r in group)
            row = {"file": name, "dictionary": dictionary, "marker_id": marker_id}
            for k, (x, y) in enumerate(CORNER_COLUMNS):
                row[x], row[y] = round(float(mean[k, 0]), 4), round(float(mean[k, 1]), 4)
            row.update(references="+".join(group), spread_px=round(float(spread), 4))
            rows.append(row)
    return pd.DataFrame(rows)


def read_consensus(folder: Path = PHOTOS_DIR) -> pd.DataFrame:
    """The committed consensus table (``consensus.csv``)."""
    return pd.read_csv(folder / CONSENSUS_FILE)


def consensus_corners(row) -> np.ndarray:
    """(4, 2) corners of one consensus row (a mapping of its columns)."""
    return np.array([[row[x], row[y]] for x, y in CORNER_COLUMNS], dtype=float)


class Outcome(NamedTuple):
    """One marker's refinement against the consensus."""

    file: str
    marker_id: int
    side_px: float
    failure: str | None
    before_px: np.ndarray  # (4,) each input corner's distance to the consensus
    after_px: np.ndarray  # (4,) the same for the refined corners (= before where it fell back)
    outward_px: np.ndarray  # (4,) refined minus consensus along the diagonal, + outward


def outward(corners: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(4,) signed offset of each corner from the truth along the marker's diagonal (+ outward)."""
    out = truth - truth.mean(axis=0)
    out /= np.linalg.norm(out, axis=1)[:, None]
    return ((corners - truth) * out).sum(axis=1)


def measure(
    method: str, start: str = "opencv", transfer: str = "auto", folder: Path = PHOTOS_DIR
) -> list[Outcome]:
    """Each consensus marker refined by ``method`` ("lines", or a detector's own corners:
    "subpix" for OpenCV's, "locus", "apriltag") from ``start``'s corners ("opencv": unrefined,
    or a peer's own), where ``start`` finds it."""
    table = read_consensus(folder)
    outcomes = []
    for (name, dictionary), rows in table.groupby(["file", "dictionary"], sort=False):
        if method != "lines" and method != "subpix":
            start = method
        if dictionary not in get_backend(start).families:
            continue
        image = load(name, folder)
        camera = pinhole(image)
        refinement = "subpix" if method == "subpix" else "none"
        found = detector_corners(image, dictionary, start, refinement)
        for row in rows.to_dict("records"):
            truth = consensus_corners(row)
            begin = match(found, row["marker_id"], truth)
            if begin is None:
                continue
            corners, failure = begin, None
            if method == "lines":
                corners, failure = refine_corners_by_edges(
                    image, begin, camera, modules(dictionary), transfer=transfer
                )
            side = float(np.linalg.norm(truth - np.roll(truth, 1, axis=0), axis=1).mean())
            outcomes.append(
                Outcome(
                    name,
                    int(row["marker_id"]),
                    side,
                    failure,
                    np.linalg.norm(begin - truth, axis=1),
                    np.linalg.norm(corners - truth, axis=1),
                    outward(corners, truth),
                )  # fmt: skip
            )
    return outcomes


#: A refined corner counts as further from the consensus than its input corner when it is
#: further by more than this (px): below it the consensus' own uncertainty (its references
#: differ by 0.1-0.6 px) decides.
WORSE_PX = 0.25


class Figures(NamedTuple):
    """A method's figures on the set (see docs/refine_real.md)."""

    markers: int
    fallback_rate: float
    reasons: dict[str, int]
    median_before_px: float  # of the input corners' distances to the consensus
    median_after_px: float  # of the output corners' (the input's where it fell back)
    worse_markers: int  # refined, with a corner further than its input's by WORSE_PX
    large_markers: int  # refined, LARGE_SIDE_PX or more a side
    large_outward_px: float  # mean signed outward offset of their corners (NaN: none)


def figures(outcomes: list[Outcome]) -> Figures:
    """The figures of one method's outcomes."""
    refined = [o for o in outcomes if o.failure is None]
    reasons: dict[str, int] = {}
    for o in outcomes:
        if o.failure is not None:
            reasons[o.failure] = reasons.get(o.failure, 0) + 1
    large = [o.outward_px for o in refined if o.side_px >= LARGE_SIDE_PX]
    return Figures(
        len(outcomes),
        1.0 - len(refined) / max(len(outcomes), 1),
        reasons,
        float(np.median(np.concatenate([o.before_px for o in outcomes]))),
        float(np.median(np.concatenate([o.after_px for o in outcomes]))),
        sum(bool(np.any(o.after_px > o.before_px + WORSE_PX)) for o in refined),
        len(large),
        float(np.mean(np.concatenate(large))) if large else float("nan"),
    )

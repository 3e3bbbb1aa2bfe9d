"""``whiskerbench detect-images``: pipelines' detectors on still photographs, scored against an
optional ground-truth file, so a user can compare pipelines on their own images.

Only a pipeline's detector runs (a still image has no track, no branch): each image is read
once, grey, 8-bit, and every pipeline's detector finds its markers, timed alone (image reading
excluded). Corners follow :mod:`scenes.conventions` (pixel centres at integer coordinates,
ArUco corner order), in the image's pixels as stored in the file (EXIF orientation is not
applied). ``lines`` refinement needs a camera model: the user's (:mod:`scenes.profile`,
:mod:`scenes.calibration_import`), else :func:`scenes.camera.pinhole_camera` sized to each image.

Bad input raises :class:`bench.common.stills.StillImageError` (:class:`ImageInputError` for
the lists and the truth file) naming the file. Every output is written at the end (atomically),
so an image refused halfway through leaves nothing behind. A backend that crashes on an image
costs that image (``failures.csv``), not the run.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pandas as pd
from tqdm import tqdm

from bench.common.atomic import write_bytes
from bench.common.image_header import ImageHeaderError, read_image_header
from bench.common.manifest import (
    RunClock,
    build_manifest,
    hash_files,
    input_digests,
    write_manifest,
)
from bench.common.stills import IMAGE_SUFFIXES, StillImageError, read_grey
from bench.common.video import draw_preview
from bench.evaluate.results_file import OUTSIDE_PX
from pipeline.backends import BackendCrashError
from pipeline.detect import detect_markers
from pipeline.presets import PipelineConfig
from scenes.bounded_read import NOT_UTF8, input_problem, is_utf8
from scenes.camera import FisheyeCamera, pinhole_camera
from scenes.input_limits import FRAME_PIXELS, FRAME_SIDE_PX, IMAGES_PER_RUN, TRUTH_CSV_BYTES
from scenes.marker import get_dictionary

KIND = "detect-images"
#: Most images one run reads: bounds the detections table and the manifest's digests.
MAX_IMAGES = IMAGES_PER_RUN
#: Largest image read (pixels): a 100 MP photograph; its colour decode is 300 MB.
MAX_IMAGE_PIXELS = FRAME_PIXELS
#: Largest truth file read: a row is about 100 bytes, so a million markers.
MAX_TRUTH_BYTES = TRUTH_CSV_BYTES
CORNER_COLUMNS = tuple(f"{axis}{k}" for k in range(4) for axis in "xy")  # x0, y0, ..., y3
KEY = ("image", "marker_id")
TRUTH_COLUMNS = (*KEY, *CORNER_COLUMNS)
DETECTION_COLUMNS = ("image", "pipeline", "marker_id", *CORNER_COLUMNS, "refine_failure")


class ImageInputError(StillImageError):
    """An image, folder or truth file the command cannot use; the message names it."""


class Truth(NamedTuple):
    """A validated ground-truth file: its path and its rows (:data:`TRUTH_COLUMNS`)."""

    path: Path
    table: pd.DataFrame


# --- Inputs -------------------------------------------------------------------------------------


def image_files(paths: Sequence[Path]) -> list[Path]:
    """The image files the arguments name (a folder: its images, sorted), each checked to be an
    image OpenCV can decode (by its signature; the pixels are read later)."""
    files: list[Path] = []
    for path in map(Path, paths):
        if path.is_dir():
            found = sorted(
                p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
            )
            if not found:
                raise ImageInputError(f"{path}: no images ({', '.join(IMAGE_SUFFIXES)}) in folder")
            files += found
        elif not path.is_file():
            raise ImageInputError(f"{path}: {input_problem(path) or 'no such file or folder'}")
        elif path.suffix.lower() not in IMAGE_SUFFIXES:
            raise ImageInputError(f"{path}: not an image name (one of {', '.join(IMAGE_SUFFIXES)})")
        else:
            files.append(path)
        if len(files) > MAX_IMAGES:
            raise ImageInputError(f"{path}: over {MAX_IMAGES} images; at most {MAX_IMAGES} a run")
    name, count = Counter(p.name for p in files).most_common(1)[0]
    if count > 1:
        raise ImageInputError(
            f"{name}: {count} images have this file name; the results and the truth file name "
            "images by file name, so give each once"
        )
    for path in files:
        if not is_utf8(path):
            raise ImageInputError(f"{path}: {NOT_UTF8}")
        if not cv2.haveImageReader(str(path)):
            raise ImageInputError(f"{path}: not a readable image")
    return files


def read_truth(path: Path, files: Sequence[Path], dictionary: str) -> Truth:
    """The ground-truth CSV (:data:`TRUTH_COLUMNS`; ``image`` is a file name among ``files``,
    corners in ArUco order and the project's pixel convention), fully checked: every refusal
    names the line and the column."""
    path = Path(path)
    if not path.is_file():  # a FIFO or device would block or never end
        raise ImageInputError(f"{path}: {input_problem(path) or 'no such file'}")
    if path.stat().st_size > MAX_TRUTH_BYTES:
        raise ImageInputError(f"{path}: larger than {MAX_TRUTH_BYTES >> 20} MiB")
    try:
        table = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ImageInputError(f"{path}: not a readable CSV file ({reason})") from None
    missing = [c for c in TRUTH_COLUMNS if c not in table.columns]
    if missing:
        raise ImageInputError(
            f"{path}: missing column(s) {', '.join(missing)}; needs {', '.join(TRUTH_COLUMNS)}"
        )
    extra = [c for c in table.columns if c not in TRUTH_COLUMNS]
    if extra:  # as the results format: a column read by nobody may be a column misnamed
        raise ImageInputError(
            f"{path}: column {extra[0]!r} is not in the format; expected {', '.join(TRUTH_COLUMNS)}"
        )
    table = table[list(TRUTH_COLUMNS)]
    names = {p.name for p in files}
    ids = int(get_dictionary(dictionary).bytesList.shape[0])
    for line, row in zip(range(2, len(table) + 2), table.itertuples(index=False), strict=True):
        where = f"{path}: line {line}"
        if row.image not in names:
            raise ImageInputError(f"{where}: image {row.image!r} is not among the images given")
        if not row.marker_id.isdigit() or int(row.marker_id) >= ids:
            raise ImageInputError(
                f"{where}: marker_id={row.marker_id!r}: family {dictionary} has ids 0..{ids - 1}"
            )
        for column in CORNER_COLUMNS:
            text = getattr(row, column)
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise ImageInputError(f"{where}: {column}={text!r} is not a finite number")
            if abs(value) > FRAME_SIDE_PX:  # no image is wider: a corner this far is no corner
                raise ImageInputError(
                    f"{where}: {column}={text!r} is outside -{FRAME_SIDE_PX}..{FRAME_SIDE_PX} px"
                )
    table = table.astype({"marker_id": int, **dict.fromkeys(CORNER_COLUMNS, float)})
    repeated = table.duplicated(list(KEY))
    if repeated.any():
        k = int(np.flatnonzero(repeated)[0])
        raise ImageInputError(
            f"{path}: line {k + 2}: marker {table.marker_id[k]} of {table.image[k]} is listed twice"
        )
    _check_inside(path, table, files)
    return Truth(path, table)


def _check_inside(path: Path, table: pd.DataFrame, files: Sequence[Path]) -> None:
    """Refuse a truth corner over OUTSIDE_PX past its image's edge: the detectors find only
    markers wholly in the image (none of paper, fast, robust, naive, hybrid, locus finds one whose
    edge touches it), so such a corner is a typo or a marker no method can find."""
    by_name = {p.name: p for p in files}
    sizes = {}
    for name in table.image.unique():
        try:
            header = read_image_header(by_name[name], MAX_IMAGE_PIXELS)
        except ImageHeaderError as exc:  # the image's fault, not the truth file's
            raise StillImageError(f"{by_name[name]}: {exc}") from None
        sizes[name] = (header.width, header.height)
    size = np.array([sizes[n] for n in table.image], float).reshape(-1, 2)
    corners = table[list(CORNER_COLUMNS)].to_numpy(float).reshape(-1, 4, 2)
    bad = (corners < -0.5 - OUTSIDE_PX) | (corners > size[:, None, :] - 0.5 + OUTSIDE_PX)
    if bad.any():
        k, corner, axis = np.argwhere(bad)[0]
        w, h = sizes[table.image[k]]
        column = CORNER_COLUMNS[2 * corner + axis]
        raise ImageInputError(
            f"{path}: line {k + 2}: {column}={table[column][k]:g} is outside image "
            f"{table.image[k]} ({w} x {h} px): expected -0.5 .. {(w, h)[axis] - 0.5:g} px with "
            f"{OUTSIDE_PX:g} px of slack (a marker the frame cuts is found by no detector)"
        )


def _camera_for(path: Path, image: np.ndarray, camera: FisheyeCamera | None) -> FisheyeCamera:
    height, width = image.shape
    if camera is None:
        return pinhole_camera(width, height)
    if (camera.width_px, camera.height_px) != (width, height):
        raise ImageInputError(
            f"{path}: {width} x {height} px, but the camera (--camera) is "
            f"{camera.width_px} x {camera.height_px} px"
        )
    return camera


# --- Detection ----------------------------------------------------------------------------------


def with_family(pipelines: Sequence[PipelineConfig], family: str) -> list[PipelineConfig]:
    """The pipelines with their detectors on ``family``; ValueError (one line) for a backend
    that cannot detect it."""
    return [p.with_family(family) for p in pipelines]


def detect_images(
    files: Sequence[Path],
    pipelines: Sequence[PipelineConfig],
    camera: FisheyeCamera | None = None,
    progress: bool = False,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(detections: :data:`DETECTION_COLUMNS`; runs: one row per image and pipeline with its
    ``ms`` and, where the backend crashed on it, its ``failure``)."""
    warm = np.full((64, 64), 255, np.uint8)  # a peer's first call starts its worker: not timed
    for p in pipelines:
        with contextlib.suppress(BackendCrashError):  # the next call starts a fresh worker
            detect_markers(warm, p.detector, camera=pinhole_camera(64, 64))
    detections, runs = [], []
    for path in tqdm(files, desc=KIND, unit="image", disable=not progress):
        image = read_grey(path, MAX_IMAGE_PIXELS)
        lens = _camera_for(path, image, camera)
        for p in pipelines:
            failure, t0 = None, time.perf_counter()
            try:
                found = detect_markers(image, p.detector, camera=lens)
            except BackendCrashError as exc:
                failure, found = str(exc), []
            runs.append((path.name, p.name, 1e3 * (time.perf_counter() - t0), failure))
            detections += [
                (path.name, p.name, d.marker_id, *d.corners_px.ravel(), d.refine_failure or "")
                for d in found
            ]
    return (
        pd.DataFrame(detections, columns=list(DETECTION_COLUMNS)),
        pd.DataFrame(runs, columns=["image", "pipeline", "ms", "failure"]),
    )


# --- Scores -------------------------------------------------------------------------------------


def corner_errors(detections: pd.DataFrame, truth: pd.DataFrame) -> pd.Series:
    """Per detection, the mean distance (px) of its 4 corners to the truth's marker of the same
    image and id (as :mod:`bench.common.marker_score`); NaN where the truth has none."""
    joined = detections[list(KEY)].merge(truth, on=list(KEY), how="left", validate="many_to_one")
    est = detections[list(CORNER_COLUMNS)].to_numpy(float).reshape(-1, 4, 2)
    true = joined[list(CORNER_COLUMNS)].to_numpy(float).reshape(-1, 4, 2)
    return pd.Series(np.linalg.norm(est - true, axis=2).mean(axis=1), index=detections.index)


def summarize(
    detections: pd.DataFrame, runs: pd.DataFrame, truth: pd.DataFrame | None
) -> pd.DataFrame:
    """One row per pipeline: images, detections, failed images, ms per image, ``lines``
    fallbacks; with a truth: markers, recall, false ids (a detection matching no truth marker,
    or a second one of the same marker) and corner error over the found markers (the best
    detection of each)."""
    rows = []
    for name, run in runs.groupby("pipeline", sort=False):
        found = detections[detections.pipeline == name]
        row = {
            "pipeline": name,
            "images": len(run),
            "detections": len(found),
            "failed_images": int(run.failure.notna().sum()),
            "ms_per_image": float(run.ms.mean()),
            "lines_fallbacks": int((found.refine_failure != "").sum()),
        }
        if truth is not None:
            errors = found["corner_err_px"].dropna()
            best = errors.groupby([found.image, found.marker_id]).min()
            row.update(
                markers=len(truth),
                recall=len(best) / len(truth) if len(truth) else math.nan,
                false_ids=len(found) - len(best),
                corner_err_mean_px=float(best.mean()) if len(best) else math.nan,
                corner_err_median_px=float(best.median()) if len(best) else math.nan,
                corner_err_max_px=float(best.max()) if len(best) else math.nan,
            )
        rows.append(row)
    return pd.DataFrame(rows)


# --- The job ------------------------------------------------------------------------------------


def _csv(table: pd.DataFrame) -> bytes:
    return table.to_csv(index=False, float_format="%.6g", lineterminator="\n").encode()


def _overlays(files, detections, truth, out: Path) -> list[Path]:
    """One PNG per image and pipeline: detections green, truth (where given) magenta."""
    written = []
    for path in files:
        image = read_grey(path, MAX_IMAGE_PIXELS)
        if truth is not None:
            rows = truth[truth.image == path.name]
            quads = rows[list(CORNER_COLUMNS)].to_numpy(float).reshape(-1, 4, 2)
            image = draw_preview(image, quads, rows.marker_id, np.zeros(len(rows), bool))
        for name, found in detections[detections.image == path.name].groupby("pipeline"):
            quads = found[list(CORNER_COLUMNS)].to_numpy(float).reshape(-1, 4, 2)
            drawn = draw_preview(image, quads, found.marker_id, text=f"{name}: {path.name}")
            target = out / "overlays" / name.replace("/", "~") / f"{path.stem}.png"
            write_bytes(target, cv2.imencode(".png", drawn)[1].tobytes())
            written.append(target)
    return written


def run_detect_images(
    files: Sequence[Path],
    pipelines: Sequence[PipelineConfig],
    out: Path,
    camera: FisheyeCamera | None = None,
    truth: Truth | None = None,
    overlays: bool = False,
    progress: bool = False,
) -> pd.DataFrame:
    """Detect, score and write ``detections.csv``, ``summary.csv`` (and overlays) into ``out``
    with its manifest; return the summary."""
    clock = RunClock()
    detections, runs = detect_images(files, pipelines, camera, progress)
    truth_table = None if truth is None else truth.table
    if truth_table is not None:
        detections["corner_err_px"] = corner_errors(detections, truth_table)
    summary = summarize(detections, runs, truth_table)
    # --- Outputs, all at the end
    out = Path(out)
    written = _overlays(files, detections, truth_table, out) if overlays else []
    tables = {"detections.csv": detections, "summary.csv": summary}
    failures = runs[runs.failure.notna()]
    if len(failures):  # the images a backend crashed on, named with the backend's message
        tables["failures.csv"] = failures
    for name, table in tables.items():
        write_bytes(out / name, _csv(table))
        written.append(out / name)
    config = {
        "pipelines": [p.to_json() for p in pipelines],
        "camera": None if camera is None else camera.to_dict()["model"],
        "truth": None if truth is None else str(truth.path),
        "overlays": overlays,
    }
    inputs = input_digests([*files, *([truth.path] if truth is not None else [])])
    write_manifest(
        out,
        build_manifest(KIND, clock, config, inputs=inputs, outputs=hash_files(written, out)),
    )
    return summary

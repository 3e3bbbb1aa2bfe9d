"""``whiskerbench detect-images``: options and command (bad input: one line, exit code 2,
nothing written)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from bench.cli.args import RUNS, check_out_folder
from bench.cli.evaluate import VARIANT_HELP, pipelines
from scenes.calibration_import import FORMATS
from scenes.validation import FieldError

DEFAULT_OUT = RUNS / "detect-images"
#: More images than this get a progress bar (on a terminal).
PROGRESS_MIN_IMAGES = 3
DESCRIPTION = """\
Run pipelines' marker detectors on still images (photographs of printed ArUco or AprilTag
markers) and, given a ground-truth file, score them. Only each pipeline's detector runs (no
tracking, no branches). Writes detections.csv (image, pipeline, marker_id, corners x0,y0..x3,y3,
refine_failure), summary.csv (per pipeline: images, detections, ms per image, lines fallbacks;
with --truth also recall, false ids, corner error) and manifest.json.

Pixel convention of every corner (output and --truth): (x, y) = (column, row), the centre of
the top-left pixel at (0, 0) (OpenCV's), in the image as stored (EXIF orientation not
applied); corners in ArUco order: top-left, top-right, bottom-right, bottom-left of the marker
as printed.
"""


def add_images_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``detect-images`` on the top-level subparsers."""
    p = subparsers.add_parser(
        "detect-images",
        help="run pipelines' detectors on still images; score them against a truth file",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "images",
        nargs="+",
        type=Path,
        metavar="IMAGES",
        help="image files (png, jpg, bmp, tif; 8-bit grey or colour, read as grey) and/or "
        "folders of them; file names must be distinct",
    )
    p.add_argument(
        "--pipelines",
        type=pipelines,
        required=True,
        metavar="NAME,...",
        help="pipelines whose detectors run, comma-separated; each " + VARIANT_HELP,
    )
    p.add_argument(
        "--truth",
        type=Path,
        metavar="FILE",
        help="ground-truth CSV with columns image (a file name among IMAGES), marker_id, x0, "
        "y0, x1, y1, x2, y2, x3, y3 (corners in ArUco order, the pixel convention above, at most "
        "8 px outside the image) and no other; one row per marker; images without rows have no "
        "markers",
    )
    p.add_argument(
        "--camera",
        metavar="PROFILE",
        help="camera model for lines refinement: a shipped profile name, a profile JSON, or with "
        "--camera-format a calibration file; its size must match every image (default: a "
        "pinhole model sized to each image, exact for lines on undistorted images)",
    )
    p.add_argument(
        "--camera-format",
        choices=FORMATS,
        help="--camera is a calibration file in this format (camera 0 of it)",
    )
    p.add_argument(
        "--family",
        metavar="NAME",
        help="marker family replacing each pipeline's (4x4_50, apriltag_36h11, apriltag_16h5, "
        "... OpenCV's dictionary names, lower case); a detector that cannot read it is refused",
    )
    p.add_argument("--out", type=Path, help=f"output folder (default {DEFAULT_OUT})")
    p.add_argument(
        "--overlays",
        action="store_true",
        help="also write overlays/<pipeline>/<image>.png: detections green, truth magenta",
    )
    p.set_defaults(func=cmd_detect_images)


def _camera(option: str, fmt: str | None):
    """The --camera lens; ValueError with the message's detail."""
    from scenes.calibration_import import CalibrationError, import_calibration
    from scenes.profile import ProfileError, load_profile

    if fmt is not None:
        try:
            return import_calibration(option, fmt)
        except CalibrationError as exc:
            raise ValueError(str(exc)) from None
    try:
        return load_profile(option).lens
    except ProfileError as exc:
        raise ValueError(exc.option_detail) from None


def cmd_detect_images(args: argparse.Namespace) -> int:
    from bench.common.run_folder import claim_out
    from bench.common.stills import StillImageError
    from bench.evaluate.images import (
        KIND,
        ImageInputError,
        image_files,
        read_truth,
        run_detect_images,
        with_family,
    )
    from pipeline.backends import BackendUnavailableError, require

    def fail(message: str) -> int:
        print(f"whiskerbench detect-images: error: {' '.join(message.split())}", file=sys.stderr)
        return 2

    pipelines = args.pipelines
    if args.family is not None:
        try:
            pipelines = with_family(pipelines, args.family)
        except ValueError as exc:
            return fail(f"--family: {exc}")
    try:
        for backend in dict.fromkeys(b for p in pipelines for b in p.backends):
            require(backend)
    except BackendUnavailableError as exc:
        return fail(f"--pipelines: {exc}")
    if args.camera_format is not None and args.camera is None:
        return fail("--camera-format: needs --camera (the calibration file)")
    try:
        camera = None if args.camera is None else _camera(args.camera, args.camera_format)
    except ValueError as exc:
        return fail(f"--camera: {exc}")
    try:
        files = image_files(args.images)
    except ImageInputError as exc:
        return fail(str(exc))
    try:
        truth = None
        if args.truth is not None:
            truth = read_truth(args.truth, files, pipelines[0].detector.dictionary)
    except ImageInputError as exc:
        return fail(f"--truth: {exc}")
    except StillImageError as exc:  # an image whose header the truth's corners are checked on
        return fail(str(exc))
    out = args.out if args.out is not None else DEFAULT_OUT
    try:
        check_out_folder(out)
        claim_out(out, KIND)
    except FieldError as exc:
        return fail(f"--out: {exc.detail}")
    args.kept = "nothing was written (every output is written at the end)"
    progress = sys.stderr.isatty() and len(files) > PROGRESS_MIN_IMAGES
    try:
        summary = run_detect_images(files, pipelines, out, camera, truth, args.overlays, progress)
    except StillImageError as exc:  # an image found unusable when read: nothing written yet
        return fail(str(exc))
    print(_table(summary, len(files)))
    print(f"wrote {out}/detections.csv, summary.csv" + (", overlays/" if args.overlays else ""))
    for row in summary[summary.failed_images > 0].itertuples():
        print(
            f"warning: {row.pipeline}: its detector crashed on {row.failed_images} image(s); "
            f"see {out}/failures.csv",
            file=sys.stderr,
        )
    return 0


def _table(summary, images: int) -> str:
    """The summary as aligned text, one line per pipeline."""
    lines = [f"{images} images"]
    for row in summary.to_dict("records"):
        text = (
            f"{row['pipeline']:>24}: {row['detections']:5d} detections, "
            f"{row['ms_per_image']:8.1f} ms/image, lines fallbacks {row['lines_fallbacks']}"
        )
        if "recall" in row:
            err = row["corner_err_median_px"]
            text += f", recall {row['recall']:.3f}, false ids {row['false_ids']}, corner error " + (
                f"median {err:.3f} mean {row['corner_err_mean_px']:.3f} max "
                f"{row['corner_err_max_px']:.3f} px"
                if math.isfinite(err)
                else "n/a"
            )
        lines.append(text)
    return "\n".join(lines)

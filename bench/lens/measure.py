"""``whiskerbench lens measure``: fit a camera twin's optics, noise and stream from footage.

From frames of ArUco markers (their black borders are slanted edges) the PSF widths along and
across the radius are measured in bins of field angle (:mod:`bench.lens.edges`,
:mod:`bench.lens.psf`); from runs of still frames, full well and read noise by photon transfer
(:mod:`bench.lens.noise`); from the first JPEG frame's headers, the stream's quality and chroma
subsampling (:mod:`bench.lens.jpeg`). What the camera's own processing (demosaicing,
sharpening, MJPEG) adds to an edge's width is found by running the profile's stages on sharp
synthetic markers and taken off (:mod:`bench.lens.calibrate`). The result is the input profile
with the measured numbers replaced, each with a ``sources`` entry naming the footage and date
(:mod:`bench.lens.profile`), plus a report.

Frames are streamed (at most ``max_frames`` are read) so memory stays bounded by a few frames.
"""

from __future__ import annotations

import datetime
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bench.common.stills import IMAGE_SUFFIXES, StillImageError, read_grey
from bench.common.video import check_video, read_video
from bench.common.video_bounds import VideoBoundsError
from bench.lens.calibrate import lens_variance, needs_calibration, processing_curve
from bench.lens.edges import PIXEL_VARIANCE_PX2, edge_geometry, edge_samples, fit_edges
from bench.lens.jpeg import stream_report
from bench.lens.noise import PhotonTransfer
from bench.lens.profile import with_noise, with_psf, with_stream
from bench.lens.psf import solve_bins
from pipeline.detect import DetectorConfig, detect_markers
from pipeline.refine import LINEAR_LUTS  # code -> linear light per transfer curve
from scenes.bounded_read import NOT_UTF8, input_problem, is_utf8
from scenes.input_limits import FRAME_PIXELS
from scenes.marker import check_dictionary
from scenes.profile import CameraProfile
from scenes.validation import FieldError

JPEG_SUFFIXES = (".jpg", ".jpeg")
DEFAULT_MAX_FRAMES = 300
DEFAULT_BIN_DEG = 10.0
MAX_FRAMES_LIMIT = 100_000
REPORT_FORMAT = "whiskerbench-lens-measure-report"


class MeasureConfigError(FieldError):
    """A bad ``lens measure`` setting; ``field`` is the keyword (bin_deg, max_frames, ...)."""


class FootageError(ValueError):
    """Footage that cannot be measured: unreadable, the wrong size, or no usable marker edges."""


# --- Frames -------------------------------------------------------------------------------------


def footage_files(footage: str | Path | Sequence[str | Path]) -> tuple[list[Path], bool]:
    """The footage's files and whether they are still images (else one video file); each
    name UTF-8 text (OpenCV cannot open another)."""
    files, images = _footage_files(footage)
    odd = next((p for p in files if not is_utf8(p)), None)
    if odd is not None:
        raise FootageError(f"{odd}: {NOT_UTF8}")
    return files, images


def _footage_files(footage: str | Path | Sequence[str | Path]) -> tuple[list[Path], bool]:
    if isinstance(footage, str | Path):
        path = Path(footage)
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not files:
                raise FootageError(f"{path}: no images ({', '.join(IMAGE_SUFFIXES)}) in folder")
            return files, True
        if not path.is_file():
            raise FootageError(f"{path}: {input_problem(path) or 'no such file or folder'}")
        return [path], path.suffix.lower() in IMAGE_SUFFIXES
    files = [Path(p) for p in footage]
    if not files:
        raise FootageError("footage: the list of images is empty")
    missing = [str(p) for p in files if not p.is_file()]
    if missing:
        raise FootageError(f"{missing[0]}: {input_problem(missing[0]) or 'no such file'}")
    return files, True


def iter_frames(files: list[Path], images: bool, max_frames: int) -> Iterator[np.ndarray]:
    """Grey uint8 frames, at most ``max_frames``; FootageError for an unreadable file."""
    if images:
        for path in files[:max_frames]:
            try:
                yield read_grey(path, FRAME_PIXELS)
            except StillImageError as exc:
                raise FootageError(str(exc)) from None
        return
    count = 0
    try:
        check_video(files[0])
    except VideoBoundsError as exc:  # over a bound, or a frame size that changes
        raise FootageError(f"{files[0]}: {exc}") from None
    except ValueError:
        pass  # not a video: read_video below says so
    try:
        for frame in read_video(files[0]):
            yield frame
            count += 1
            if count >= max_frames:
                return
    except ValueError as exc:  # unreadable, or cut off after `count` frames
        if count == 0:
            raise FootageError(f"{files[0]}: not a readable video or image ({exc})") from None


# --- Measurement --------------------------------------------------------------------------------


def _check_settings(dictionary: str, bin_deg: float, max_frames: int) -> str:
    try:
        dictionary = check_dictionary(dictionary)
    except ValueError as exc:
        raise MeasureConfigError("dictionary", str(exc).split(": ", 1)[-1]) from None
    ok = isinstance(bin_deg, int | float) and not isinstance(bin_deg, bool)
    if not (ok and 0.5 <= bin_deg <= 90.0):
        raise MeasureConfigError("bin_deg", f"{bin_deg!r}: allowed range is [0.5, 90] degrees")
    ok = isinstance(max_frames, int) and not isinstance(max_frames, bool)
    if not (ok and 1 <= max_frames <= MAX_FRAMES_LIMIT):
        raise MeasureConfigError(
            "max_frames", f"{max_frames!r}: allowed range is 1..{MAX_FRAMES_LIMIT}"
        )
    return dictionary


def measure_lens(
    footage: str | Path | Sequence[str | Path],
    profile: CameraProfile,
    dictionary: str = "4x4_50",
    bin_deg: float = DEFAULT_BIN_DEG,
    max_frames: int = DEFAULT_MAX_FRAMES,
    still: bool = False,
    date: str | None = None,
    progress: bool = False,
) -> tuple[CameraProfile, dict]:
    """The profile with PSF (and, where measured, sensor noise and stream) from the footage,
    and a report of every number behind it.

    ``footage``: a video file, a folder of images or a list of image paths; ``still`` treats
    every frame as one static scene for photon transfer (else still runs are detected);
    ``date`` (ISO, default today) goes into the sources; ``progress`` shows a bar over frames.
    Raises :class:`FootageError` when no marker edge is usable, MeasureConfigError for a bad
    setting.
    """
    dictionary = _check_settings(dictionary, bin_deg, max_frames)
    files, images = footage_files(footage)
    name = str(footage) if isinstance(footage, str | Path) else f"{files[0]} (+{len(files) - 1})"
    date = date or datetime.date.today().isoformat()
    stem = f"measured by whiskerbench lens measure from {name} on {date}"
    lut = LINEAR_LUTS[profile.processing.transfer]
    noise = PhotonTransfer(lut, all_still=still)
    stream = _stream(files, images)
    camera = with_stream(profile, stream, stem)  # the processing the footage went through
    # --- Frames: marker edges and still runs
    frames, markers, edges = _scan(
        files, images, max_frames, profile, dictionary, lut, noise, name, progress
    )
    used = [e for e in edges if e["status"] == "ok"]
    if not used:
        reasons = Counter(e["status"] for e in edges)
        raise FootageError(
            f"no usable marker edges in {name}: {frames} frames read, {markers} markers found"
            + (f", {len(edges)} edges rejected ({_counts(reasons)})" if edges else "")
        )
    # --- PSF: per-edge variance, less what the processing adds, solved per field bin
    variance = np.array([e["s_px"] for e in used]) ** 2 - PIXEL_VARIANCE_PX2
    if needs_calibration(camera):
        black = max(float(np.median([e["black"] for e in used])), 0.0)
        white = min(float(np.median([e["black"] + e["contrast"] for e in used])), 1.0)
        calibration = processing_curve(camera, dictionary, (black, white), lut)
        variance = lens_variance(variance, calibration)
    else:
        calibration = {"note": "none needed: grey sensor, no sharpening, no MJPEG"}
    for e, v in zip(used, variance, strict=True):
        e["theta_deg"], e["psi_deg"] = edge_geometry(e, profile.lens)
        e["lens_variance_px2"] = float(v)
    bins = solve_bins(
        np.array([e["theta_deg"] for e in used]), np.array([e["psi_deg"] for e in used]),
        variance, bin_deg,
    )  # fmt: skip
    solved = [b for b in bins if "sigma_radial_px" in b]
    if not solved:
        raise FootageError(
            f"no usable PSF bins in {name}: {len(used)} usable edges, but no {bin_deg:g} deg "
            "field bin has enough (try a larger --bin-deg or more footage)"
        )
    # --- Report and profile
    report = {
        "format": REPORT_FORMAT,
        "version": 1,
        "footage": name,
        "date": date,
        "camera": profile.name,
        "settings": {
            "dictionary": dictionary,
            "bin_deg": bin_deg,
            "max_frames": max_frames,
            "still": still,
            "transfer": profile.processing.transfer,
        },
        "frames_read": frames,
        "markers_found": markers,
        "edges_fitted": len(edges),
        "edges_used": len(used),
        "edges_rejected": dict(Counter(e["status"] for e in edges if e["status"] != "ok")),
        "processing_calibration": calibration,
        "psf_bins": bins,
        "psf_note": f"the table holds its end values outside {solved[0]['theta_mean_deg']:.1f}"
        f"..{solved[-1]['theta_mean_deg']:.1f} deg",
        "edges": [{k: e[k] for k in _EDGE_KEYS} for e in used],
        "noise": noise.result(),
        "stream": stream,
    }
    measured = with_psf(camera, report, solved, stem)
    refused = _noise_refusal(profile)
    if refused and "full_well_e" in report["noise"]:
        report["noise"]["not_applied"] = refused  # reported, but the profile keeps its own
        return measured, report
    return with_noise(measured, report["noise"], stem, jpeg=stream["codec"] == "mjpeg"), report


def _noise_refusal(profile: CameraProfile) -> str | None:
    """Why the photon-transfer fit must not replace the profile's sensor noise, or None.

    The fit sees the noise of the decoded grey frames, which is the photosites' own noise only
    for a grey sensor: demosaicing mixes neighbouring photosites into each pixel (on the
    dataset's own video of the GRBG prototype twin it returned a 3,279 e- well and 0 e- read
    noise for the set 6,457 and 2.02). Compression also removes noise; a fit through it is
    written with a source saying so (JPEG q95 stills: within 1% of the set well).
    """
    if profile.sensor.cfa != "none":
        return f"a {profile.sensor.cfa} colour sensor: the frames' noise is demosaiced"
    return None


_EDGE_KEYS = ("frame", "marker_id", "edge", "theta_deg", "psi_deg", "s_px", "s_err_px",
              "lens_variance_px2", "contrast", "rms_residual_fraction")  # fmt: skip


def _counts(counter: Counter) -> str:
    return ", ".join(f"{reason} {n}" for reason, n in counter.most_common())


def _scan(files, images, max_frames, profile, dictionary, lut, noise, name, progress=False):
    """Read the frames once: fit every marker edge, feed photon transfer. Returns (frames,
    markers, edge fits)."""
    lens = profile.lens
    detector = DetectorConfig(dictionary=dictionary)
    frames = markers = 0
    edges: list[dict] = []
    total = min(max_frames, len(files)) if images else max_frames
    with tqdm(
        total=total, desc="lens measure", unit="frame", disable=not progress, leave=False
    ) as bar:  # closed (cleared) before any error is printed
        for frame in iter_frames(files, images, max_frames):
            bar.update()
            if frame.shape != (lens.height_px, lens.width_px):
                raise FootageError(
                    f"{name}: frames are {frame.shape[1]} x {frame.shape[0]} px but the camera "
                    f"profile's lens is {lens.width_px} x {lens.height_px}"
                )
            linear = lut[frame]
            detections = detect_markers(frame, detector)
            samples = [
                e
                for d in detections
                for e in edge_samples(linear, frame, d.corners_px, dictionary, d.marker_id)
            ]
            for result in fit_edges(samples):
                result["frame"] = frames
                edges.append(result)
            noise.add(frame)
            frames += 1
            markers += len(detections)
    return frames, markers, edges


def _stream(files: list[Path], images: bool) -> dict:
    """The stream report of the first JPEG file (a video file is scanned for MJPEG frames)."""
    if not images:
        return stream_report(files[0])
    jpegs = [p for p in files if p.suffix.lower() in JPEG_SUFFIXES]
    if not jpegs:
        return {"codec": "none", "note": "no JPEG files in the footage; stream left as it was"}
    return stream_report(jpegs[0])

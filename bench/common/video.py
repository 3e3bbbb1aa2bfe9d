"""Video files of the benchmark: near-lossless H.264 .mp4 writing, grey reading, label previews.

Codec choice, measured here (2 cores shared with other jobs, so speeds vary up to 2x between
runs; opencv-contrib-python-headless 5.0.0.93; imageio-ffmpeg 0.8.1 = ffmpeg 9.0.2 + libx264).
Frames: 2592x1944 grey with 40-px ArUco 4x4 markers (white quiet zone) area-sampled from 8x
supersampling at sub-pixel positions, Gaussian noise sigma 2 levels. "band": a 250-row textured
band with 12 markers, the rest black (the real case); "full": textured everywhere, 108 markers.
Corner shift: distance between CORNER_REFINE_SUBPIX detections before and after encode + decode
through cv2.VideoCapture, over 192 (band) corners; no codec lost a marker.

  codec, setting                   corner shift px, band   fps            kB/frame     max |dI|
                                   median / p95 / max      band / full    band / full  band
  cv2 'mp4v' (no quality control)  0.040 / 0.155 / 0.333   69-84 / 13-25    62 / 385       64
  cv2 'FFV1' (lossless)            0 / 0 / 0               37-41 / 8-12    298 / 2283       0
  x264 ultrafast qp 0 (lossless)   0 / 0 / 0               73 / 12         382 / 2785       0
  x264 ultrafast qp 12 (chosen)    0.007 / 0.023 / 0.071   57-86 / 18-28   232 / 1768       3
  x264 ultrafast qp 16             0.011 / 0.044 / 0.096   53-67 / 16-18   162 / 1241       5
  x264 ultrafast crf 12            0.007 / 0.021 / 0.070   43-46 / 11-12   268 / 1264       3
  x264 veryfast crf 12             0.028 / 0.099 / 0.172   19-20 / -        81 / -         66
  x264 veryfast qp 12              0.010 / 0.037 / 0.093   15-27 / 2.5-4   120 / 1058       3

With qp 12 the full frames' 1728 corners move 0.007 / 0.020 / 0.100 px; without noise, band
frames give 0.005 / 0.014 / 0.024 px and 129 kB/frame. The wheel's own FFmpeg has no software
H.264 encoder ('avc1'/'H264' fail to open: only the hardware h264_v4l2m2m wrapper is built in);
its 'mp4v' ignores VIDEOWRITER_PROP_QUALITY (set() returns False) and rings by up to 64 levels
at marker edges; its VP9 ('VP90') runs at 2 fps; FFV1 in .mp4 plays in VLC/ffplay, not browsers.
Slower x264 presets add B-frames and psycho-visual rate control that takes bits from marker
edges (veryfast crf 12), and all run below 30 fps on 2 cores.

So: libx264 through the ffmpeg binary of the ``imageio-ffmpeg`` wheel, preset ultrafast
(Constrained Baseline profile: decodable by browsers, VLC, ffplay; not tried in a browser here),
constant quantizer ``qp`` 12 (one quantizer everywhere, so codec loss does not depend on the
content the way crf's does), 4:2:0 in full range: grey levels 0-255 are luma 0-255 unchanged,
where limited range would requantize to 220 levels and lose up to 1 level even losslessly.
``qp=0`` is exactly lossless (High 4:4:4 Predictive profile: VLC, ffplay and OpenCV, not
browsers), to separate codec effects from scene effects. A keyframe every 2 s keeps seeking
cheap; faststart puts the index first, for browsers and so that a cut-off file still opens and
is recognized as truncated.
"""

from __future__ import annotations

import errno
import itertools
import os
import queue
import subprocess
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, NamedTuple

# FFmpeg inside OpenCV prints its own complaints (e.g. "moov atom not found") on stderr; we
# report unreadable files ourselves, in one line.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
import cv2  # noqa: E402
import imageio_ffmpeg  # noqa: E402
import numpy as np  # noqa: E402

from bench.common.atomic import atomic_path
from bench.common.video_bounds import StreamFacts, check_stream
from scenes.bounded_read import NOT_UTF8, is_utf8

DEFAULT_QP = 12
PRESET = "ultrafast"
KEYFRAME_INTERVAL_S = 2.0

#: Fractional bits of the drawing coordinates: 1/16 px.
DRAW_SHIFT = 4
VISIBLE_BGR = (0, 255, 0)
HIDDEN_BGR = (255, 0, 255)
TOP_LEFT_RADIUS_PX = 3
FONT = cv2.FONT_HERSHEY_SIMPLEX
ID_FONT_SCALE = 0.4
CAPTION_FONT_SCALE = 0.6
CAPTION_PAD_PX = 4


class VideoInfo(NamedTuple):
    frame_count: int
    fps: float
    width: int
    height: int


# --- Writing -------------------------------------------------------------------------------------


def write_video(
    path: Path, frames: Iterable[np.ndarray], fps: float, *, qp: int = DEFAULT_QP
) -> int:
    """Encode uint8 grey (H, W) or BGR (H, W, 3) frames to an H.264 .mp4; return the frame count.

    Frames stream to ffmpeg one at a time (a video never sits in memory). The file appears only
    when encoding succeeded: any exception, including one raised by ``frames``, leaves no file
    and no temporary file, and an existing file at ``path`` untouched. H and W must be even (4:2:0
    chroma). ``qp``: 0 lossless, 12 near-lossless (see the module docstring), up to 51.
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if not 0 <= qp <= 51:
        raise ValueError(f"qp must be in 0..51, got {qp}")
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise ValueError(f"{path}: no frames to write")
    with atomic_path(Path(path)) as tmp:
        return _encode(tmp, itertools.chain([first], it), first.shape, fps, qp)


def _check_frame(frame: np.ndarray, shape: tuple[int, ...]) -> None:
    """Raise ValueError unless ``frame`` is uint8 grey or BGR, of even size, shaped as ``shape``."""
    if frame.dtype != np.uint8 or not (
        frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)
    ):
        raise ValueError(
            f"frames must be uint8 (H, W) or (H, W, 3), got {frame.dtype} {frame.shape}"
        )
    if frame.shape != shape:
        raise ValueError(f"frame shape {frame.shape} differs from the first frame's {shape}")
    if frame.shape[0] % 2 or frame.shape[1] % 2:
        raise ValueError(f"frame size {frame.shape[1]}x{frame.shape[0]} must be even (4:2:0)")


def _encode(
    out: Path, frames: Iterable[np.ndarray], shape: tuple[int, ...], fps: float, qp: int
) -> int:
    """Pipe ``frames`` into ffmpeg writing ``out``; kill ffmpeg if anything goes wrong."""
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(
            _ffmpeg_command(out, shape, fps, qp),
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=log,
        )
        try:
            count = _pipe_frames(proc.stdin, frames, shape)
        except BrokenPipeError:
            proc.wait()  # ffmpeg exited early: its log says why
            raise _ffmpeg_failure(out, proc.returncode, log) from None
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        if proc.wait() != 0:
            raise _ffmpeg_failure(out, proc.returncode, log)
    return count


def _ffmpeg_failure(out: Path, returncode: int, log: IO[bytes]) -> Exception:
    """RuntimeError with ffmpeg's log; OSError when the log names a full disk (the
    environment's failure, told as such by the command line)."""
    log.seek(0)
    message = log.read().decode(errors="replace").strip()[-2000:]
    if os.strerror(errno.ENOSPC) in message:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(out))
    return RuntimeError(f"ffmpeg failed (exit {returncode}) writing {out}: {message}")


def _pipe_frames(pipe: IO[bytes], frames: Iterable[np.ndarray], shape: tuple[int, ...]) -> int:
    count = 0
    for frame in frames:
        _check_frame(frame, shape)
        pipe.write(np.ascontiguousarray(frame).data)
        count += 1
    pipe.close()
    return count


def _ffmpeg_command(out: Path, shape: tuple[int, ...], fps: float, qp: int) -> list[str]:
    height, width = shape[:2]
    keyframe_interval = max(1, round(KEYFRAME_INTERVAL_S * fps))
    # Input "gray" is full range; output yuv420p tagged full range keeps the levels unchanged.
    return [
        imageio_ffmpeg.get_ffmpeg_exe(),
        "-hide_banner",
        "-loglevel", "error",
        "-f", "rawvideo",
        "-pix_fmt", "gray" if len(shape) == 2 else "bgr24",
        "-s", f"{width}x{height}",
        "-r", repr(float(fps)),
        "-i", "pipe:0",
        "-an",
        "-c:v", "libx264",
        "-preset", PRESET,
        "-qp", str(qp),
        "-g", str(keyframe_interval),
        "-pix_fmt", "yuv420p",
        "-color_range", "pc",
        "-movflags", "+faststart",
        "-f", "mp4",
        "-y", str(out),
    ]  # fmt: skip


# --- Reading -------------------------------------------------------------------------------------


def read_video(path: Path) -> Iterator[np.ndarray]:
    """Yield the frames of a video as grey uint8 (H, W) images: each frame decoded to BGR and
    converted to grey, or, where frame 0 shows that to be the same image, its luma plane as
    decoded (the project's videos: half the decoding time; :mod:`bench.common.grey_video`).

    Raises ValueError when the file cannot be opened, is over a bound or changes its frame
    size (:func:`check_video`, before the first frame is decoded), or, after the last frame,
    when fewer frames decoded than the container declares (a truncated or damaged file), so
    that a consumer never silently gets part of a video.
    """
    from bench.common.grey_video import GreyVideo  # which builds on this module

    count = 0
    with GreyVideo(path, seek=False) as video:
        for frame in video.frames():
            count += 1
            yield frame
        declared = video.frame_count
    if count == 0 or count < declared:
        raise ValueError(f"{path}: {count} frames decode of {declared} declared (truncated?)")


def video_info(path: Path) -> VideoInfo:
    """Frame count, fps and size of a video; ValueError for an unreadable or truncated file.

    The container's frame count is trusted only when its last frame decodes and nothing follows
    it (a seek, cheap); otherwise frames are counted by decoding them all, and a count below the
    declared one (data cut off after the index) is an error.
    """
    cap = open_capture(path)
    try:
        check_stream(cap, path)
        declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        confirmed = declared > 0 and _ends_at(cap, declared)
    finally:
        cap.release()
    count = declared if confirmed else _count_by_decoding(path)
    if count == 0 or count < declared:
        raise ValueError(f"{path}: {count} frames decode of {declared} declared (truncated?)")
    return VideoInfo(count, fps, width, height)


def check_video(path: Path) -> StreamFacts:
    """The video's frame size and packet count, bounded before any frame is decoded
    (:func:`bench.common.video_bounds.check_stream`): FileNotFoundError, or ValueError in one
    line without the path."""
    cap = open_capture(path)
    try:
        return check_stream(cap, path)
    finally:
        cap.release()


def open_capture(path: Path) -> cv2.VideoCapture:
    """An opened FFmpeg capture of ``path``: FileNotFoundError, or ValueError in one line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(path)
    if not is_utf8(path):
        raise ValueError(NOT_UTF8)
    log = cv2.utils.logging
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_ERROR)  # a failed open is reported below, in one line
    try:
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    finally:
        log.setLogLevel(level)
    if not cap.isOpened():
        raise ValueError("not a readable video")
    return cap


def _ends_at(cap: cv2.VideoCapture, count: int) -> bool:
    """True if frame ``count - 1`` decodes and no frame follows it."""
    cap.set(cv2.CAP_PROP_POS_FRAMES, count - 1)
    return cap.grab() and not cap.grab()


def _count_by_decoding(path: Path) -> int:
    cap = open_capture(path)
    try:
        count = 0
        while cap.grab():
            count += 1
        return count
    finally:
        cap.release()


# --- Previews ------------------------------------------------------------------------------------


def draw_preview(
    frame: np.ndarray,
    corners_px: np.ndarray,
    ids: np.ndarray,
    visible: np.ndarray | None = None,
    text: str | None = None,
) -> np.ndarray:
    """A BGR copy of ``frame`` with the ground-truth markers drawn on it, for eyeballing labels.

    ``corners_px``: (n, 4, 2) in ArUco order, pixel-centre convention (centre of the top-left
    pixel at (0, 0), as OpenCV draws), drawn to 1/16 px with anti-aliased 1-px lines so that a
    label off by a fraction of a pixel shows. A ring marks each marker's top-left corner, its id
    is written to its right; markers not ``visible`` are magenta instead of green; markers with
    non-finite corners are skipped. ``text`` is a caption line at the top left.
    """
    out = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame.copy()
    corners = np.asarray(corners_px, dtype=float).reshape(-1, 4, 2)
    ids = np.asarray(ids).ravel()
    shown = np.ones(len(ids), bool) if visible is None else np.asarray(visible, bool).ravel()
    if not len(corners) == len(ids) == len(shown):
        raise ValueError(f"{len(corners)} markers' corners, {len(ids)} ids, {len(shown)} flags")
    for quad, marker_id, seen in zip(corners, ids, shown, strict=True):
        if np.isfinite(quad).all():
            _draw_marker(out, quad, int(marker_id), VISIBLE_BGR if seen else HIDDEN_BGR)
    if text:
        _draw_caption(out, text)
    return out


def _draw_marker(
    image: np.ndarray, quad: np.ndarray, marker_id: int, colour: tuple[int, int, int]
) -> None:
    pts = np.round(quad * (1 << DRAW_SHIFT)).astype(np.int32)
    cv2.polylines(image, [pts], True, colour, 1, cv2.LINE_AA, DRAW_SHIFT)
    radius = TOP_LEFT_RADIUS_PX << DRAW_SHIFT
    cv2.circle(image, (int(pts[0, 0]), int(pts[0, 1])), radius, colour, 1, cv2.LINE_AA, DRAW_SHIFT)
    label = str(marker_id)
    (_, text_h), _ = cv2.getTextSize(label, FONT, ID_FONT_SCALE, 1)
    org = (int(np.ceil(quad[:, 0].max())) + 4, int(round(quad[:, 1].mean())) + text_h // 2)
    cv2.putText(image, label, org, FONT, ID_FONT_SCALE, colour, 1, cv2.LINE_AA)


def _draw_caption(image: np.ndarray, text: str) -> None:
    """White text on a black box at the top left, readable over any scene."""
    (text_w, text_h), baseline = cv2.getTextSize(text, FONT, CAPTION_FONT_SCALE, 1)
    box = (text_w + 2 * CAPTION_PAD_PX, text_h + baseline + 2 * CAPTION_PAD_PX)
    cv2.rectangle(image, (0, 0), box, (0, 0, 0), cv2.FILLED)
    org = (CAPTION_PAD_PX, CAPTION_PAD_PX + text_h)
    cv2.putText(image, text, org, FONT, CAPTION_FONT_SCALE, (255, 255, 255), 1, cv2.LINE_AA)


def write_preview(
    path: Path,
    frames: Iterable[np.ndarray],
    corners: Iterable[np.ndarray],
    ids: Iterable[np.ndarray],
    visible: Iterable[np.ndarray | None],
    captions: Iterable[str | None],
    fps: float,
    scale: float = 0.5,
) -> int:
    """Write a downscaled video of frames with their labels drawn (:func:`draw_preview`).

    All five iterables give one item per frame (a ``visible`` item None: all visible; a caption
    None: none); they are consumed in step, so nothing is held in memory, and must have equal
    lengths. Frames are shrunk by ``scale`` (INTER_AREA, rounded to an even size) before drawing,
    so the lines stay 1 px thin in the small video. Returns the frame count.
    """
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    rows = zip(frames, corners, ids, visible, captions, strict=True)
    drawn = (
        draw_preview(*_downscale(frame, quads, scale), marker_ids, seen, caption)
        for frame, quads, marker_ids, seen, caption in rows
    )
    return write_video(path, drawn, fps)


def _downscale(
    frame: np.ndarray, corners_px: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Resize ``frame`` by about ``scale`` and map pixel-centre corners with the exact factors."""
    height, width = frame.shape[:2]
    size = (_even(width * scale), _even(height * scale))
    small = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
    factors = np.array([size[0] / width, size[1] / height])
    return small, (np.asarray(corners_px, dtype=float) + 0.5) * factors - 0.5


class BackgroundWriter:
    """Feeds frames to a video writer running in its own thread, so that encoding (ffmpeg's pipe,
    OpenCV's drawing: both release the GIL) overlaps the caller's next frame. Any consumer of a
    stream of items works the same way: the dataset's camera twin records each frame's radiance
    (or None, a still frame) in one while the next frame renders.

    ``write`` is called as ``write(frames)`` with an iterable that yields what :meth:`put` is
    given, e.g. ``lambda frames: write_video(path, frames, fps)``. Used as a context manager: an
    exception inside the block reaches ``write``'s iterable, so a video writer leaves no file, as
    if its frames had raised; :attr:`count` is ``write``'s return value after the block.
    """

    _END = object()

    def __init__(self, write: Callable[[Iterable[np.ndarray]], int], depth: int = 2) -> None:
        self._write, self._queue = write, queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._ended = False
        self.count = 0

    def __enter__(self) -> BackgroundWriter:
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _frames(self) -> Iterator[np.ndarray]:
        while (item := self._queue.get()) is not self._END:
            if isinstance(item, BaseException):
                raise item
            yield item
        self._ended = True

    def _run(self) -> None:
        try:
            self.count = self._write(self._frames())
        except BaseException as exc:  # handed to the caller's thread in put() or __exit__
            self._error = exc
            while not self._ended and self._queue.get() is not self._END:  # until the block ends
                pass

    def put(self, frame: np.ndarray | None) -> None:
        """Queue one frame (waits while ``depth`` frames are waiting); raises the writer's error."""
        if self._error is not None:
            raise self._error
        self._queue.put(frame)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is not None and self._error is None:
            self._queue.put(RuntimeError("the frames' producer failed"))
        self._queue.put(self._END)
        self._thread.join()
        if self._error is not None and exc is None:
            raise self._error


def _even(length: float) -> int:
    return max(2, 2 * round(length / 2))

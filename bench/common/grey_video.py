"""Random access to the grey frames of a video: decoded on demand, sought exactly.

:func:`bench.common.video.read_video` decodes a video front to back; a dataset reader
(:mod:`bench.dataset.loader`) also wants frame ``i`` on its own. :class:`GreyVideo` keeps one
``cv2.VideoCapture`` and its position: the next frame is read; a frame up to one keyframe
interval ahead is reached by decoding forward (``grab``, no colour conversion); any other by
seeking (``CAP_PROP_POS_FRAMES``: FFmpeg goes back to the keyframe at or before the frame and
decodes forward from there).

**Seeking is exact for this project's videos.** Measured here (opencv-contrib-python-headless
5.0.0.93): every frame of four rendered samples (62-86 frames each) and of a three-keyframe
synthetic video, asked for in random order, equals the same frame of a front-to-back decode; a
test keeps it so (``tests/test_loader.py``). The videos make it so: constant frame rate, no
B-frames (x264 ultrafast is Constrained Baseline), a keyframe every 2 s, the index at the front.
A video from elsewhere (B-frames, variable frame rate) may seek inexactly in OpenCV: with
``seek=False`` a frame behind the position is reached by decoding again from the first frame.

**The grey image.** The project's videos are grey frames stored as full-range 4:2:0
(``yuvj420p``: the luma plane is the grey level, unchanged). With ``CAP_PROP_CONVERT_RGB`` off,
OpenCV's FFmpeg backend hands over that plane as an (H, W) uint8 image instead of converting
it to BGR (which :func:`~bench.common.video.read_video` then converts back to grey): measured
here 1.3-1.6x as fast as decoding to BGR alone, on 2592 x 1944 frames. OpenCV logs a warning
on each such frame (the format is "treated as 8UC1"), so those reads run at log level ERROR.
The shortcut is taken only when frame 0 read that way equals frame 0 decoded to BGR and
converted to grey, as ``read_video`` does (checked on the first opening of a file in a
process: about two frames' decoding time); otherwise (a limited-range or colour video, another
OpenCV build) every frame is decoded to BGR and converted, so the images are ``read_video``'s
either way.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from bench.common.video import KEYFRAME_INTERVAL_S, open_capture
from bench.common.video_bounds import check_stream


class GreyVideo:
    """One video's frames as (H, W) uint8 grey images by index; see the module docstring.

    ``frame_count`` is what the container declares; a frame that does not decode (a truncated
    file) raises ValueError naming the file. Not thread-safe (one capture, one position).
    """

    def __init__(self, path: Path, seek: bool = True) -> None:
        self.path = Path(path)
        self.seek = seek
        self._cap = open_capture(self.path)
        try:
            check_stream(self._cap, self.path)
        except ValueError:
            self._cap.release()
            raise
        self.frame_count = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.fps = float(self._cap.get(cv2.CAP_PROP_FPS))
        self.width = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        #: Frames past the position reached by decoding forward rather than by a seek.
        self.skip_max = max(1, round(KEYFRAME_INTERVAL_S * self.fps)) if self.fps > 0 else 30
        self.position = 0  # the index the next read returns
        self.seeks = 0  # how many seeks were made (for tests and reports)
        self._first: np.ndarray | None = None  # frame 0, kept from the luma check
        self.luma = self._choose_luma()

    # --- reading
    def read(self, index: int) -> np.ndarray:
        """Frame ``index`` (0-based) as a grey (H, W) uint8 image."""
        frame = self._at(index)
        if frame is None:
            raise self._missing(self.position)  # the first frame that did not decode
        return frame

    def frames(self) -> Iterator[np.ndarray]:
        """Every frame from the first, front to back, until one does not decode (whether that
        is the end :attr:`frame_count` declares is the caller's check)."""
        index = 0
        while (frame := self._at(index)) is not None:
            yield frame
            index += 1

    def _at(self, index: int) -> np.ndarray | None:
        """Frame ``index``, or None if it (or a frame before it) does not decode: then
        :attr:`position` is the first frame that did not."""
        if self._cap is None:
            raise ValueError(f"{self.path}: the video is closed")
        index = int(index)
        if index < 0:
            raise IndexError(f"{self.path}: frame {index} < 0")
        if index == 0 and self._first is not None:
            return self._first.copy()
        ahead = index - self.position
        if ahead < 0 or ahead > self.skip_max:
            self._move_to(index)
        while self.position < index:
            if not self._cap.grab():
                return None
            self.position += 1
        ok, frame = self._read_raw()
        if not ok:
            return None
        self.position = index + 1
        return self._grey(frame)

    def _move_to(self, index: int) -> None:
        if self.seek:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, index)
            self.seeks += 1
            if int(self._cap.get(cv2.CAP_PROP_POS_FRAMES)) == index:
                self.position = index
                return
        elif index >= self.position:  # decode forward from here
            return
        self._reopen()  # decode forward from the first frame (or a seek went astray)

    def _reopen(self) -> None:
        self._cap.release()
        self._cap = open_capture(self.path)
        if self.luma:
            self._cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        self.position = 0

    def _read_raw(self) -> tuple[bool, np.ndarray | None]:
        if not self.luma:
            return self._cap.read()
        log = cv2.utils.logging
        level = log.getLogLevel()
        log.setLogLevel(log.LOG_LEVEL_ERROR)  # "treated as 8UC1", on every frame
        try:
            return self._cap.read()
        finally:
            log.setLogLevel(level)

    def _grey(self, frame: np.ndarray) -> np.ndarray:
        if self.luma:
            return frame[: self.height]  # the luma plane (some builds append the chroma rows)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)  # exact for grey: B = G = R

    def _missing(self, index: int) -> ValueError:
        return ValueError(
            f"{self.path}: frame {index} does not decode ({self.frame_count} declared; "
            "truncated or damaged?)"
        )

    def _choose_luma(self) -> bool:
        """Switch the capture to the luma plane if frame 0 read so equals ``read_video``'s (the
        verdict kept per file, size and modification time, for this process)."""
        stat = self.path.stat()
        key = (str(self.path.resolve()), stat.st_size, stat.st_mtime_ns)
        verdict = _LUMA_VERDICTS.get(key)
        if verdict is False or not self._cap.set(cv2.CAP_PROP_CONVERT_RGB, 0):
            return False
        self.luma = True
        ok, raw = self._read_raw()
        plane = raw[: self.height] if ok and raw.ndim == 2 and raw.shape[1] == self.width else None
        if plane is None:
            verdict = False
        elif verdict is None:
            verdict = np.array_equal(plane, _bgr_grey_frame0(self.path))
            if len(_LUMA_VERDICTS) >= _MAX_VERDICTS:
                _LUMA_VERDICTS.clear()
            _LUMA_VERDICTS[key] = verdict
        self.luma = verdict
        if verdict:  # the capture is past frame 0: keep it
            self._first, self.position = plane, 1
        else:
            self._reopen()  # back to frame 0, converting to BGR
        return verdict

    # --- lifetime
    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __enter__(self) -> GreyVideo:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: (resolved path, size, modification time ns): whether its luma plane is its grey image.
_LUMA_VERDICTS: dict[tuple[str, int, int], bool] = {}
_MAX_VERDICTS = 4096


def _bgr_grey_frame0(path: Path) -> np.ndarray | None:
    """Frame 0 decoded to BGR and converted to grey (None if it does not decode)."""
    cap = open_capture(path)
    try:
        ok, frame = cap.read()
    finally:
        cap.release()
    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if ok else None

"""A video's frame size and count, bounded before any frame is decoded, and every frame's size
checked against the first.

The container's size and frame count are read when the capture opens (no frame decoded); then
one pass over the stream's packets, demuxed and not decoded (OpenCV's raw mode,
``CAP_PROP_FORMAT = -1``), counts the frames and reads the size each frame header states: the
SPS of H.264 (ITU-T H.264 7.3.2.1.1, cropping applied) and the SOF of each MJPEG frame. OpenCV's
FFmpeg reader rescales every frame to the first frame's size without a word (measured here: an
MJPEG AVI of 64x48 frames then 128x96 ones reads as six 64x48 frames), so a video whose frame
size changes must be refused here, where the change is still visible. Other codecs cannot be
checked without decoding and are refused, naming the fix (re-encode as H.264).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2

from bench.common.image_header import ImageHeaderError, image_header
from scenes.input_limits import FRAME_PIXELS, FRAME_SIDE_PX, VIDEO_FRAMES

H264_FOURCCS = {b"h264", b"H264", b"avc1", b"AVC1", b"x264", b"X264"}
MJPEG_FOURCCS = {b"MJPG", b"mjpg", b"AVRn", b"jpeg", b"JPEG", b"mjpa"}
#: H.264 profiles whose SPS carries chroma format, bit depths and scaling lists (7.3.2.1.1).
_HIGH_PROFILES = {100, 110, 122, 244, 44, 83, 86, 118, 128, 138, 139, 134, 135}


class VideoBoundsError(ValueError):
    """A video over a bound, or whose frame size changes; the message names no file."""


class StreamFacts(NamedTuple):
    width: int
    height: int
    frames: int  # packets of the video stream


class _Bits:
    """Big-endian bit reader over an RBSP (emulation-prevention bytes removed)."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def u(self, n: int) -> int:
        value = 0
        for _ in range(n):
            byte = self.pos >> 3
            if byte >= len(self.data):
                raise VideoBoundsError("H.264 sequence parameter set cut short")
            value = (value << 1) | ((self.data[byte] >> (7 - (self.pos & 7))) & 1)
            self.pos += 1
        return value

    def ue(self) -> int:
        zeros = 0
        while self.u(1) == 0:
            zeros += 1
            if zeros > 31:
                raise VideoBoundsError("H.264 sequence parameter set: malformed number")
        return (1 << zeros) - 1 + self.u(zeros)

    def se(self) -> int:
        k = self.ue()
        return (k + 1) // 2 if k % 2 else -(k // 2)


def sps_size(nal: bytes) -> tuple[int, int]:
    """(width, height) in pixels of an H.264 SPS NAL unit (header byte included)."""
    r = _Bits(nal[1:].replace(b"\x00\x00\x03", b"\x00\x00"))
    profile = r.u(8)
    r.u(16)  # constraint flags, level
    r.ue()  # seq_parameter_set_id
    chroma, separate = 1, 0
    if profile in _HIGH_PROFILES:
        chroma = r.ue()
        if chroma == 3:
            separate = r.u(1)
        r.ue(), r.ue(), r.u(1)  # bit depths, qpprime_y_zero_transform_bypass
        if r.u(1):  # seq_scaling_matrix_present_flag: skip the lists (7.3.2.1.1.1)
            for i in range(8 if chroma != 3 else 12):
                if r.u(1):
                    last = following = 8
                    for _ in range(16 if i < 6 else 64):
                        if following:
                            following = (last + r.se() + 256) % 256
                        last = following or last
    r.ue()  # log2_max_frame_num_minus4
    poc_type = r.ue()
    if poc_type == 0:
        r.ue()
    elif poc_type == 1:
        r.u(1), r.se(), r.se()
        for _ in range(min(r.ue(), 255)):
            r.se()
    r.ue(), r.u(1)  # max_num_ref_frames, gaps_in_frame_num_value_allowed_flag
    width_mbs, height_units = r.ue() + 1, r.ue() + 1
    frame_mbs_only = r.u(1)
    if not frame_mbs_only:
        r.u(1)  # mb_adaptive_frame_field_flag
    r.u(1)  # direct_8x8_inference_flag
    width, height = 16 * width_mbs, 16 * height_units * (2 - frame_mbs_only)
    if r.u(1):  # frame_cropping_flag (7-19 .. 7-22)
        left, right, top, bottom = r.ue(), r.ue(), r.ue(), r.ue()
        if chroma == 0 or separate:
            crop_x, crop_y = 1, 2 - frame_mbs_only
        else:
            crop_x, crop_y = (
                (1 if chroma == 3 else 2),
                (2 if chroma == 1 else 1) * (2 - frame_mbs_only),
            )
        width, height = width - crop_x * (left + right), height - crop_y * (top + bottom)
    return width, height


def _h264_sizes(packet: bytes) -> list[tuple[int, int]]:
    """The sizes the packet's SPS NAL units state (Annex B: OpenCV's raw mode converts)."""
    sizes = []
    at = packet.find(b"\x00\x00\x01")
    while at >= 0 and at + 3 < len(packet):
        end = packet.find(b"\x00\x00\x01", at + 3)
        if packet[at + 3] & 0x1F == 7:
            sizes.append(sps_size(packet[at + 3 : end if end >= 0 else len(packet)].rstrip(b"\0")))
        at = end
    return sizes


def _mjpeg_size(packet: bytes) -> tuple[int, int]:
    try:
        header = image_header(packet)
    except ImageHeaderError as exc:
        raise VideoBoundsError(f"an MJPEG frame: {exc}") from None
    return header.width, header.height


def check_size(width: int, height: int, where: str) -> None:
    if not (0 < width <= FRAME_SIDE_PX and 0 < height <= FRAME_SIDE_PX):
        raise VideoBoundsError(
            f"{where}: {width} x {height} px; each side must be 1..{FRAME_SIDE_PX}"
        )
    if width * height > FRAME_PIXELS:
        raise VideoBoundsError(
            f"{where}: {width} x {height} px is over the limit of {FRAME_PIXELS / 1e6:g} MP a frame"
        )


#: (resolved path, size, modification time ns) -> facts of a file that passed, for this process
_PASSED: dict[tuple[str, int, int], StreamFacts] = {}
_MAX_PASSED = 4096


def check_stream(cap: cv2.VideoCapture, path: Path) -> StreamFacts:
    """Bound an opened (not yet read) capture of ``path`` by its container's frame size and
    count, then by a demux pass over its packets: their count, and each frame header's size
    against the container's. VideoBoundsError otherwise. A file that passed is not scanned
    again while its size and modification time stay (a dataset's videos are opened often)."""
    stat = Path(path).stat()
    key = (str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _PASSED:
        if len(_PASSED) >= _MAX_PASSED:
            _PASSED.clear()
        _PASSED[key] = _scan(cap, path)
    return _PASSED[key]


def _scan(cap: cv2.VideoCapture, path: Path) -> StreamFacts:
    width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    check_size(width, height, "the container's frame size")
    declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    if declared > VIDEO_FRAMES:
        raise VideoBoundsError(f"{declared} frames declared; at most {VIDEO_FRAMES} are read")
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little")
    if fourcc in H264_FOURCCS:
        sizes_of = _h264_sizes
    elif fourcc in MJPEG_FOURCCS:
        sizes_of = lambda packet: [_mjpeg_size(packet)]  # noqa: E731
    else:
        name = fourcc.decode("ascii", "replace").strip("\0 ") or "unknown"
        raise VideoBoundsError(
            f"codec {name!r}: its frame sizes cannot be checked before decoding (H.264 and "
            "MJPEG can); re-encode it, e.g. ffmpeg -i IN -c:v libx264 -qp 12 OUT.mp4"
        )
    raw = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        if not raw.isOpened() or not raw.set(cv2.CAP_PROP_FORMAT, -1):
            raise VideoBoundsError("not a readable video (its packets cannot be read)")
        frames = 0
        while raw.grab():
            frames += 1
            if frames > VIDEO_FRAMES:
                raise VideoBoundsError(f"over {VIDEO_FRAMES} frames; at most that many are read")
            ok, packet = raw.retrieve()
            for size in sizes_of(packet.tobytes()) if ok else []:
                if size != (width, height):
                    raise VideoBoundsError(
                        f"frame {frames - 1} is {size[0]} x {size[1]} px where the video "
                        f"starts at {width} x {height} px: a frame size that changes is refused "
                        "(it would be rescaled without a word)"
                    )
    finally:
        raw.release()
    return StreamFacts(width, height, frames)

"""An image file's size, bit depth and channels from its header, before anything is decoded.

OpenCV has no header-only read: ``cv2.imread`` allocates what the header claims, so a 335-byte
JPEG whose SOF says 30000 x 30000 px took 5.3 GB before failing (measured here, opencv 5.0).
The formats that ``detect-images`` and ``lens measure`` accept (PNG, JPEG, BMP, TIFF) are
recognized by their signature, as OpenCV does (never by the file name), and their headers read
here in a few dozen bytes; anything else is refused, since its size could not be checked.
:func:`read_bounded_image` reads the file's bytes once, checks the header against the bounds of
:mod:`scenes.input_limits` and decodes those same bytes (no second read that could differ).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from scenes.bounded_read import BoundedReadError, read_bounded_bytes
from scenes.input_limits import FRAME_PIXELS, FRAME_SIDE_PX, IMAGE_BITS, IMAGE_BYTES


class ImageHeader(NamedTuple):
    format: str
    width: int
    height: int
    bits: int  # per sample
    channels: int


class ImageHeaderError(ValueError):
    """A header that is missing, malformed or over a bound; the message names no file."""


_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}  # colour type -> samples (palette -> RGB)
#: JPEG start-of-frame markers (T.81 Table B.1): every SOFn but DHT (C4), JPG (C8), DAC (CC).
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _png(data: bytes) -> ImageHeader:
    if len(data) < 33 or data[12:16] != b"IHDR":
        raise ImageHeaderError("PNG without an IHDR header")
    width, height, bits, colour = struct.unpack(">IIBB", data[16:26])
    if colour not in _PNG_CHANNELS:
        raise ImageHeaderError(f"PNG colour type {colour} is not valid")
    return ImageHeader("PNG", width, height, 8 if colour == 3 else bits, _PNG_CHANNELS[colour])


def _jpeg(data: bytes) -> ImageHeader:
    """The first SOF segment, walking segments by their lengths from the SOI."""
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            raise ImageHeaderError(f"JPEG segment expected at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0xD9, 0xDA):  # end of image or start of scan before any frame header
            break
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # no length
            pos += 2
            continue
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker in _SOF:
            body = data[pos + 4 : pos + 2 + length]
            if length < 8 or len(body) < 6:
                raise ImageHeaderError("JPEG frame header cut short")
            bits, height, width, channels = struct.unpack(">BHHB", body[:6])
            if height == 0:  # the height comes later in a DNL segment: unbounded here
                raise ImageHeaderError("JPEG height 0 (defined by a DNL segment): refused")
            return ImageHeader("JPEG", width, height, bits, channels)
        if length < 2:
            raise ImageHeaderError(f"JPEG segment of length {length} at byte {pos}")
        pos += 2 + length
    raise ImageHeaderError("JPEG without a frame header")


def _bmp(data: bytes) -> ImageHeader:
    if len(data) < 26:
        raise ImageHeaderError("BMP header cut short")
    size = struct.unpack("<I", data[14:18])[0]
    if size == 12:  # BITMAPCOREHEADER
        width, height, _, bpp = struct.unpack("<HHHH", data[18:26])
    elif size >= 40 and len(data) >= 30:
        width, height, _, bpp = struct.unpack("<iiHH", data[18:30])
    else:
        raise ImageHeaderError(f"BMP header of {size} bytes is not valid")
    channels = 4 if bpp == 32 else 3 if bpp in (16, 24) or bpp <= 8 else 0
    return ImageHeader("BMP", abs(width), abs(height), 8 if bpp <= 8 else bpp // channels, channels)


def _tiff(data: bytes) -> ImageHeader:
    """The first image file directory (the page cv2.imread decodes)."""
    order = "<" if data[:2] == b"II" else ">"
    offset = struct.unpack(order + "I", data[4:8])[0]
    if offset + 2 > len(data):
        raise ImageHeaderError("TIFF directory beyond the end of the file")
    (count,) = struct.unpack(order + "H", data[offset : offset + 2])
    tags: dict[int, tuple[int, int, bytes]] = {}
    for i in range(count):
        entry = data[offset + 2 + 12 * i : offset + 14 + 12 * i]
        if len(entry) < 12:
            raise ImageHeaderError("TIFF directory cut short")
        tag, kind, n = struct.unpack(order + "HHI", entry[:8])
        tags[tag] = (kind, n, entry[8:])

    def value(tag: int, default: int | None = None) -> int:
        if tag not in tags:
            if default is None:
                raise ImageHeaderError(f"TIFF without tag {tag}")
            return default
        kind, _, raw = tags[tag]
        return struct.unpack(order + ("H" if kind == 3 else "I"), raw[: 2 if kind == 3 else 4])[0]

    bits = value(258, 1)  # the first sample's: inline for up to two samples
    if tags.get(258, (3, 1, b""))[1] > 2:  # more samples: the values are at an offset
        at = struct.unpack(order + "I", tags[258][2])[0]
        bits = struct.unpack(order + "H", data[at : at + 2])[0]
    return ImageHeader("TIFF", value(256), value(257), bits, value(277, 1))


def image_header(data: bytes) -> ImageHeader:
    """The header of PNG, JPEG, BMP or TIFF bytes, by signature; ImageHeaderError otherwise."""
    try:
        if data.startswith(b"\x89PNG\r\n\x1a\n"):
            return _png(data)
        if data.startswith(b"\xff\xd8\xff"):
            return _jpeg(data)
        if data.startswith(b"BM"):
            return _bmp(data)
        if data[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff(data)
    except struct.error:
        raise ImageHeaderError("header cut short") from None
    raise ImageHeaderError("not a readable image: not PNG, JPEG, BMP or TIFF by its first bytes")


def check_header(header: ImageHeader, max_pixels: int = FRAME_PIXELS) -> None:
    """Refuse a size, depth or channel count beyond the bounds (ImageHeaderError)."""
    size = f"{header.format} of {header.width} x {header.height} px"
    if not (0 < header.width <= FRAME_SIDE_PX and 0 < header.height <= FRAME_SIDE_PX):
        raise ImageHeaderError(f"{size}: each side must be 1..{FRAME_SIDE_PX} px")
    if header.width * header.height > max_pixels:
        raise ImageHeaderError(f"{size} is over the limit of {max_pixels / 1e6:g} MP")
    if not 1 <= header.bits <= IMAGE_BITS:  # 1, 2, 4 bits decode to 8
        raise ImageHeaderError(
            f"{size}, {header.bits}-bit samples: refused; convert it to 8-bit with the camera's "
            "transfer curve (sRGB unless the pipeline says /transfer=linear)"
        )
    if header.channels not in (1, 2, 3, 4):
        raise ImageHeaderError(f"{size}: {header.channels} channels; 1 to 4 are read")


def _checked_bytes(path: Path, max_pixels: int) -> tuple[bytes, ImageHeader]:
    """The file's bytes and header, both within bounds (ImageHeaderError otherwise)."""
    try:
        data = read_bounded_bytes(path, IMAGE_BYTES)
    except BoundedReadError as exc:
        raise ImageHeaderError(str(exc)) from None
    header = image_header(data)
    check_header(header, max_pixels)
    return data, header


def read_image_header(path: Path, max_pixels: int = FRAME_PIXELS) -> ImageHeader:
    """The header of the image :func:`read_bounded_image` would decode (its size before any
    pixel is decoded, e.g. to check coordinates given for it), checked the same way."""
    return _checked_bytes(path, max_pixels)[1]


def read_bounded_image(path: Path, max_pixels: int = FRAME_PIXELS) -> np.ndarray:
    """The image as ``cv2.imread(path, IMREAD_UNCHANGED)`` gives it, once its file size and
    header are within bounds; ImageHeaderError naming what is wrong (not the path) otherwise."""
    data, _ = _checked_bytes(path, max_pixels)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageHeaderError("not a readable image (its data does not decode)")
    return image

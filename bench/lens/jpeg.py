"""The MJPEG stream's quality, read from a JPEG frame's own headers.

A camera's bridge chip does not publish its JPEG quality, but every JPEG frame carries the
quantisation tables it was coded with (DQT segments) and its chroma sampling (SOF segment). The
luma table of an IJG-style encoder is the standard table of ITU-T T.81 Annex K (K.1) scaled by
libjpeg's quality formula, so comparing the frame's table with that table at q = 1..100 names the
quality; the error of the best match says whether the encoder used that scheme at all.

An MJPEG AVI holds its frames as plain JPEG byte streams, so the first frame is found by scanning
the file for a start-of-image marker and accepting the first candidate whose segments parse.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

#: ITU-T T.81 (1992) Annex K, Table K.1: luminance quantisation table, natural (row) order.
ANNEX_K_LUMA = (
    16, 11, 10, 16, 24, 40, 51, 61,
    12, 12, 14, 19, 26, 58, 60, 55,
    14, 13, 16, 24, 40, 57, 69, 56,
    14, 17, 22, 29, 51, 87, 80, 62,
    18, 22, 37, 56, 68, 109, 103, 77,
    24, 35, 55, 64, 81, 104, 113, 92,
    49, 64, 78, 87, 103, 121, 120, 101,
    72, 92, 95, 98, 112, 100, 103, 99,
)  # fmt: skip
#: Table K.2: chrominance quantisation table, natural order.
ANNEX_K_CHROMA = (
    17, 18, 24, 47, 99, 99, 99, 99,
    18, 21, 26, 66, 99, 99, 99, 99,
    24, 26, 56, 99, 99, 99, 99, 99,
    47, 66, 99, 99, 99, 99, 99, 99,
    *(99,) * 32,
)  # fmt: skip

SOI = b"\xff\xd8\xff"
_SOF_MARKERS = {0xC0, 0xC1, 0xC2}  # baseline, extended sequential, progressive (Huffman)
_SOS, _EOI = 0xDA, 0xD9
#: How far into a container the first JPEG frame is looked for (an AVI header is a few kB).
MAX_SCAN_BYTES = 64 << 20


@dataclass(frozen=True)
class JpegHeader:
    """What one JPEG frame's headers say: tables (natural order) and chroma sampling."""

    luma_table: tuple[int, ...]
    chroma_table: tuple[int, ...] | None
    subsampling: str  # "4:4:4", "4:2:2", "4:2:0", "grey" or e.g. "other (H1xV1 = 4x1)"
    offset: int  # byte offset of the frame in the file


@cache
def zigzag_to_natural() -> np.ndarray:
    """Natural (row-major) index of each of the 64 coefficients in the JPEG zig-zag order."""
    cells = [(r, c) for r in range(8) for c in range(8)]
    # Anti-diagonals in turn; odd ones run top-right to bottom-left (row increasing), even
    # ones the other way (T.81 Figure 5).
    cells.sort(key=lambda rc: (rc[0] + rc[1], rc[0] if (rc[0] + rc[1]) % 2 else rc[1]))
    return np.array([r * 8 + c for r, c in cells])


def ijg_table(quality: int, chroma: bool = False) -> np.ndarray:
    """The Annex K table scaled to an IJG quality 1..100 as libjpeg does (baseline: <= 255)."""
    if not 1 <= quality <= 100:
        raise ValueError(f"quality={quality!r}: allowed range is 1..100")
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality
    base = np.array(ANNEX_K_CHROMA if chroma else ANNEX_K_LUMA, dtype=np.int64)
    return np.clip((base * scale + 50) // 100, 1, 255)


def match_quality(table: tuple[int, ...], chroma: bool = False) -> tuple[int, float]:
    """(best IJG quality, mean absolute difference of the 64 entries at that quality)."""
    observed = np.asarray(table, dtype=np.int64)
    errors = [float(np.abs(ijg_table(q, chroma) - observed).mean()) for q in range(1, 101)]
    best = int(np.argmin(errors))
    return best + 1, errors[best]


def _parse_at(data: bytes, start: int) -> JpegHeader | None:
    """Parse the segments of a JPEG frame starting at ``data[start]`` (its SOI); None if they
    do not form a valid header (DQT and SOF before the scan)."""
    tables: dict[int, tuple[int, ...]] = {}
    sampling: list[tuple[int, int]] | None = None
    table_ids: list[int] = []
    pos = start + 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (_SOS, _EOI):
            break
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        body = data[pos + 4 : pos + 2 + length]
        if length < 2 or len(body) != length - 2:
            return None
        if marker == 0xDB and not _read_dqt(body, tables):
            return None
        if marker in _SOF_MARKERS:
            if len(body) < 6 or len(body) != 6 + 3 * body[5]:
                return None
            components = [body[6 + 3 * i : 9 + 3 * i] for i in range(body[5])]
            sampling = [(c[1] >> 4, c[1] & 15) for c in components]
            table_ids = [c[2] for c in components]
        pos += 2 + length
    else:
        return None
    if marker != _SOS or sampling is None or not table_ids or table_ids[0] not in tables:
        return None
    luma = tables[table_ids[0]]
    chroma = tables.get(table_ids[1]) if len(table_ids) > 1 else None
    return JpegHeader(luma, chroma, _subsampling(sampling), start)


def _read_dqt(body: bytes, tables: dict[int, tuple[int, ...]]) -> bool:
    """Add the DQT segment's tables (natural order) to ``tables``; False if malformed."""
    natural = zigzag_to_natural()
    pos = 0
    while pos < len(body):
        precision, table_id = body[pos] >> 4, body[pos] & 15
        size = 128 if precision else 64
        raw = body[pos + 1 : pos + 1 + size]
        if len(raw) != size or precision > 1 or table_id > 3:
            return False
        values = np.frombuffer(raw, dtype=">u2" if precision else np.uint8).astype(np.int64)
        out = np.empty(64, dtype=np.int64)
        out[natural] = values
        tables[table_id] = tuple(int(v) for v in out)
        pos += 1 + size
    return True


def _subsampling(sampling: list[tuple[int, int]]) -> str:
    if len(sampling) == 1:
        return "grey"
    (h1, v1), rest = sampling[0], sampling[1:]
    if all(hv == (1, 1) for hv in rest):
        named = {(1, 1): "4:4:4", (2, 1): "4:2:2", (2, 2): "4:2:0"}
        if (h1, v1) in named:
            return named[(h1, v1)]
    return f"other (H1xV1 = {h1}x{v1})"


def read_jpeg_header(path: Path, max_scan_bytes: int = MAX_SCAN_BYTES) -> JpegHeader | None:
    """The headers of the first JPEG frame in a .jpg file or an MJPEG container; None if the
    first ``max_scan_bytes`` hold no parseable JPEG frame (e.g. PNG or H.264 footage)."""
    with open(path, "rb") as f:
        data = f.read(max_scan_bytes)
    at = data.find(SOI)
    while at >= 0:
        header = _parse_at(data, at)
        if header is not None:
            return header
        at = data.find(SOI, at + 1)
    return None


def stream_report(path: Path) -> dict:
    """The stream's codec, IJG quality (with the match error) and chroma subsampling."""
    header = read_jpeg_header(path)
    if header is None:
        return {"codec": "none", "note": f"{path}: no JPEG frame found; stream left as it was"}
    quality, error = match_quality(header.luma_table)
    out = {
        "codec": "mjpeg",
        "file": str(path),
        "frame_offset_bytes": header.offset,
        "quality": quality,
        "luma_match_mean_abs_error": error,
        "ijg_scaled": error == 0.0,
        "chroma_subsampling": header.subsampling,
        "luma_table": list(header.luma_table),
    }
    if header.chroma_table is not None:
        out["chroma_quality"], out["chroma_match_mean_abs_error"] = match_quality(
            header.chroma_table, chroma=True
        )
    return out

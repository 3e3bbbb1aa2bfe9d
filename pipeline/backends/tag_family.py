"""AprilTag 3 families and OpenCV's dictionaries: a family struct built from an OpenCV ArUco
dictionary, so the AprilTag decoder reads ArUco markers with OpenCV's ids, and how OpenCV draws
the library's own AprilTag families.

A family tells the decoder where each code bit sits (``bit_x``, ``bit_y``: the cell, counted
from the black border's top-left cell at (0, 0), +x right and +y down the upright marker) and
which codes are ids. The decoder reads the bits in that order, most significant first, white
as 1, and tries the 4 rotations by rotating the code word a quarter of its bits at a time: that
is a rotation of the marker only if the bits are laid out as the library's own families lay
them out, one quarter of the cells and then that quarter turned by 90 degrees three times (the
centre cell, for an odd side, last). :func:`bit_layout` builds that layout for any side (it
equals tag16h5's, tag25h9's and tag36h11's, which a test checks) and the codes are read from
OpenCV's own marker images in it.

OpenCV 5.0 draws its AprilTag dictionaries turned by a half turn from the library's (and the
official) tag images, with the same ids (opencv/opencv#28823 turns them back in a later 5.x):
:func:`opencv_turn` measures the turn on the installed OpenCV rather than assuming it.
"""

from __future__ import annotations

import ctypes
from functools import cache

import cv2
import numpy as np

from scenes.marker import get_dictionary


class Family(ctypes.Structure):
    """apriltag_family_t (AprilTag 3.4.5 apriltag.h)."""

    _fields_ = [
        ("ncodes", ctypes.c_uint32),
        ("codes", ctypes.POINTER(ctypes.c_uint64)),
        ("width_at_border", ctypes.c_int),
        ("total_width", ctypes.c_int),
        ("reversed_border", ctypes.c_bool),
        ("nbits", ctypes.c_uint32),
        ("bit_x", ctypes.POINTER(ctypes.c_uint32)),
        ("bit_y", ctypes.POINTER(ctypes.c_uint32)),
        ("h", ctypes.c_uint32),
        ("name", ctypes.c_char_p),
        ("impl", ctypes.c_void_p),
    ]


def bit_layout(side: int) -> np.ndarray:
    """(side^2, 2) int, the cells (x, y) of the code bits in the library's order; 1-based inside
    the black border, which is at 0 and side + 1."""
    quarter = [(x, y) for y in range(1, side // 2 + 1) for x in range(y, side + 1 - y)]
    cells = []
    for _ in range(4):
        cells += quarter
        quarter = [(side + 1 - y, x) for x, y in quarter]  # a quarter turn clockwise
    if side % 2:
        cells.append((side // 2 + 1, side // 2 + 1))
    return np.array(cells)


def code_bits(name: str) -> np.ndarray:
    """(ids, side, side) bool, the white cells of each marker's code as OpenCV draws it."""
    dictionary = get_dictionary(name)
    side = int(dictionary.markerSize)
    ids = range(len(dictionary.bytesList))
    images = [cv2.aruco.generateImageMarker(dictionary, i, side + 2, borderBits=1) for i in ids]
    return np.stack([image[1:-1, 1:-1] > 127 for image in images])


def read_codes(bits: np.ndarray) -> np.ndarray:
    """(ids,) uint64, the code words the library reads from ``bits`` (ids, side, side)."""
    side = bits.shape[1]
    cells = bit_layout(side)
    msb_first = np.left_shift(np.uint64(1), np.arange(side * side, dtype=np.uint64)[::-1])
    read = bits[:, cells[:, 1] - 1, cells[:, 0] - 1].astype(np.uint64)
    return (read * msb_first).sum(1, dtype=np.uint64)


def min_hamming(bits: np.ndarray) -> int:
    """The minimum Hamming distance of the codes ``bits`` (ids, side, side) over ids and
    rotations: every code against every other in 4 rotations, and against itself turned."""
    count = len(bits)
    turned = np.stack([read_codes(np.rot90(bits, k, axes=(1, 2))) for k in range(4)], axis=1)
    distance = np.bitwise_count(turned[:, None, None, 0] ^ turned[None, :, :])
    distance[np.arange(count), np.arange(count), 0] = bits[0].size  # a code is itself upright
    return int(distance.min())


@cache
def aruco_family(name: str) -> ctypes.POINTER(Family):
    """The family struct for OpenCV dictionary ``name``, OpenCV's drawing upright (kept, with its
    arrays, for the process's life: the detector holds pointers into them)."""
    bits = code_bits(name)
    count, side = len(bits), bits.shape[1]
    cells = bit_layout(side)
    family = Family(
        ncodes=count,
        codes=(ctypes.c_uint64 * count)(*read_codes(bits).tolist()),
        width_at_border=side + 2,
        total_width=side + 4,
        reversed_border=False,
        nbits=side * side,
        bit_x=(ctypes.c_uint32 * (side * side))(*cells[:, 0].tolist()),
        bit_y=(ctypes.c_uint32 * (side * side))(*cells[:, 1].tolist()),
        h=min_hamming(bits),
        name=f"opencv_{name}".encode(),
    )
    return ctypes.pointer(family)


def opencv_turn(name: str, family: ctypes.POINTER(Family)) -> int:
    """Quarter turns k such that OpenCV's drawing of dictionary ``name`` turned by
    ``np.rot90(drawing, k)`` (anticlockwise on screen) is the library's ``family`` upright, with
    the same ids; RuntimeError if no turn makes every id agree."""
    fam = family.contents
    library = np.ctypeslib.as_array(fam.codes, (fam.ncodes,))
    bits = code_bits(name)
    for k in range(4):
        codes = read_codes(np.rot90(bits, k, axes=(1, 2)))
        if len(codes) == len(library) and (codes == library).all():
            return k
    raise RuntimeError(f"OpenCV's {name} and the AprilTag library's {fam.name.decode()} differ")

"""Still image files: which file names are images, and reading one as the detectors' 8-bit grey.

Shared by the commands that read photographs (``detect-images``; ``lens measure`` reads the same
suffixes).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bench.common.image_header import ImageHeaderError, read_bounded_image

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class StillImageError(ValueError):
    """An image file that cannot be used; the message names the file."""


def read_grey(path: Path, max_pixels: int) -> np.ndarray:
    """(H, W) uint8: the image as stored (no EXIF rotation), colour converted to grey (BT.601
    weights on the coded values).

    Bounded before it is decoded (:func:`bench.common.image_header.read_bounded_image`): images
    over ``max_pixels`` are refused, and so are 16-bit and float images, not converted: their
    scale and transfer curve are unknown, and ``lines`` refinement reads intensities through one.
    """
    try:
        image = read_bounded_image(path, max_pixels)
    except ImageHeaderError as exc:
        raise StillImageError(f"{path}: {exc}") from None
    return grey(image)


def grey(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 of a decoded 8-bit image: grey as it is, BGR(A) converted (BT.601)."""
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        return cv2.cvtColor(image, code)
    return np.ascontiguousarray(image if image.ndim == 2 else image[..., 0])

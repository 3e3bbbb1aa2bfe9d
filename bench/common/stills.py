"""Still image files: which file names are images, and reading one as the detectors' 8-bit grey.

Shared by the commands that read photographs (``detect-images``; ``lens measure`` reads the same
suffixes).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class StillImageError(ValueError):
    """An image file that cannot be used; the message names the file."""


def read_grey(path: Path, max_pixels: int) -> np.ndarray:
    """(H, W) uint8: the image as stored (no EXIF rotation), colour converted to grey (BT.601
    weights on the coded values).

    16-bit and float images are refused, not converted: their scale and transfer curve are
    unknown, and ``lines`` refinement reads intensities through one. Images over
    ``max_pixels`` are refused too (OpenCV itself refuses over 2**30 before decoding).
    """
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise StillImageError(f"{path}: not a readable image")
    if image.dtype != np.uint8:
        raise StillImageError(
            f"{path}: {image.dtype} pixels: refused; convert it to 8-bit with the camera's "
            "transfer curve (sRGB unless the pipeline says /transfer=linear)"
        )
    height, width = image.shape[:2]
    if height * width > max_pixels:
        raise StillImageError(
            f"{path}: {width} x {height} px is over the limit of {max_pixels / 1e6:g} MP"
        )
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        return cv2.cvtColor(image, code)
    return np.ascontiguousarray(image if image.ndim == 2 else image[..., 0])

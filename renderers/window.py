"""Pixel windows (crops) of the full fisheye image, and where their samples fall."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from scenes.camera import FisheyeCamera

#: Adaptive anti-aliasing: a pixel takes every sample where its 3 x 3 neighbourhood's first-pass
#: samples spread by more than this fraction of their light (edges); elsewhere (flat patches,
#: the smooth sky) its first samples stand for all, within this fraction: far below one 8-bit
#: level at any brightness of the sRGB curve.
ADAPTIVE_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Window:
    """A rectangle of whole pixels: columns x0..x0+width-1, rows y0..y0+height-1."""

    x0: int
    y0: int
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"window {self}: width and height must be >= 1")

    @classmethod
    def full(cls, camera: FisheyeCamera) -> Window:
        return cls(0, 0, camera.width_px, camera.height_px)

    @classmethod
    def around(
        cls,
        points_px: np.ndarray,
        camera: FisheyeCamera,
        margin_px: int = 16,
        min_size_px: int = 64,
    ) -> Window:
        """The window holding ``points_px`` plus a margin, at least ``min_size_px`` square, clipped.

        Points outside the image circle (NaN) are ignored; at least one must be inside.
        """
        pts = np.asarray(points_px, dtype=float).reshape(-1, 2)
        pts = pts[~np.isnan(pts).any(axis=1)]
        if len(pts) == 0:
            raise ValueError("cannot frame points that all lie outside the image circle")
        lo = np.floor(pts.min(axis=0)) - margin_px
        hi = np.ceil(pts.max(axis=0)) + margin_px
        grow = np.maximum(min_size_px - (hi - lo + 1), 0)
        lo -= np.floor(grow / 2)
        hi += np.ceil(grow / 2)
        lo = np.maximum(lo, 0).astype(int)
        hi = np.minimum(hi, [camera.width_px - 1, camera.height_px - 1]).astype(int)
        return cls(int(lo[0]), int(lo[1]), int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1))

    def aligned(self, grid_px: int, camera: FisheyeCamera) -> Window:
        """The smallest window holding this one whose edges lie on multiples of ``grid_px``
        (clipped to the image): an MJPEG block grid or a Bayer tile, so that a crop sees the
        same blocks and colour phase as the full frame."""
        if grid_px < 1:
            raise ValueError(f"grid_px={grid_px}: must be >= 1")
        x0 = self.x0 - self.x0 % grid_px
        y0 = self.y0 - self.y0 % grid_px
        x1 = min(camera.width_px, -(-(self.x0 + self.width) // grid_px) * grid_px)
        y1 = min(camera.height_px, -(-(self.y0 + self.height) // grid_px) * grid_px)
        return Window(x0, y0, x1 - x0, y1 - y0)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    def pixel_centres(self) -> np.ndarray:
        """(height, width, 2) pixel centres in full-image pixel coordinates."""
        xs = np.arange(self.x0, self.x0 + self.width, dtype=float)
        ys = np.arange(self.y0, self.y0 + self.height, dtype=float)
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx, gy], axis=-1)

    def sample_positions(self, spp: int, rng: np.random.Generator) -> np.ndarray:
        """(height, width, spp, 2) jittered sample positions, each inside its own pixel.

        A square ``spp`` is stratified (one sample per sub-cell); otherwise uniform.
        """
        if spp < 1:
            raise ValueError(f"spp={spp}: must be >= 1")
        n = math.isqrt(spp)
        jitter = rng.random((self.height, self.width, spp, 2))
        if n * n == spp:
            cells = np.stack(np.meshgrid(np.arange(n), np.arange(n)), axis=-1).reshape(spp, 2)
            jitter = (cells + jitter) / n
        return self.pixel_centres()[:, :, None, :] - 0.5 + jitter


def edge_pixels(light_max: np.ndarray, light_min: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose 3 x 3 neighbourhood's light (each pixel's largest and smallest
    first-pass sample) spreads by more than :data:`ADAPTIVE_TOLERANCE` of it. An edge passing
    between one pixel's samples and the next pixel's flags both, not only one crossing a
    pixel's own samples."""
    box = np.ones((3, 3), np.uint8)
    hi = cv2.dilate(light_max, box, borderType=cv2.BORDER_REPLICATE)
    lo = cv2.erode(light_min, box, borderType=cv2.BORDER_REPLICATE)
    return hi - lo > ADAPTIVE_TOLERANCE * (np.abs(hi) + 1e-12)

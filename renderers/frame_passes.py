"""Two-pass sampling of a frame: every pixel's first sample, then its others only where needed.

Lit by the sun (a delta light) and the exact sky term, a frame of flat facets with one albedo each
is piecewise constant: on the quick dataset's zone, 94% of the pixels hold the same value for any
two seeds, the spread being all at edges (marker modules, leaves, rods; moving or not). So the
first pass renders one sample per pixel (:attr:`RayPlan.first <renderers.frame_rays.RayPlan>`:
over each 2 x 2 block the four strata, at four time samples) and the second pass the pixel's
other samples only where the first pass's values (the largest channel) in the pixel's 3 x 3
neighbourhood differ by more than :data:`~renderers.window.ADAPTIVE_TOLERANCE` of their largest
(:func:`~renderers.window.edge_pixels`: an edge within the neighbourhood, in space or, as the
neighbours' samples lie at other times, in time). A pixel left at one sample had neighbours of
one value: its own samples would have agreed. Pixels that get all their samples get the exact
samples, sums and divisor of one pass (bit for bit: the sums are kept per time sample, in the
same order); ``tests/test_video_speed_fidelity.py`` checks both and that the rest stays within
the reference's own seed spread.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.window import edge_pixels


@dataclass
class Batch:
    """The rays of one time sample, resident on the Dr.Jit side."""

    dirs: mi.Vector3f
    pixel: mi.UInt32
    sky_escape: mi.Color3f  # radiance of the sky seen by rays that hit nothing
    to_sun: mi.Vector3f | None  # per ray, jittered over the solar disk (canopy shadows)
    bounce_seed: int  # seeds the bounce directions of "path"
    index: mi.UInt32  # each ray's place in its time sample's plan: seeds its own bounces

    def take(self, rows: mi.UInt32) -> Batch:
        """The rays at ``rows``, with their own bounce seeds: a ray renders alike in any batch."""

        def gather(kind, values):
            return None if values is None else dr.gather(kind, values, rows)

        batch = Batch(
            gather(mi.Vector3f, self.dirs),
            gather(mi.UInt32, self.pixel),
            gather(mi.Color3f, self.sky_escape),
            gather(mi.Vector3f, self.to_sun),
            self.bounce_seed,
            gather(mi.UInt32, self.index),
        )
        dr.eval(batch.dirs, batch.pixel, batch.sky_escape, batch.to_sun, batch.index)
        return batch


def needs_more(first: np.ndarray, band_rows: slice) -> np.ndarray:
    """(H, W) bool: pixels whose 3 x 3 neighbourhood in the first pass ``first`` (H, W, 3) is not
    flat. The band's rows are judged on their own (their border replicated), so a band frame and a
    full frame flag the same pixels there."""
    values = np.maximum(np.maximum(first[..., 0], first[..., 1]), first[..., 2])
    flags = edge_pixels(values, values)
    if band_rows != slice(0, values.shape[0]):
        band = np.ascontiguousarray(values[band_rows])
        flags[band_rows] = edge_pixels(band, band)
    return flags


class TwoPasses:
    """A sample's rays split into the first pass (resident) and the rest (chosen per frame)."""

    def __init__(self, batches: list[Batch], first: list[np.ndarray], shape: tuple[int, int]):
        """``first``: per time sample, (m,) bool of its plan's first-pass rays; ``shape``: the
        region's (H, W)."""
        self.first = [
            b.take(mi.UInt32(np.flatnonzero(f))) for b, f in zip(batches, first, strict=True)
        ]
        self.rest_rows = [np.flatnonzero(~f).astype(np.uint32) for f in first]
        self.rest_pixel = [b.pixel.numpy()[r] for b, r in zip(batches, self.rest_rows, strict=True)]
        pixels = np.concatenate([b.pixel.numpy() for b in self.first])
        self.first_count = np.bincount(pixels, minlength=shape[0] * shape[1]).reshape(shape)

    def rest(self, j: int, batch: Batch, flags: np.ndarray) -> Batch | None:
        """Time sample ``j``'s other samples of the flagged pixels (``flags`` (H * W,)), or None."""
        rows = self.rest_rows[j][flags[self.rest_pixel[j]]]
        return batch.take(mi.UInt32(rows)) if len(rows) else None

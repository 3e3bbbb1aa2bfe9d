"""The fixed set of rays a sample's frames shoot, for :mod:`renderers.frames`.

The camera is rigid with the array, so every frame shoots the same rays: drawn once per sample,
split over the exposure's time samples, and counted per pixel to average them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from renderers.fisheye import jitter_in_cone
from renderers.window import Window
from scenes.camera import FisheyeCamera

if TYPE_CHECKING:
    from renderers.frame_sampling import FrameSampling


@dataclass
class RayPlan:
    """The fixed samples of one time sample, NumPy side."""

    dirs: np.ndarray  # (m, 3) float32 camera-frame directions
    pixel: np.ndarray  # (m,) uint32 flat index into the region
    to_sun: np.ndarray | None  # (m, 3) float32 jittered sun directions, or None
    first: np.ndarray  # (m,) bool: the pixel's first-pass sample (renderers.frame_passes)


def ray_plan(
    camera: FisheyeCamera,
    region: Window,
    zone: Window,
    sampling: FrameSampling,
    sun_cone: tuple[np.ndarray, float] | None,
    seed: int,
) -> tuple[list[RayPlan], np.ndarray]:
    """The samples of each time sample, and the number of samples per region pixel (H, W).

    Zone samples come from their own random stream and are drawn first, so they are the same
    whatever the region (band or full frame). Sample j of pixel (x, y) goes to time sample
    (j + x + y) mod subframes: every time sample covers the image evenly. A pixel's first-pass
    sample is its sample ``(x mod 2 + 2 (y mod 2)) mod spp``: over each 2 x 2 block of pixels the
    four strata of a stratified 4 spp, at four different time samples.
    """
    streams = np.random.SeedSequence(seed).spawn(2)
    parts = []
    for window, spp, stream in (
        (zone, sampling.marker_spp, streams[0]),
        (region, sampling.background_spp, streams[1]),
    ):
        rng = np.random.default_rng(stream)
        pos = window.sample_positions(spp, rng)  # (h, w, spp, 2)
        xy = np.floor(pos + 0.5).astype(np.int64).reshape(-1, 2)
        slot = np.tile(np.arange(spp), window.width * window.height)
        first = slot == (xy[:, 0] % 2 + 2 * (xy[:, 1] % 2)) % spp
        keep = np.ones(len(xy), bool)
        if window is region:  # background: only pixels outside the zone
            keep = ~(
                (xy[:, 0] >= zone.x0)
                & (xy[:, 0] < zone.x0 + zone.width)
                & (xy[:, 1] >= zone.y0)
                & (xy[:, 1] < zone.y0 + zone.height)
            )
        sun = None
        if sun_cone is not None:
            sun = jitter_in_cone(*sun_cone, (len(xy),), rng)[keep]
        parts.append((pos.reshape(-1, 2)[keep], xy[keep], slot[keep], first[keep], sun))
    pos, xy, slot, first = (np.concatenate([p[i] for p in parts]) for i in range(4))
    dirs, valid = camera.unproject(pos)
    pixel = (xy[:, 1] - region.y0) * region.width + (xy[:, 0] - region.x0)
    when = (slot + xy[:, 0] + xy[:, 1]) % sampling.subframes
    sun = np.concatenate([p[4] for p in parts]) if sun_cone is not None else None
    plans = []
    for k in range(sampling.subframes):
        pick = valid & (when == k)
        plans.append(
            RayPlan(
                dirs[pick].astype(np.float32),
                pixel[pick].astype(np.uint32),
                None if sun is None else sun[pick].astype(np.float32),
                first[pick],
            )
        )
    count = np.bincount(pixel[valid], minlength=region.height * region.width)
    return plans, count.reshape(region.shape)

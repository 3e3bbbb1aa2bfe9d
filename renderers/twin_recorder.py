"""A region's radiance recorded through one camera twin: :class:`TwinRecorder`.

Kept apart from the renderer (:mod:`renderers.frames`) so that one render can be recorded through
several twins (the fidelity ladder's stage rungs, the calibration's evidence).
"""

from __future__ import annotations

import time

import numpy as np

from renderers.camera_twin import PIXEL_GAIN_STAGES, STAGES, optical_image, sensor_images
from renderers.window import Window
from scenes.profile import CameraProfile

#: The twin's stages after the per-pixel gain the renderer applies.
_LENS_STAGES = tuple(s for s in STAGES if s not in PIXEL_GAIN_STAGES)


class TwinRecorder:
    """A region's radiance recorded through one camera twin as the camera's 8-bit grey frame,
    with the seconds spent in the optics and in the sensor.

    The optics run once over the region; the band's sensor noise comes from its own stream, so a
    band frame and a full frame of the same sample hold identical pixels wherever their optical
    images agree (the band starts on the stream's block grid). Kept apart from the renderer so
    that one render can be recorded through several twins (the fidelity ladder's stage rungs).
    """

    def __init__(
        self, profile: CameraProfile, region: Window, band: Window, exposure: float, noise_seed: int
    ) -> None:
        """``exposure``: linear radiance to sensor full scale, the lighting's factor included."""
        self.profile, self.region, self.band, self.exposure = profile, region, band, exposure
        self.rng_band, self.rng_rest = (
            np.random.default_rng(s) for s in np.random.SeedSequence(noise_seed).spawn(2)
        )
        self.optics_s = self.sensor_s = 0.0

    def _sensor(self, irradiance: np.ndarray, window: Window, rng: np.random.Generator):
        origin = (window.x0, window.y0)
        return sensor_images(irradiance, self.profile, rng, 1, origin, self.exposure)[0]

    def record(self, radiance: np.ndarray) -> np.ndarray:
        """The frame (H, W) of the region's radiance (:meth:`FrameRecorder.radiance`): black
        outside the region."""
        return self.expose(self.optics(radiance))

    def optics(self, radiance: np.ndarray) -> np.ndarray:
        """The region's sensor irradiance: the lens stages, deterministic (a still scene's
        images share it; :meth:`expose` draws each one's noise)."""
        t0 = time.perf_counter()
        region = self.region
        irradiance = optical_image(radiance, self.profile, (region.x0, region.y0), _LENS_STAGES)
        self.optics_s += time.perf_counter() - t0
        return irradiance

    def expose(self, irradiance: np.ndarray) -> np.ndarray:
        """One frame (H, W) of the region's irradiance (:meth:`optics`) through the sensor and
        stream, with this recorder's next noise; black outside the region."""
        t0 = time.perf_counter()
        lens, region, band = self.profile.lens, self.region, self.band
        image = np.zeros((lens.height_px, lens.width_px), np.uint8)
        if region != band:
            image[region.y0 : region.y0 + region.height, region.x0 : region.x0 + region.width] = (
                self._sensor(irradiance, region, self.rng_rest)
            )
        rows = slice(band.y0 - region.y0, band.y0 - region.y0 + band.height)
        image[band.y0 : band.y0 + band.height] = self._sensor(irradiance[rows], band, self.rng_band)
        self.sensor_s += time.perf_counter() - t0
        return image

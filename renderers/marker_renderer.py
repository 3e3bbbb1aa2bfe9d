"""A lone marker's renderer as an object handed to each task: one loaded scene per lighting.

The detectability study and the sweeps render many crops of one marker (dictionary, id) through
one lens under a few lightings. Loading a Mitsuba scene and compiling its kernels costs more than
rendering a crop, so a process builds one :class:`MarkerRenderer` and passes it to every task it
runs (a pool worker builds its own: :class:`bench.common.executor.TaskPool`'s ``setup``). Each
lighting's scene is loaded on its first crop and re-posed for every crop after that. Mitsuba is
imported then too, after the process chose its variant (:func:`renderers.variant.init_worker`).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from renderers.frame_sampling import check_light_paths
from renderers.window import Window
from scenes.camera import FisheyeCamera
from scenes.lighting import get_lighting
from scenes.marker import MarkerSpec, carrier_outline

if TYPE_CHECKING:
    from renderers.fisheye import FisheyeRenderer, RenderedWindow
    from renderers.mitsuba_scene import CanopyScene

#: Size of the loaded print; each crop scales it to its own marker's size when posing it.
SCENE_SIZE_MM = 10.0


class MarkerRenderer:
    """Crops of one marker through one lens, ``spp`` samples per pixel, any lighting preset.

    ``integrator``: ``"direct"`` (the exact unoccluded sky, noise-free) or ``"path"`` (Mitsuba's
    path tracer over the sky with ``path_depth`` indirect bounces, the fidelity ladder's
    reference; :class:`renderers.fisheye.FisheyeRenderer` says what it adds for a lone marker).
    """

    def __init__(
        self,
        lens: FisheyeCamera,
        dictionary: str,
        marker_id: int,
        spp: int = 16,
        integrator: str = "direct",
        path_depth: int = 3,
    ):
        check_light_paths(integrator, path_depth)
        self.lens = lens
        self.marker = MarkerSpec(dictionary, marker_id, SCENE_SIZE_MM)
        self.spp = spp
        self.integrator, self.path_depth = integrator, path_depth
        self._loaded: dict[str, tuple[FisheyeRenderer, CanopyScene | None]] = {}
        self._sky: dict[str, np.ndarray] = {}  # the open sky's full frame per lighting

    def fisheye(self, lighting: str) -> FisheyeRenderer:
        """The renderer of the marker's scene under that lighting preset (loaded on first use)."""
        return self._scene(lighting)[0]

    def _scene(self, lighting: str) -> tuple[FisheyeRenderer, CanopyScene | None]:
        if lighting not in self._loaded:
            from renderers.fisheye import FisheyeRenderer
            from renderers.mitsuba_scene import CanopyScene, MarkerScene

            preset = get_lighting(lighting)
            scene = MarkerScene(self.marker, preset)
            canopy = CanopyScene(preset) if preset.canopy else None
            sky = "path" if self.integrator == "path" else "irradiance"
            renderer = FisheyeRenderer(
                self.lens, scene, spp=self.spp, sky=sky, path_depth=self.path_depth
            )
            self._loaded[lighting] = (renderer, canopy)
        return self._loaded[lighting]

    def crop(
        self, T_cam_marker: np.ndarray, size_mm: float, grid_px: int, margin_px: int = 16
    ) -> Window:
        """The window framing the marker's carrier plus ``margin_px``, on a ``grid_px`` grid."""
        spec = dataclasses.replace(self.marker, size_mm=size_mm)
        outline = self.lens.project(carrier_outline(T_cam_marker, spec))
        return Window.around(outline, self.lens, margin_px=margin_px).aligned(grid_px, self.lens)

    def render(
        self,
        lighting: str,
        T_cam_marker: np.ndarray,
        size_mm: float,
        window: Window,
        seed: int,
    ) -> RenderedWindow:
        """The clean render of ``window`` with the marker (side ``size_mm``) at that pose."""
        renderer = self.fisheye(lighting)
        renderer.scene.set_pose(T_cam_marker, size_mm)
        return renderer.render(window, seed=seed)

    def render_frame(
        self, lighting: str, T_cam_marker: np.ndarray, size_mm: float, grid_px: int, seed: int
    ) -> np.ndarray:
        """Full-frame linear RGB radiance (H, W, 3): the crop around the marker (:meth:`crop`)
        traced by :meth:`render`, the open sky elsewhere (:mod:`renderers.sky_frame`, computed
        on the lighting's first frame). Lightings without a leaf canopy."""
        from renderers.sky_frame import sky_background

        if lighting not in self._sky:
            self._sky[lighting] = sky_background(self.lens, get_lighting(lighting), self.spp)
        window = self.crop(T_cam_marker, size_mm, grid_px)
        crop = self.render(lighting, T_cam_marker, size_mm, window, seed).radiance()
        frame = self._sky[lighting].copy()
        frame[window.y0 : window.y0 + window.height, window.x0 : window.x0 + window.width] = crop
        return frame

    def radiance(
        self, lighting: str, rendered: RenderedWindow, n_images: int, rng: np.random.Generator
    ) -> np.ndarray:
        """Linear RGB radiance of a render: (H, W, 3), or (n_images, H, W, 3) under a canopy
        (a new leaf shadow position per image, drawn from ``rng``)."""
        from renderers.fisheye import canopy_visibility

        canopy = self._scene(lighting)[1]
        if canopy is None:
            return rendered.radiance()
        visibility = canopy_visibility(canopy, get_lighting(lighting), rendered, n_images, rng)
        return rendered.radiance(visibility)

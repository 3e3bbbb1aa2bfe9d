"""The array-in-foliage scene of ``whiskerbench bench render --scene array``, for both renderers.

One frame of a default dataset sample (``soft-intermediate-0-outdoor-sun``, prototype camera, at
mid-sample: whiskers deflected by the foliage): the project renders it as the dataset does
(:class:`renderers.frames.FrameRenderer`: fixed rays, the array posed, the vegetation offset),
here over the whole frame with ``spp`` samples in every pixel and one time sample (no motion
blur: Cycles gets the same instant); Cycles gets the same meshes, posed and moved into the camera
frame (:func:`cycles_parts`). Detection outcome: the marker ids the project's detector finds on
each image and their corners against the labels' true corners.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.dataset.config import DatasetConfig
from bench.dataset.labels import corners_of_frame
from bench.dataset.sample import simulate_sample
from pipeline.detect import DetectorConfig, detect_markers
from scenes.lighting import get_lighting

#: The sample and the frame: mid-sample of a default sample with foliage touching the array.
SAMPLE = dict(foliage="soft", distance="intermediate", branches_mm=(0.0,), protocol="outdoor")
SEED = 0


@dataclass
class ArrayFrame:
    """One frame of the array in foliage: what both renderers and the scoring need."""

    config: DatasetConfig
    renderer: object  # renderers.frames.FrameRenderer (Dr.Jit side: imported lazily)
    angles_rad: np.ndarray  # (n, 2) deflections at the frame's instant
    offset_mm: np.ndarray  # (2,) the array's (x, z) offset in the vegetation frame
    vegetation: list  # (name, mesh in the vegetation frame, RGB albedo)
    truth: tuple[np.ndarray, np.ndarray, np.ndarray]  # corners (n, 4, 2), ids, visible
    exposure: float

    def render_project(self) -> np.ndarray:
        """Linear RGB radiance of the whole frame (H, W, 3)."""
        return self.renderer.render(self.angles_rad[None], self.offset_mm[None])

    def cycles_parts(self) -> list:
        """The same meshes in the camera frame for :class:`~bench.benchmarks.cycles_scene.
        CyclesScene`: the array posed at the frame's deflections, the vegetation moved by the
        array's offset (a vegetation point p sits at p - (x, 0, z) in the camera frame)."""
        array = self.renderer.array
        posed = array.posed_vertices(self.angles_rad)
        parts = []
        for name, (mesh, albedo) in array.parts.items():
            moved = mesh.copy()
            if name in posed:
                moved.vertices = posed[name]
            parts.append((name, moved, albedo))
        shift = np.array([self.offset_mm[0], 0.0, self.offset_mm[1]])
        for name, mesh, albedo in self.vegetation:
            if len(mesh.faces):
                moved = mesh.copy()
                moved.vertices = np.asarray(mesh.vertices) - shift
                parts.append((name, moved, tuple(float(a) for a in albedo)))
        return parts


def array_frame(spp: int) -> ArrayFrame:
    """Simulate the sample and set up the project's renderer for its middle frame."""
    from renderers.frame_sampling import FrameSampling
    from renderers.frames import FrameRenderer

    config = DatasetConfig(
        foliage=(SAMPLE["foliage"],),
        distances=(SAMPLE["distance"],),
        branches=(SAMPLE["branches_mm"],),
        protocols=(SAMPLE["protocol"],),
        seed=SEED,
    )
    sample = config.samples()[0]
    sim = simulate_sample(config, sample)
    f = len(sim.times_s) // 2
    k = config.sampling.subframes
    angles = sim.angles_rad[f, k]  # the frame's own instant (what the labels hold)
    offset = sim.motion.offsets_at(sim.times_s[f : f + 1])[0]
    vegetation = [(p.name, p.mesh, p.albedo_rgb) for p in sim.vegetation.parts]
    lighting = get_lighting(sample.lighting)
    sampling = FrameSampling(marker_spp=spp, background_spp=spp, subframes=1, full_frame=True)
    lens = config.camera.lens
    renderer = FrameRenderer(
        lens, config.array, vegetation, lighting, sampling, SEED, angles_rad=angles[None]
    )
    return ArrayFrame(
        config,
        renderer,
        angles,
        offset,
        vegetation,
        corners_of_frame(sim.labels, f),
        config.exposure * lighting.exposure,
    )


def array_outcome(image: np.ndarray, frame: ArrayFrame) -> dict:
    """Markers found on an 8-bit frame: ids, and mean corner error against the true corners."""
    corners, ids, visible = frame.truth
    found = {
        d.marker_id: d.corners_px
        for d in detect_markers(image, DetectorConfig(), (0, 0), frame.config.camera.lens)
    }
    truth = {int(i): c for i, c, v in zip(ids, corners, visible, strict=True) if v}
    hits = sorted(set(found) & set(truth))
    errors = [np.linalg.norm(found[i] - truth[i], axis=1).mean() for i in hits]
    return {
        "detected": hits,  # marker ids, compared between the renderers
        "visible": len(truth),
        "corner_err_px": float(np.mean(errors)) if errors else float("nan"),
        "corners": np.array([found[i] for i in hits]).reshape(-1, 2),
    }

"""One frame with and without the per-query evaluation (renderers.frames.FrameRenderer._query):
on LLVM both must hold the same pixels; on CUDA the split is what avoids OptiX's one-SBT limit.
Usage: python split_check.py VARIANT [OUT.npy] (OUT.npy: the frame with the split)"""

import sys
import time

import numpy as np

from renderers.variant import select_variant

variant = select_variant(sys.argv[1])
from renderers.frame_sampling import FrameSampling  # noqa: E402
from renderers.frames import FrameRenderer  # noqa: E402
from scenes.array import ArraySpec  # noqa: E402
from scenes.camera import default_camera  # noqa: E402
from scenes.lighting import get_lighting  # noqa: E402
from scenes.vegetation import VegetationSpec, build_vegetation  # noqa: E402

SPEC = ArraySpec()
veg = build_vegetation(VegetationSpec("soft", "intermediate", (0.0,), seed=1), SPEC)
parts = [(p.name, p.mesh, p.albedo_rgb) for p in veg.parts]
r = FrameRenderer(default_camera(), SPEC, parts, get_lighting("canopy"), FrameSampling(), seed=5)
angles = np.zeros((4, 13, 2))
angles[:, 6, 0] = np.linspace(0.3, 0.35, 4)
offsets = np.tile([10.0, 0.0], (4, 1))
out = {}
for split in (False, True):
    r._query_per_kernel = split
    r.render(angles, offsets)  # compile
    t = time.perf_counter()
    out[split] = r.render(angles, offsets)
    print(
        f"{variant} split={split}: {time.perf_counter() - t:.3f} s/frame, "
        f"mean {out[split].mean():.5f}, lit pixels {(out[split].sum(-1) > 0).mean():.4f}",
        flush=True,
    )
d = np.abs(out[True] - out[False])
if len(sys.argv) > 2:
    np.save(sys.argv[2], out[True])
print(
    f"{variant}: identical={np.array_equal(out[True], out[False])} max|d|={d.max():.3g} "
    f"mean|d|={d.mean():.3g} pixels differing={(d.sum(-1) > 0).mean():.4f}"
)

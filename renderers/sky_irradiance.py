"""Sky irradiance E(n) on a surface of normal n: the exact, noise-free sky term for open surfaces.

For a Lambertian point that sees the whole sky above its tangent plane (nothing occludes it:
true of every visible point of the study's marker on its carrier, a convex object alone in
the scene), the sky's contribution is ``albedo * E(n) / pi`` with

    E(n) = integral over the sphere of L_sky(w) max(0, n . w) dw.

E is smooth in n (a cosine-blurred sky), so it is tabulated once per sky by quadrature over a
fine lat-long grid and looked up bilinearly. Monte Carlo sampling of the same integral at
16 spp left 3-60 % pixel noise frozen into every image drawn from a clean render;
``tests/test_renderer.py`` checks that both routes agree in expectation.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from scenes.array_ops import NUMPY
from scenes.lighting import Sky

_SKY_GRID = (128, 256)  # quadrature directions (rows over polar angle, cols over azimuth)
_TABLE = (48, 96)  # tabulated normals


def _sphere_grid(rows: int, cols: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directions at cell centres of a (polar from +z, azimuth) grid, their solid angles, angles."""
    theta = (np.arange(rows) + 0.5) * math.pi / rows
    phi = (np.arange(cols) + 0.5) * 2 * math.pi / cols
    t, p = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    d_omega = (
        (np.cos(t - 0.5 * math.pi / rows) - np.cos(t + 0.5 * math.pi / rows)) * 2 * math.pi / cols
    )
    return dirs, d_omega, np.stack([t, p], axis=-1)


def irradiance_direct(sky: Sky, normals: np.ndarray) -> np.ndarray:
    """E(n) by quadrature for (N, 3) unit normals (luminance units; multiply by the sky colour)."""
    dirs, d_omega, _ = _sphere_grid(*_SKY_GRID)
    dirs = dirs.reshape(-1, 3).astype(np.float32)
    weights = (sky.radiance(dirs) * d_omega.ravel()).astype(np.float32)
    normals = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
    out = np.empty(len(normals))
    for start in range(0, len(normals), 256):  # bounded memory: 256 x 32768 cosines at a time
        cosines = normals[start : start + 256] @ dirs.T
        out[start : start + 256] = np.maximum(cosines, 0.0) @ weights
    return out


@lru_cache(maxsize=16)
def irradiance_table(sky: Sky) -> np.ndarray:
    """E on the (polar from +z, azimuth) grid of normals: rows over [0, pi], cols over [0, 2 pi)."""
    normals, _, _ = _sphere_grid(*_TABLE)
    return irradiance_direct(sky, normals.reshape(-1, 3)).reshape(_TABLE)


def irradiance(sky: Sky, normals, xp=NUMPY):
    """E(n) for (..., 3) unit normals, bilinear in the tabulated (polar, azimuth) grid.

    ``normals`` may also be the tuple of their x, y and z arrays in another array namespace
    ``xp`` (:mod:`scenes.array_ops`): the renderer's kernels look E up with this same code."""
    rows, cols = _TABLE
    if isinstance(normals, tuple | list):
        nx, ny, nz = (xp.asarray(c) for c in normals)
    else:
        n = np.asarray(normals, dtype=float)
        nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    theta = xp.acos(xp.clip(nz, -1.0, 1.0))
    phi = xp.atan2(ny, nx)
    phi = xp.where(phi < 0.0, phi + 2 * math.pi, phi)
    r = xp.clip(theta * (rows / math.pi) - 0.5, 0.0, rows - 1.0)
    c = phi * (cols / (2 * math.pi)) - 0.5
    r0 = xp.minimum(xp.floor(r), rows - 2.0)
    c0 = xp.floor(c)
    fr, fc = r - r0, c - c0
    table = irradiance_table(sky).ravel()
    c0w = xp.where(c0 < 0.0, c0 + cols, c0)  # azimuth wraps around (c0 >= -1)
    c1w = xp.where(c0 + 1.0 >= cols, c0 + 1.0 - cols, c0 + 1.0)

    def at(row, col):
        return xp.gather(table, row * cols + col)

    top = at(r0, c0w) * (1 - fc) + at(r0, c1w) * fc
    bottom = at(r0 + 1.0, c0w) * (1 - fc) + at(r0 + 1.0, c1w) * fc
    return top * (1 - fr) + bottom * fr


def sky_luminance(sky: Sky, valid, hit, lit, normal_xyz: tuple, dir_xyz: tuple, xp=NUMPY):
    """The sky's light per sample before albedo and colour: E(n) / pi on lit surfaces (``lit``:
    a front face with albedo), the sky itself along valid rays that hit nothing, else 0."""
    lum = xp.where(lit, irradiance(sky, normal_xyz, xp) / math.pi, 0.0)
    return xp.where(valid & ~hit, sky.radiance_xyz(*dir_xyz, xp), lum)

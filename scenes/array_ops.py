"""One array vocabulary for the formulas that run both as NumPy and as Dr.Jit kernels.

The lens models (:mod:`scenes.lens_models`, :class:`scenes.camera.FisheyeCamera`) and the sky
(:class:`scenes.lighting.Sky`, :mod:`renderers.sky_irradiance`) are written once against the
names below, taking the namespace as ``xp``. :data:`NUMPY` runs them on float64 NumPy arrays
(labels, the pipeline, the tests); :class:`renderers.drjit_ops.DrJitOps` runs the same code as
Dr.Jit array code, so the renderer's per-pixel work is traced into its kernels and runs on every
core (``llvm_ad_rgb``) or on the GPU (``cuda_ad_rgb``). ``tests/test_array_ops.py`` checks that
both give the same pixels.

Only what the formulas need is here: elementwise maths, ``where``, ``any`` (a loop's exit test:
it evaluates pending Dr.Jit work), and look-ups in small constant tables (``gather``,
``searchsorted``, ``interp``). Operators (+, -, *, /, comparisons, &, |, ~) are the arrays' own.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from typing import Any

import numpy as np


class NumpyOps:
    """The vocabulary over NumPy float64 arrays."""

    name = "numpy"
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    sqrt = staticmethod(np.sqrt)
    atan2 = staticmethod(np.arctan2)
    acos = staticmethod(np.arccos)
    hypot = staticmethod(np.hypot)
    floor = staticmethod(np.floor)
    abs = staticmethod(np.abs)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)
    clip = staticmethod(np.clip)
    where = staticmethod(np.where)
    isinf = staticmethod(np.isinf)
    isnan = staticmethod(np.isnan)
    interp = staticmethod(np.interp)

    @staticmethod
    def asarray(x: Any) -> np.ndarray:
        return np.asarray(x, dtype=float)

    @staticmethod
    def copy(x: np.ndarray) -> np.ndarray:
        return np.array(x, dtype=float, copy=True)

    @staticmethod
    def full_like(x: np.ndarray, value: float) -> np.ndarray:
        return np.full(np.shape(x), value, dtype=float)

    @staticmethod
    def any(mask: np.ndarray) -> bool:
        return bool(np.any(mask))

    @staticmethod
    def gather(table: np.ndarray, index: np.ndarray) -> np.ndarray:
        """``table[index]`` for a 1-D constant table (integer-valued float indices too)."""
        return table[np.asarray(index).astype(np.intp)]

    @staticmethod
    def searchsorted(table: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Leftmost insertion index of ``y`` in the increasing 1-D ``table``."""
        return np.searchsorted(table, y)

    @staticmethod
    def errstate() -> AbstractContextManager:
        """Quiet division by zero and invalid operations: the formulas mask them themselves."""
        return np.errstate(divide="ignore", invalid="ignore")


#: The NumPy namespace: the default ``xp`` everywhere.
NUMPY = NumpyOps()

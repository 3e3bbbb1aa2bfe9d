"""The array vocabulary of :mod:`scenes.array_ops` over Dr.Jit: the camera model and the sky as
kernel code.

Arrays are the active variant's ``Float64`` (the camera model needs double precision to agree
with the NumPy labels to 1e-6 px; on a GPU without fast doubles this is the price of exact
rays). Constant tables go over once per call as Dr.Jit arrays; ``any`` evaluates the pending
work (a Newton loop's exit test), everything else stays symbolic and fuses into the kernel
that uses it.
"""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.variant import jit_variant_active


class DrJitOps:
    """The vocabulary over the active Mitsuba variant's Dr.Jit arrays (JIT variants only)."""

    name = "drjit"
    sin = staticmethod(dr.sin)
    cos = staticmethod(dr.cos)
    sqrt = staticmethod(dr.sqrt)
    atan2 = staticmethod(dr.atan2)
    acos = staticmethod(dr.acos)
    floor = staticmethod(dr.floor)
    abs = staticmethod(dr.abs)
    minimum = staticmethod(dr.minimum)
    maximum = staticmethod(dr.maximum)
    clip = staticmethod(dr.clip)
    where = staticmethod(dr.select)
    isinf = staticmethod(dr.isinf)
    isnan = staticmethod(dr.isnan)

    def __init__(self) -> None:
        if not jit_variant_active():
            raise RuntimeError(f"Dr.Jit array code needs a JIT variant, not {mi.variant()}")
        self.Float = mi.Float64
        self.UInt = mi.UInt32

    def asarray(self, x: Any):
        return x if isinstance(x, self.Float) else self.Float(x)

    def copy(self, x):
        return self.Float(x)

    def full_like(self, x, value: float):
        return dr.full(self.Float, value, dr.width(x))

    @staticmethod
    def hypot(x, y):
        return dr.sqrt(dr.fma(x, x, y * y))

    @staticmethod
    def any(mask) -> bool:
        return bool(dr.any(mask, axis=None))

    def _table(self, table: np.ndarray):
        return self.Float(np.ascontiguousarray(table, dtype=float))

    def gather(self, table: np.ndarray, index):
        return dr.gather(self.Float, self._table(table), self.UInt(index))

    def searchsorted(self, table: np.ndarray, y):
        """Leftmost i with table[i] >= y (y within the table's range), by binary search."""
        values = self._table(table)
        return dr.binary_search(0, len(table) - 1, lambda i: dr.gather(self.Float, values, i) < y)

    def interp(self, y, fs: np.ndarray, xs: np.ndarray):
        """Linear interpolation of xs over increasing fs at y (y within fs's range)."""
        i = dr.clip(self.searchsorted(fs, y), 1, len(fs) - 1)
        f0, f1 = self.gather(fs, i - 1), self.gather(fs, i)
        x0, x1 = self.gather(xs, i - 1), self.gather(xs, i)
        return x0 + (y - f0) * (x1 - x0) / (f1 - f0)

    @staticmethod
    def errstate() -> AbstractContextManager:
        return nullcontext()  # Dr.Jit does not trap on division by zero

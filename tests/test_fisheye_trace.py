"""The tracer's chunks: whole pixels, whole packets of rays, every pixel once and in order."""

from __future__ import annotations

import numpy as np
import pytest

from renderers.fisheye_trace import PACKET_LANES, SMALL_CHUNK_RAYS, BlockTracer


@pytest.mark.parametrize("k", [1, 3, 4, 9, 12, 27, 48])
def test_every_kernel_is_whole_packets_and_every_pixel_comes_back_once(monkeypatch, k) -> None:
    widths: list[int] = []

    def fake_trace(self, points, k_, c, seed, positions):
        widths.append(len(points))
        x = points[:, 0].reshape(-1, k_).astype(np.float32)  # each pixel's samples
        sums = np.stack([x.sum(axis=1)] * 3, axis=-1)
        return sums, sums, x.max(axis=1), x.min(axis=1), None

    monkeypatch.setattr(BlockTracer, "_trace_jit", fake_trace)
    tracer = BlockTracer.__new__(BlockTracer)
    tracer.jit = True
    m = 3 * (SMALL_CHUNK_RAYS // k) + 7  # several chunks, the last one partial
    points = np.zeros((m, k, 2))
    points[..., 0] = np.arange(m)[:, None]  # pixel i's samples all hold i
    out = tracer.trace(points, seed=0, positions=False)
    assert all(w % PACKET_LANES == 0 for w in widths), widths
    assert len(set(widths)) == 1  # one kernel size
    assert np.array_equal(out.light_max, np.arange(m, dtype=np.float32))
    assert np.array_equal(out.sky[:, 0], k * np.arange(m, dtype=np.float32))

"""Pixel statistics of two frames saved by split_check.py (CUDA with the fix against LLVM).
Usage: python compare.py CUDA.npy LLVM.npy"""

import sys

import numpy as np

a, b = np.load(sys.argv[1]), np.load(sys.argv[2])
d = np.abs(a - b)
print(
    f"cuda (split) vs llvm, one frame {a.shape}: mean {a.mean():.5f} vs {b.mean():.5f}, "
    f"lit {(a.sum(-1) > 0).mean():.4f} vs {(b.sum(-1) > 0).mean():.4f}, max|d| {d.max():.3g}, "
    f"mean|d| {d.mean():.3g}, p99|d| {np.quantile(d, 0.99):.3g}, "
    f"rel mean|d| {d.mean() / b.mean():.3g}"
)

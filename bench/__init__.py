"""What the product does with the layers below, one sub-package per job, in data-flow order.

* :mod:`bench.common`: plumbing every job shares (atomic writes, the task pool, video files,
  manifests and the resumable-run skeleton).
* :mod:`bench.study`: the marker detectability study (cells, the run, its tables and figures).
* :mod:`bench.dataset`: benchmark datasets (sample grid, simulation, labels, generation).
* :mod:`bench.evaluate`: running pipelines on videos and judging them (detect, score, sweeps,
  compare).
* :mod:`bench.lens`: fitting a camera profile's optics, noise and stream from real footage.
* :mod:`bench.twin`: holding the camera twin to what the real sensor did (observations checked,
  estimates calibrated).
* :mod:`bench.ladder`: the fidelity ladder: each rendering shortcut against a reference.
* :mod:`bench.benchmarks`: speed benchmarks with same-run baselines.
* :mod:`bench.cli`: the ``whiskerbench`` command line, which only parses, validates and calls.
"""

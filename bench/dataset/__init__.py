"""Benchmark datasets: the sample grid (config.py), one sample's simulation and frames
(sample.py), exact labels (labels.py), the resumable generation of a whole dataset
(generate.py), the integrity check every reader runs first (verify.py), the format's version
(format.py; the format itself: docs/dataset_format.md) and the reader (loader.py:
``open_dataset``)."""

"""Benchmark datasets: the sample grid (config.py), one sample's simulation and frames
(sample.py), exact labels (labels.py), the resumable generation of a whole dataset
(generate.py) and the integrity check every reader runs first (verify.py)."""

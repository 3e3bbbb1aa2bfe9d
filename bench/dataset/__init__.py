"""Benchmark datasets: the sample grid, one sample's simulation and frames, exact labels, and
the resumable generation of a whole dataset."""

"""Pipelines on videos: ``detect`` one video, ``score`` a dataset, one-axis sweeps (config,
run, report), the accuracy-against-speed ``compare`` report and the pipeline timing it shares
with ``bench pipeline`` (timing.py)."""

"""Pipelines on videos: ``detect`` one video, ``score`` a dataset, one-axis ``sweeps``, and the
accuracy-against-speed ``compare`` report."""

"""Pipelines on videos: ``detect`` one video, ``score`` a dataset, one-axis sweeps (config,
run, report), the accuracy-against-speed ``compare`` report and the pipeline timing it shares
with ``bench pipeline`` (timing.py); methods from outside the project: results files
(results_file.py, branches_file.py, external.py), branch-finder plugins (branch_plugin.py) and
both in ``compare`` (outside.py)."""

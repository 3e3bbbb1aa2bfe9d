"""The studies, dataset generation, scoring, comparisons and the ``whiskerbench`` command line."""

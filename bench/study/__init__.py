"""The marker detectability study: per-cell rendering and scoring, the resumable run, the
per-cell statistics and the figures."""

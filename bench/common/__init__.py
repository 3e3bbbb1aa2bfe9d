"""Plumbing shared by every job: atomic file output (atomic.py), the process pool and its
per-worker context (executor.py), manifests and folder claims (manifest.py), the resumable-run
skeleton shared by the study and the dataset (resumable.py), scoring one marker image against
its truth (marker_score.py), and video files (video.py)."""

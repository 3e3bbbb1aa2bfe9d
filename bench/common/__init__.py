"""Plumbing shared by every job: atomic file output (atomic.py), the process pool (executor.py),
manifests and folder claims (manifest.py), the resumable-run skeleton shared by the study and
the dataset (resumable.py), and video files (video.py)."""

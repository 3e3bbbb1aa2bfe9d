"""Plumbing shared by every job: atomic file output (atomic.py), the process pool and its
per-worker context (executor.py), manifests (manifest.py), run folders: claim, lock and clean
(run_folder.py), units verified before reuse (units.py), the resumable-run skeleton shared by
the study, the dataset and the ladder (resumable.py), scoring one marker image against
its truth (marker_score.py), and video files (video.py)."""

"""Plumbing shared by every job: atomic file output, the process pool, video files."""

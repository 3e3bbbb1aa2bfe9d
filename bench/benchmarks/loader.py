"""``whiskerbench bench loader DATASET``: reading a sample through the loader against decoding
its video with plain OpenCV, same run, same file.

Three readers of one sample's ``video.mp4``, in turn, ``repeats`` times each (medians
reported), after one untimed read that brings the file into the page cache:

- ``opencv``: ``cv2.VideoCapture.read`` to the end: BGR frames, decoded and nothing else;
- ``read_video``: :func:`bench.common.video.read_video`, the project's front-to-back reader
  (``score``, ``detect``): the luma plane where frame 0 shows it is the grey image;
- ``loader``: :meth:`bench.dataset.loader.Sample.frames` on a sample taken afresh from the
  dataset: ``sample.json``, ``camera.json`` and ``labels.parquet`` read, then per frame the
  grey image and its label rows. Its first run also checks, once per file and process, that
  the video's luma plane is its grey image (:mod:`bench.common.grey_video`): printed apart.

Then random access: ``random_frames`` frames in a random order through
:meth:`~bench.dataset.loader.Sample.frame` (each a seek and a decode from the keyframe before).
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from bench.common.video import read_video
from bench.dataset.loader import open_dataset


def _opencv(path: Path) -> int:
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    count = 0
    try:
        while cap.read()[0]:
            count += 1
    finally:
        cap.release()
    return count


def _read_video(path: Path) -> int:
    return sum(1 for _ in read_video(path))


def bench_loader(
    dataset: Path, sample: str | None = None, repeats: int = 3, random_frames: int = 20
) -> dict:
    """Time the three readers on one sample (default: the dataset's first); print and return
    the figures. DatasetFormatError if ``dataset`` is not one (KeyError: no such sample)."""
    ds = open_dataset(dataset)
    sample_id = sample if sample is not None else ds.sample_ids[0]
    first = ds[sample_id]
    video, n = first.video_path, len(first)

    def loader() -> int:
        return sum(1 for _ in ds[sample_id].frames())

    readers = {"opencv": _opencv, "read_video": _read_video, "loader": loader}
    _opencv(video)  # the file into the page cache
    seconds: dict[str, list[float]] = {name: [] for name in readers}
    for _ in range(repeats):
        for name, read in readers.items():
            t0 = time.perf_counter()
            count = read(video) if name != "loader" else read()
            seconds[name].append(time.perf_counter() - t0)
            if count != n:
                raise ValueError(f"{video}: {name} read {count} frames, sample.json says {n}")
    fps = {name: n / statistics.median(s) for name, s in seconds.items()}
    ratio = fps["loader"] / fps["opencv"]
    camera = first.camera
    print(
        f"sample {sample_id}: {n} frames of {camera.width_px}x{camera.height_px} px; median of "
        f"{repeats} runs each, in turn, {os.cpu_count()} cores"
    )
    print(f"  OpenCV VideoCapture.read (BGR, decode only): {fps['opencv']:6.1f} frames/s")
    print(f"  read_video (grey, front to back):            {fps['read_video']:6.1f} frames/s")
    print(f"  loader frames() (grey image + label rows):    {fps['loader']:6.1f} frames/s")
    first_fps = n / seconds["loader"][0]
    print(f"  loader, its first run (checks the decoder):   {first_fps:6.1f} frames/s")
    print(f"loader / OpenCV: {ratio:.2f}x")

    order = np.random.default_rng(0).permutation(n)[: min(random_frames, n)]
    with ds[sample_id] as picked:
        picked.frame(int(order[0]))  # opens the video, reads the labels: not timed
        t0 = time.perf_counter()
        for index in order[1:]:
            picked.frame(int(index))
        random_s = time.perf_counter() - t0
    random_fps = (len(order) - 1) / random_s if len(order) > 1 else float("nan")
    print(f"random access: {len(order) - 1} frames in random order, {random_fps:.1f} frames/s")
    return {
        "sample": sample_id,
        "frames": n,
        "repeats": repeats,
        "seconds": seconds,
        "frames_per_s": fps,
        "loader_over_opencv": ratio,
        "loader_first_run_frames_per_s": first_fps,
        "random_frames": len(order) - 1,
        "random_frames_per_s": random_fps,
        "cpu_count": os.cpu_count(),
    }

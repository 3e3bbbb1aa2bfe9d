"""A dataset folder in the format of ``docs/dataset_format.md``, made without rendering.

Small frames (96 x 72 px noise, distinct per frame, so a wrong frame never passes for the right
one), exact labels of the array at rest through a small lens (:func:`bench.dataset.labels.
label_table`), the files and hashes ``whiskerbench dataset`` writes. For the loader's tests,
in well under a second; the rendered datasets of ``tests/conftest.py`` check the real thing.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from bench.common.manifest import sha256
from bench.common.video import write_video
from bench.dataset.config import SAMPLE_FILES
from bench.dataset.format import FORMAT_VERSION
from bench.dataset.labels import label_table
from scenes.array import ArraySpec
from scenes.camera import FisheyeCamera
from scenes.profile import CameraProfile

WIDTH, HEIGHT, FPS = 96, 72, 15.0
SAMPLES = {"soft-far-none-outdoor-lab": 64, "soft-far-0-outdoor-lab": 5}  # id: frames


def small_camera() -> FisheyeCamera:
    f = (HEIGHT / 2) / (math.pi / 2)
    return FisheyeCamera(WIDTH, HEIGHT, f, f, (WIDTH - 1) / 2, (HEIGHT - 1) / 2, 95.0)


def noise_frames(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8) for _ in range(n)]


def make_dataset(out: Path, samples: dict[str, int] | None = None) -> Path:
    """Write the dataset into ``out`` (created); return ``out``."""
    out = Path(out)
    profile = CameraProfile(name="test-small", lens=small_camera())
    spec = ArraySpec()
    files = {}
    for k, (sample_id, n) in enumerate((samples or SAMPLES).items()):
        folder = out / sample_id
        folder.mkdir(parents=True)
        write_video(folder / "video.mp4", noise_frames(n, k), FPS)
        write_video(folder / "preview.mp4", noise_frames(n, k + 100), FPS)
        times = (np.arange(n) + 0.5) / FPS
        angles = np.zeros((n, spec.n_whiskers, 2))
        flags = np.zeros((n, spec.n_whiskers), bool)
        labels = label_table(profile.lens, spec, angles, flags, flags, times, np.arange(n))
        labels.to_parquet(folder / "labels.parquet", index=False)
        (folder / "camera.json").write_text(json.dumps(profile.to_json()))
        foliage, distance, branches, protocol, lighting = sample_id.split("-")
        record = {
            "sample_id": sample_id,
            "foliage": foliage,
            "distance": distance,
            "branches_mm": [] if branches == "none" else [float(branches)],
            "branch_gaps": [] if branches == "none" else [[6, 7]],
            "protocol": {"name": protocol, "fps": FPS},
            "lighting": lighting,
            "frames": n,
            "settings_sha256": "0" * 64,
            "files": {name: sha256(folder / name) for name in SAMPLE_FILES},
        }
        (folder / "sample.json").write_text(json.dumps(record))
        for name in (*SAMPLE_FILES, "sample.json"):
            files[f"{sample_id}/{name}"] = sha256(folder / name)
    manifest = {
        "kind": "dataset",
        "schema": 1,
        "format_version": FORMAT_VERSION,
        "config": {},
        "samples": list(samples or SAMPLES),
        "files": files,
        "outputs": files,
        "settings_sha256": "0" * 64,
    }
    (out / "manifest.json").write_text(json.dumps(manifest))
    return out

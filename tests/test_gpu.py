"""cuda_ad_rgb: the study, the dataset, the benchmarks and the camera model on a GPU.

Skipped cleanly where no GPU works (CI, most machines): the whole module is skipped before any
CUDA call unless an NVIDIA device node exists and a subprocess can set the variant and run one
kernel. Each test runs in its own process (the Mitsuba variant is per process) and compares with
the CPU variant's output where the two must agree.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from renderers.variant import find_libllvm, gpu_present

ROOT = Path(__file__).resolve().parents[1]
CUDA = "cuda_ad_rgb"
#: Dr.Jit's warning when a CUDA kernel traces more than one scene: it then *disables* the ray
#: queries beyond the first scene (the frames came out brighter: sun shadows lost), silently
#: for the output files, so the runs below must not print it.
OPTIX_ONE_SCENE = "more than one OptiX shader binding table"


@functools.cache
def gpu_works() -> bool:
    if not gpu_present():
        return False
    probe = (
        "import mitsuba as mi; mi.set_variant('cuda_ad_rgb'); import drjit as dr; "
        "assert (mi.Float(1.0) + 1.0).numpy()[0] == 2.0"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=300)
    return done.returncode == 0


pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not gpu_works(), reason="no working CUDA GPU (cuda_ad_rgb)"),
]


def _run(*args: str, timeout: int = 1200) -> subprocess.CompletedProcess:
    done = subprocess.run(
        [sys.executable, "-m", "bench.cli", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert OPTIX_ONE_SCENE not in done.stdout + done.stderr, done.stderr[-2000:]
    return done


def test_camera_model_on_the_gpu_gives_the_numpy_pixels():
    code = """
import numpy as np
from renderers.variant import select_variant
select_variant("cuda_ad_rgb")
from renderers.drjit_ops import DrJitOps
from scenes.profile import load_profile
cam = load_profile("prototype").lens
ops = DrJitOps()
px = np.random.default_rng(0).uniform([0, 0], [cam.width_px, cam.height_px], (100000, 2))
ref, valid = cam.unproject(px)
*d, v = cam.unproject_xy(ops.Float(px[:, 0]), ops.Float(px[:, 1]), ops)
got = np.stack([c.numpy() for c in d], -1)
assert (v.numpy() == valid).all()
err = np.linalg.norm(cam.project(got[valid]) - cam.project(ref[valid]), axis=-1)
assert err.max() < 1e-6, err.max()
"""
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.skipif(find_libllvm() is None, reason="the CPU reference needs llvm_ad_rgb")
def test_study_on_the_gpu_gives_the_cpu_answer(tmp_path):
    """The quick study on both variants: the same detection counts in (almost) every cell."""
    tables = {}
    for variant in (CUDA, "llvm_ad_rgb"):
        out = tmp_path / variant
        _run("detectability", "--quick", "--variant", variant, "--out", str(out))
        assert json.loads((out / "manifest.json").read_text())["variant"] == variant
        tables[variant] = pd.read_csv(out / "summary.csv")
    a, b = (tables[v]["n_detected"].to_numpy() for v in (CUDA, "llvm_ad_rgb"))
    assert len(a) == len(b) > 0
    # float rounding differs between the GPU and the CPU; a cell may move by one image
    assert (abs(a - b) <= 1).all() and (a != b).mean() < 0.1


@pytest.mark.skipif(find_libllvm() is None, reason="the CPU reference needs llvm_ad_rgb")
def test_dataset_on_the_gpu_has_the_cpu_labels_and_close_frames(tmp_path):
    from bench.common.video import read_video

    outs = {}
    for variant in (CUDA, "llvm_ad_rgb"):
        outs[variant] = tmp_path / variant
        _run("dataset", "--quick", "--variant", variant, "--out", str(outs[variant]))
    for sample in sorted(p.name for p in outs[CUDA].iterdir() if p.is_dir()):
        gpu, cpu = (outs[v] / sample for v in (CUDA, "llvm_ad_rgb"))
        pd.testing.assert_frame_equal(
            pd.read_parquet(gpu / "labels.parquet"), pd.read_parquet(cpu / "labels.parquet")
        )
        for fg, fc in zip(
            read_video(gpu / "video.mp4"), read_video(cpu / "video.mp4"), strict=True
        ):
            assert abs(fg.astype(int) - fc.astype(int)).mean() < 1.0


def test_benchmarks_run_on_the_gpu(tmp_path):
    done = _run("bench", "render", "--variant", CUDA, "--out", str(tmp_path / "render"))
    assert "project" in done.stdout
    assert json.loads((tmp_path / "render" / "manifest.json").read_text())["variant"] == CUDA
    done = _run("bench", "scale", "--variant", CUDA, "--executors", "inline", "--workers-max", "1")
    assert "frames/s" in done.stdout
    _run("bench", "dataset", "--variant", CUDA, "--quick", "--frames", "5")

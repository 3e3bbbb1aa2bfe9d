"""Provenance: every writing command's manifest has the common fields, and the SHA-256 it records
for its inputs and outputs are those of the files (recomputed here with hashlib)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from conftest import copy_pair

from pipeline.presets import PRESETS
from scenes.profile import load_profile

FIELDS = {
    "kind", "schema", "config", "seed", "versions", "machine", "variant", "inputs", "outputs",
    "started", "finished", "wall_s",
}  # fmt: skip
BRANCH = "soft-intermediate-100-outdoor-lab"


def _digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def check_manifest(folder: Path, kind: str) -> dict:
    """The manifest in ``folder``: its fields, kind, finish time and every recorded digest."""
    manifest = json.loads((folder / "manifest.json").read_text())
    assert set(manifest) >= FIELDS, FIELDS - set(manifest)
    assert manifest["kind"] == kind and manifest["schema"] == 1
    assert manifest["finished"] >= manifest["started"]
    assert manifest["versions"]["numpy"] and manifest["versions"]["python"]
    assert set(manifest["machine"]) == {"cpu", "cores", "simd"} and manifest["machine"]["cpu"]
    for path, digest in manifest["inputs"].items():
        assert _digest(path) == digest, path
    for name, digest in manifest["outputs"].items():
        assert _digest(folder / name) == digest, name
    return manifest


@pytest.mark.slow
def test_dataset_manifest(rendered_pair, variant) -> None:
    manifest = check_manifest(rendered_pair, "dataset")
    assert manifest["variant"] == variant and manifest["seed"] == manifest["config"]["seed"]
    assert manifest["outputs"] == manifest["files"]
    assert f"{BRANCH}/sample.json" in manifest["outputs"]


@pytest.mark.slow
def test_study_manifest(variant, tmp_path) -> None:
    """Through the CLI, with the camera profile as a user's file: the file is an input."""
    from bench.cli.main import main
    from scenes.profile import profile_path

    camera = tmp_path / "my_camera.json"
    shutil.copy(profile_path("prototype"), camera)
    out = tmp_path / "study"
    grid = ["--sizes", "13.2", "--alphas", "0", "--phis", "0", "--images", "3"]
    argv = ["detectability", *grid, "--camera", str(camera), "--workers", "1"]
    assert main([*argv, "--variant", variant, "--out", str(out)]) == 0
    manifest = check_manifest(out, "detectability")
    assert manifest["inputs"] == {str(camera): _digest(camera)}
    assert manifest["variant"] == variant and manifest["seed"] == 0
    assert "images.parquet" in manifest["outputs"]
    assert manifest["config"] == json.loads((out / "config.json").read_text())


#: The pipeline the scoring commands' manifests are checked on: what a manifest records does
#: not depend on it, and fast (ROI search, no refinement) does half of paper's work on a video.
PIPELINE = PRESETS["fast"]


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the manifest's digests are the files'
def test_detect_records_the_videos_digest(rendered_pair, tmp_path) -> None:
    from bench.evaluate.detect import run_detect
    from scenes.profile import load_profile

    video = rendered_pair / BRANCH / "video.mp4"
    camera = load_profile(rendered_pair / BRANCH / "camera.json").lens
    run_detect(video, camera, PIPELINE, tmp_path / "d")
    manifest = check_manifest(tmp_path / "d", "detect")
    assert manifest["inputs"][str(video)] == _digest(video)
    assert manifest["config"]["pipeline"] == PIPELINE.to_json()
    assert set(manifest["outputs"]) == {"detections.parquet", "branches.json", "branches.png"}


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the manifest's digests are the files'
def test_score_records_every_sample_file(rendered_pair, tmp_path) -> None:
    from bench.evaluate.score import score_dataset

    data = tmp_path / "data"
    copy_pair(rendered_pair, data)
    score_dataset(data, PIPELINE, tmp_path / "s")
    manifest = check_manifest(tmp_path / "s", "score")
    files = json.loads((data / "manifest.json").read_text())["files"]
    assert set(manifest["inputs"]) == {str(data / "manifest.json")} | {
        str(data / rel) for rel in files
    }
    assert "samples.csv" in manifest["outputs"]
    check_manifest(tmp_path / "s" / BRANCH, "detect")  # each sample's detect folder


@pytest.mark.slow
def test_bench_pipeline_manifest(variant, tmp_path) -> None:
    from bench.benchmarks.pipeline import bench_pipeline

    bench_pipeline([PRESETS["paper"]], frames=2, rounds=3, variant=variant, out=tmp_path)
    manifest = check_manifest(tmp_path, "bench-pipeline")
    assert set(manifest["outputs"]) == {"bench.json"}
    assert manifest["config"]["pipelines"] == [PRESETS["paper"].to_json()]
    # the same frames at the prototype band's ends: OpenCV reads more through the sharper lens
    figures = json.loads((tmp_path / "bench.json").read_text())
    low, high = load_profile("prototype").band.psf_ends
    ends = figures["band_ends"]
    assert set(ends) == {f"{low:g}", f"{high:g}"}
    sharp, blurred = ends[f"{low:g}"][0], ends[f"{high:g}"][0]
    assert sharp["pipeline"] == blurred["pipeline"] == "paper"
    nominal = figures["pipelines"][0]["recall"]
    assert sharp["recall"] >= nominal >= blurred["recall"] and sharp["recall"] > blurred["recall"]
    leads = {row["measure"]: row for row in figures["leaders"]}
    assert leads["recall"]["holds_across_band"] is True  # one pipeline leads everywhere
    assert leads["recall"]["band_leaders"] == f"{low:g}: paper; {high:g}: paper"
    assert leads["fps"]["holds_across_band"] is None  # speed is not judged


X86_CPUINFO = """processor\t: 0
vendor_id\t: GenuineIntel
model name\t: Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz
flags\t\t: fpu vme sse4_1 sse4_2 avx avx2 fma avx512f avx512bw
"""
ARM_CPUINFO = """processor\t: 0
BogoMIPS\t: 50.00
Features\t: fp asimd evtstrm aes crc32
CPU implementer\t: 0x41
"""


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (X86_CPUINFO, ("Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz", "avx512f")),
        (
            X86_CPUINFO.replace(" avx512f avx512bw", ""),
            ("Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz", "avx2"),
        ),
        (ARM_CPUINFO, (None, "asimd")),
        ("", (None, None)),
        ("flags\t: fpu vme\n", (None, None)),
    ],
    ids=["avx512", "avx2", "arm", "empty", "no-simd"],
)
def test_cpu_summary_names_the_model_and_the_widest_simd_level(text, expected):
    """The machine record that tells why two machines' files differ in their last bits: NumPy and
    Dr.Jit pick their kernels (and Dr.Jit its 16 or 8 lanes) by these flags."""
    from bench.common.manifest import cpu_summary

    assert cpu_summary(text.splitlines()) == expected


def test_the_machine_record_is_this_machines():
    import os

    from bench.common.manifest import machine

    record = machine()
    assert record["cores"] == os.cpu_count() and isinstance(record["cpu"], str) and record["cpu"]
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if " avx512f" in flags:
        assert record["simd"] == "avx512f"
    elif " avx2" in flags:
        assert record["simd"] == "avx2"


def test_every_unit_record_names_the_machine_that_made_it(tmp_path):
    """A study cell, a dataset sample, a score unit or a ladder rung made on another machine (a
    resumed run, a remote Dask worker) says so; the field is bookkeeping, not the unit's own
    result, and does not decide whether the unit is reused."""
    from bench.common.manifest import machine
    from bench.common.units import DONE, payload, unit_state, write_unit

    path = tmp_path / "unit.json"
    record = {"unit": "a", "settings_sha256": "s", "files": {}, "result": 1}
    written = write_unit(path, record)
    assert written["machine"] == machine() and json.loads(path.read_text()) == written
    assert payload(written) == {"result": 1}
    assert unit_state(path, "s", {"unit": "a"}) == DONE

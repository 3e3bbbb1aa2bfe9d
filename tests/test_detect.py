"""``whiskerbench detect`` end to end on a rendered sample, every preset, and bad input."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from pipeline.backends import available
from pipeline.presets import PRESETS
from scenes.tables import DETECTIONS, corners_of, names


@pytest.fixture(scope="module")
def sample_video(rendered_pair):
    return rendered_pair / "soft-intermediate-100-outdoor-lab"


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        pytest.param(
            name,
            marks=pytest.mark.skipif(
                not all(map(available, preset.backends)), reason="needs the peers extra"
            ),
        )
        for name, preset in PRESETS.items()
    ],
)
def test_every_preset_runs_and_paper_finds_the_branch(sample_video, tmp_path, name) -> None:
    from bench.evaluate.detect import run_detect
    from scenes.profile import load_profile

    camera = load_profile(sample_video / "camera.json").lens
    record = run_detect(sample_video / "video.mp4", camera, PRESETS[name], tmp_path)
    assert record["true_gaps"] == [[8, 9]]
    assert (tmp_path / "branches.png").stat().st_size > 1000
    table = pd.read_parquet(tmp_path / "detections.parquet")
    assert list(table.columns) == names(DETECTIONS)
    assert [str(table[c.name].dtype) for c in DETECTIONS] == [c.dtype for c in DETECTIONS]
    assert record["frames"] == table["frame"].max() + 1
    if name == "paper":
        gaps = [b["gap"] for b in record["branches"]]
        assert len(gaps) == 1 and abs(gaps[0][0] - 8) <= 1


def _run(*args: str) -> subprocess.CompletedProcess:
    """``whiskerbench detect`` as a user runs it: a process of its own (the exit code reaches
    the shell). The other tests call :func:`_detect`, the same command in this process."""
    return subprocess.run(
        [sys.executable, "-m", "bench.cli", "detect", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def _detect(capsys, *args: str) -> tuple[int, str]:
    """``whiskerbench detect`` in this process: (exit code, stderr)."""
    from bench.cli.main import main

    capsys.readouterr()
    code = main(["detect", *args])
    return code, capsys.readouterr().err


@pytest.mark.slow
def test_unreadable_video_and_bad_camera_one_line_exit_2(tmp_path) -> None:
    """An old dataset's bare camera file still loads (the video is what is refused)."""
    camera = tmp_path / "camera.json"
    from scenes.camera import default_camera

    camera.write_text(json.dumps(default_camera().to_dict()))
    video = tmp_path / "v.mp4"
    video.write_bytes(b"\x00not a video" * 100)
    bad = _run(str(video), "--camera", str(camera), "--out", str(tmp_path / "o"))
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert "not a readable video" in bad.stderr and not (tmp_path / "o").exists()
    (tmp_path / "c.json").write_text("{}")
    worse = _run(str(video), "--camera", str(tmp_path / "c.json"))
    assert worse.returncode == 2 and "--camera" in worse.stderr
    assert len(worse.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_score_dataset_uses_the_twin_threshold_and_scores_every_sample(sample_video, tmp_path):
    from bench.evaluate.score import score_dataset

    table = score_dataset(sample_video.parent, PRESETS["paper"], tmp_path)
    assert len(table) == 2 and (tmp_path / "samples.csv").exists()
    assert (tmp_path / "grid-outdoor-lab.png").stat().st_size > 1000
    branch = table[table["branches"] == "100"].iloc[0]
    assert branch["threshold_source"] == "none-sample twin"
    assert branch["outcome"] == "correct" and branch["recall"] > 0.98
    assert table[table["branches"] == "none"].iloc[0]["false_positives"] == 0


def _cut(sample_video, tmp_path, frames) -> tuple:
    """A copy of the sample's video holding only ``frames`` (with its camera file)."""
    import itertools

    from bench.common.video import read_video, write_video

    video = tmp_path / "cut.mp4"
    chosen = set(frames)
    source = read_video(sample_video / "video.mp4")
    write_video(
        video,
        (f for i, f in enumerate(itertools.islice(source, max(chosen) + 1)) if i in chosen),
        15.0,
    )
    camera = sample_video / "camera.json"
    return video, camera


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")
def test_a_video_that_starts_in_contact_is_refused(sample_video, tmp_path, capsys) -> None:
    labels = pd.read_parquet(sample_video / "labels.parquet")
    deflection = labels.pivot(index="frame", columns="whisker", values="deflection_mm").to_numpy()
    window = 10
    rise = [
        (deflection[s : s + window].max(axis=0) - deflection[s : s + window].min(axis=0)).max()
        for s in range(len(deflection) - window)
    ]
    start = int(np.argmax(rise))
    assert rise[start] > 2.0  # the labels say a whisker moves 2+ mm in those frames
    # those frames alone: the baseline check reads a video's first 10 (baseline_frames) frames,
    # each detected on its own (the paper preset, detect's default, searches the full frame), so
    # frames past them change nothing in the refusal
    assert PRESETS["paper"].baseline_frames == window
    video, camera = _cut(sample_video, tmp_path, range(start, start + window))
    code, err = _detect(capsys, str(video), "--camera", str(camera), "--out", str(tmp_path / "o"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "no no-contact frames" in err and not (tmp_path / "o").exists()
    # the same video from its free-air start is fine
    fine, _ = _cut(sample_video, tmp_path, range(0, start + window))
    assert _detect(capsys, str(fine), "--camera", str(camera), "--out", str(tmp_path / "p"))[0] == 0


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")
def test_a_camera_file_of_another_size_is_refused(sample_video, tmp_path, capsys) -> None:
    from scenes.profile import load_profile

    profile = load_profile(sample_video / "camera.json")
    small = profile.with_lens(
        dataclasses.replace(profile.lens, width_px=1296, height_px=972, cx_px=647.5, cy_px=485.5)
    )
    (tmp_path / "small.json").write_text(json.dumps(small.to_json()))
    video, _ = _cut(sample_video, tmp_path, range(12))
    code, err = _detect(capsys, str(video), "--camera", str(tmp_path / "small.json"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "2592x1944 px but the camera model is 1296x972" in err


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")
def test_a_marker_never_seen_is_reported(sample_video, tmp_path, capsys) -> None:
    """Black out whisker 0's marker in every frame: the estimate goes on and says so."""
    import itertools

    from bench.common.video import read_video, write_video

    labels = pd.read_parquet(sample_video / "labels.parquet")
    first = labels[labels["whisker"] == 0]
    xs, ys = np.moveaxis(corners_of(first), -1, 0)
    x0, x1 = int(np.nanmin(xs)) - 6, int(np.nanmax(xs)) + 7
    y0, y1 = int(np.nanmin(ys)) - 6, int(np.nanmax(ys)) + 7

    def hidden(frames):
        for frame in frames:
            frame = frame.copy()
            frame[y0:y1, x0:x1] = 0
            yield frame

    video = tmp_path / "hidden.mp4"
    write_video(video, hidden(itertools.islice(read_video(sample_video / "video.mp4"), 40)), 15.0)
    camera = str(sample_video / "camera.json")
    code, err = _detect(capsys, str(video), "--camera", camera, "--out", str(tmp_path / "o"))
    assert code == 0
    assert "markers of whiskers [0] never seen" in err
    assert json.loads((tmp_path / "o" / "branches.json").read_text())["unseen_markers"] == [0]


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")
def test_score_flags_a_sample_without_no_contact_frames(sample_video, tmp_path) -> None:
    """A sample cut to start while a whisker is pushed is refused and reported, not scored."""
    import shutil

    from bench.evaluate.score import score_dataset

    dataset = tmp_path / "data"
    shutil.copytree(sample_video.parent, dataset, ignore=shutil.ignore_patterns("scores"))
    folder = dataset / sample_video.name
    labels = pd.read_parquet(folder / "labels.parquet")
    deflection = labels.pivot(index="frame", columns="whisker", values="deflection_mm").to_numpy()
    rise = [np.ptp(deflection[s : s + 10], axis=0).max() for s in range(len(deflection) - 10)]
    start = int(np.argmax(rise))
    end = start + PRESETS["paper"].baseline_frames  # what the refusal reads (see above)
    video, _ = _cut(sample_video, tmp_path, range(start, end))
    shutil.copy(video, folder / "video.mp4")
    cut = labels[labels["frame"].between(start, end - 1)].copy()
    cut["frame"] -= start
    cut.to_parquet(folder / "labels.parquet")
    _reseal(dataset, sample_video.name)
    table = score_dataset(dataset, PRESETS["paper"], tmp_path / "scores")
    refused = table[table["sample_id"] == sample_video.name].iloc[0]
    assert refused["outcome"] == "refused"
    assert "no no-contact frames" in refused["refused_reason"]
    assert table[table["branches"] == "none"].iloc[0]["outcome"] == "correct"


def _reseal(dataset, sample_id) -> None:
    """Record an edited sample's files as the dataset's own, as regenerating it would: score
    refuses files that differ from their recorded SHA-256."""
    from bench.common.manifest import sha256
    from bench.common.video import video_info

    folder = dataset / sample_id
    record = json.loads((folder / "sample.json").read_text())
    record["files"] = {name: sha256(folder / name) for name in record["files"]}
    record["frames"] = video_info(folder / "video.mp4").frame_count
    (folder / "sample.json").write_text(json.dumps(record))
    manifest = json.loads((dataset / "manifest.json").read_text())
    for name in [*record["files"], "sample.json"]:
        manifest["files"][f"{sample_id}/{name}"] = sha256(folder / name)
    (dataset / "manifest.json").write_text(json.dumps(manifest))

"""The dataset loader (``whiskerbench.open_dataset``): lazy frames, exact random access, labels,
camera and metadata; refusals in one line naming the file; no Mitsuba; the format version."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from fake_dataset import SAMPLES, make_dataset, small_camera

from bench.common.grey_video import GreyVideo
from bench.common.video import read_video
from bench.dataset.format import FORMAT_VERSION, DatasetFormatError, check_format_version
from bench.dataset.loader import Frame, open_dataset
from bench.dataset.verify import DatasetIntegrityError
from scenes.tables import CORNER_COLUMNS

ROOT = Path(__file__).resolve().parents[1]
LONG, SHORT = SAMPLES  # 64 frames (three keyframes: 0, 30, 60), 5 frames


@pytest.fixture(scope="module")
def fake(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("fake") / "data")


@pytest.fixture
def copy(fake, tmp_path) -> Path:
    """A copy of the fake dataset, for a test to break."""
    return Path(shutil.copytree(fake, tmp_path / "data"))


def bgr_grey(path: Path) -> list[np.ndarray]:
    """Every frame as plain OpenCV gives it, decoded to BGR, converted to grey: the reference
    the luma shortcut must equal."""
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    frames = []
    while (read := cap.read())[0]:
        frames.append(cv2.cvtColor(read[1], cv2.COLOR_BGR2GRAY))
    cap.release()
    return frames


def test_dataset_samples_meta_camera_labels(fake) -> None:
    ds = open_dataset(fake)
    assert len(ds) == 2 and ds.sample_ids == (LONG, SHORT)
    assert ds.format_version == FORMAT_VERSION and ds.manifest["kind"] == "dataset"
    assert [s.id for s in ds] == [LONG, SHORT] and ds[-1].id == ds[SHORT].id == SHORT
    assert LONG in ds and "nope" not in ds
    sample = ds[LONG]
    assert sample.meta == json.loads((fake / LONG / "sample.json").read_text())
    assert sample.camera == small_camera() and sample.profile.name == "test-small"
    pd.testing.assert_frame_equal(sample.labels, pd.read_parquet(fake / LONG / "labels.parquet"))
    assert len(sample) == SAMPLES[LONG]
    with pytest.raises(KeyError, match="nope"):
        ds["nope"]
    with pytest.raises(IndexError):
        ds[2]


def test_frames_are_the_videos_frames_with_their_labels(fake) -> None:
    sample = open_dataset(fake)[LONG]
    truth = list(read_video(fake / LONG / "video.mp4"))
    frames = sample.frames()
    assert not isinstance(frames, list)  # a lazy iterator
    count = 0
    for k, frame in enumerate(frames):
        assert isinstance(frame, Frame) and frame.index == k
        assert frame.image.dtype == np.uint8 and frame.image.shape == (72, 96)
        assert np.array_equal(frame.image, truth[k])
        rows = sample.labels[sample.labels["frame"] == k]
        pd.testing.assert_frame_equal(frame.labels, rows)
        assert frame.time_s == rows["time_s"].iloc[0] == pytest.approx((k + 0.5) / 15)
        count += 1
    assert count == len(truth) == len(sample)


def test_random_access_equals_the_sequential_decode(fake) -> None:
    """frame(i) in any order (backwards, across keyframes, repeated) is the i-th frame."""
    sample = open_dataset(fake)[LONG]
    truth = bgr_grey(fake / LONG / "video.mp4")
    order = [63, 0, 31, 30, 29, 62, 1, 1, 45, 5, 60, -1, *np.random.default_rng(3).permutation(64)]
    for index in order:
        frame = sample.frame(int(index))
        assert frame.index == index % 64 and np.array_equal(frame.image, truth[index])
    with pytest.raises(IndexError, match="out of range"):
        sample.frame(64)
    for index in (1.5, "3", None, True):
        with pytest.raises(TypeError, match="a frame is taken by integer index"):
            sample.frame(index)
    assert sample.frame(np.int64(2)).index == 2
    sample.close()
    assert np.array_equal(sample.frame(10).image, truth[10])  # reopens


def test_a_sample_pickles_for_worker_processes(fake) -> None:
    import pickle

    sample = open_dataset(fake)[LONG]
    first = sample.frame(7).image  # the video is open
    copy = pickle.loads(pickle.dumps(sample))
    assert copy.id == LONG and np.array_equal(copy.frame(7).image, first)


@pytest.mark.parametrize("seek", [True, False])
def test_grey_video_seeks_exactly_or_decodes_forward(fake, seek) -> None:
    path = fake / LONG / "video.mp4"
    truth = bgr_grey(path)
    with GreyVideo(path, seek=seek) as video:
        assert video.luma  # this OpenCV hands over the luma plane: the fast path is tested
        for index in np.random.default_rng(1).permutation(64):
            assert np.array_equal(video.read(int(index)), truth[index])
        assert (video.seeks > 0) == seek


def test_grey_video_falls_back_on_a_colour_video(tmp_path) -> None:
    """A colour video's luma is not its grey conversion: every frame goes through BGR."""
    from bench.common.video import write_video

    rng = np.random.default_rng(2)
    path = tmp_path / "colour.mp4"
    write_video(path, [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(8)], 15.0)
    truth = bgr_grey(path)
    with GreyVideo(path) as video:
        assert not video.luma
        assert all(np.array_equal(video.read(i), truth[i]) for i in (7, 0, 3, 4))
    assert all(map(np.array_equal, read_video(path), truth))


def test_read_video_takes_the_luma_plane_of_a_grey_video(fake, monkeypatch) -> None:
    """Front to back (score, detect), the project's grey video is read as its luma plane and
    equals the BGR decode converted to grey, frame for frame."""
    from bench.common import grey_video

    path = fake / LONG / "video.mp4"
    truth = bgr_grey(path)
    luma = []
    monkeypatch.setattr(
        grey_video.GreyVideo, "_grey", lambda self, f: luma.append(self.luma) or f[: self.height]
    )
    frames = list(read_video(path))
    assert len(frames) == len(truth) == 64 and all(map(np.array_equal, frames, truth))
    assert luma == [True] * 63  # frame 0 kept from the check, the rest as luma planes


def test_the_luma_check_runs_once_per_file(fake, monkeypatch) -> None:
    from bench.common import grey_video

    path = fake / SHORT / "video.mp4"
    GreyVideo(path).close()  # checked (or the verdict kept from another test)

    def fail(_path):
        raise AssertionError("checked again")

    monkeypatch.setattr(grey_video, "_bgr_grey_frame0", fail)
    with GreyVideo(path) as video:
        assert video.luma and np.array_equal(video.read(4), list(read_video(path))[4])


def test_frame_labels_from_a_table_out_of_frame_order(copy) -> None:
    path = copy / LONG / "labels.parquet"
    labels = pd.read_parquet(path)
    labels.sample(frac=1.0, random_state=0).to_parquet(path, index=False)
    sample = open_dataset(copy)[LONG]
    for index in (0, 33, 63):
        frame = sample.frame(index)
        want = labels[labels["frame"] == index]
        assert frame.time_s == want["time_s"].iloc[0]
        pd.testing.assert_frame_equal(
            frame.labels.sort_values("whisker").reset_index(drop=True),
            want.reset_index(drop=True),
        )


def test_grey_video_names_a_truncated_file(fake, tmp_path) -> None:
    path = tmp_path / "cut.mp4"
    data = (fake / LONG / "video.mp4").read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with GreyVideo(path) as video, pytest.raises(ValueError, match="cut.mp4: frame .* decode"):
        for index in range(64):
            video.read(index)


def test_verify_checks_every_hash_on_request(copy) -> None:
    assert open_dataset(copy, verify=True).verified is not None
    labels = copy / SHORT / "labels.parquet"
    labels.write_bytes(labels.read_bytes() + b"\0")
    ds = open_dataset(copy)  # hashes are not read unless asked
    with pytest.raises(DatasetIntegrityError, match="labels.parquet: SHA-256 differs"):
        ds.verify()
    with pytest.raises(DatasetFormatError, match="labels.parquet"):
        open_dataset(copy, verify=True)


def test_verify_refuses_a_newer_major_version(copy) -> None:
    """score and compare verify first: they refuse it too, naming the manifest."""
    from bench.dataset.verify import verify_dataset

    _edit_json(copy / "manifest.json", format_version="2.1")
    with pytest.raises(DatasetFormatError, match=r"manifest.json: dataset format 2.1 is newer"):
        verify_dataset(copy)


def _edit_json(path: Path, **changes) -> None:
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps({k: v for k, v in data.items() if v is not None}))


def test_format_versions() -> None:
    assert check_format_version({}, "m.json") == "1.0"  # made before the field
    assert check_format_version({"format_version": "1.9"}, "m.json") == "1.9"
    with pytest.raises(DatasetFormatError, match=r"^m.json: dataset format 2.0 is newer"):
        check_format_version({"format_version": "2.0"}, "m.json")
    for bad in ("1", "one.0", 1.0, "0.3", "1.0.1"):
        with pytest.raises(DatasetFormatError, match="is not a version"):
            check_format_version({"format_version": bad}, "m.json")


def _break(root: Path, how: str) -> tuple[Path, str]:
    """Break the copied dataset ``how``; (the path to open, the file the error must name)."""
    manifest = root / "manifest.json"
    sample = root / LONG
    if how == "no folder":
        return root / "absent", "absent"
    if how == "no manifest":
        manifest.unlink()
    elif how == "malformed manifest":
        manifest.write_text('{"kind": "dataset", ')
    elif how == "another command's":
        _edit_json(manifest, kind="score")
    elif how == "unfinished":
        _edit_json(manifest, files=None)
    elif how == "newer major":
        _edit_json(manifest, format_version="2.0")
    elif how == "bad sample id":
        _edit_json(manifest, samples=["../x"])
    elif how == "missing video":
        (sample / "video.mp4").unlink()
        return root, f"{LONG}/video.mp4"
    else:
        raise AssertionError(how)
    return root, "manifest.json"


@pytest.mark.parametrize(
    "how",
    [
        "no folder",
        "no manifest",
        "malformed manifest",
        "another command's",
        "unfinished",
        "newer major",
        "bad sample id",
        "missing video",
    ],
)
def test_open_refuses_in_one_line_naming_the_file(copy, how) -> None:
    path, name = _break(copy, how)
    with pytest.raises(DatasetFormatError) as info:
        open_dataset(path)
    message = str(info.value)
    assert "\n" not in message and name in message, message


@pytest.mark.parametrize(
    "how, name",
    [
        ("sample.json", "sample.json"),
        ("camera.json", "camera.json"),
        ("camera field", "camera.json"),
        ("labels column", "labels.parquet"),
        ("labels text", "labels.parquet"),
        ("frame count", "sample.json"),
        ("video size", "video.mp4"),
    ],
)
def test_a_sample_refuses_in_one_line_naming_the_file(copy, how, name) -> None:
    folder = copy / LONG
    if how == "sample.json":
        (folder / "sample.json").write_text("{not json")
    elif how == "camera.json":
        (folder / "camera.json").write_text("[1, 2")
    elif how == "camera field":
        _edit_json(folder / "camera.json", lens={"model": {"width_px": 96}})
    elif how == "labels column":
        pd.read_parquet(folder / "labels.parquet").drop(columns=CORNER_COLUMNS[0][0]).to_parquet(
            folder / "labels.parquet"
        )
    elif how == "labels text":
        (folder / "labels.parquet").write_text("frame,marker_id\n0,0\n")
    elif how == "frame count":
        _edit_json(folder / "sample.json", frames=65)
    elif how == "video size":
        camera = json.loads((folder / "camera.json").read_text())
        camera["lens"]["model"].update(width_px=98, cx_px=48.5)
        (folder / "camera.json").write_text(json.dumps(camera))
    with pytest.raises(DatasetFormatError) as info:
        sample = open_dataset(copy)[LONG]
        sample.labels  # noqa: B018 - read on first use
        sample.frame(0)
    message = str(info.value)
    assert "\n" not in message and f"{LONG}/{name}" in message, message


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_imports_no_mitsuba_or_drjit(fake) -> None:
    """Opening, verifying and reading a dataset loads neither (a fresh interpreter)."""
    code = (
        "import sys\n"
        "from bench.dataset.loader import open_dataset\n"
        f"ds = open_dataset({str(fake)!r}, verify=True)\n"
        "s = ds[0]; s.camera; s.labels; s.frame(40); sum(1 for _ in s.frames())\n"
        "print(sorted(m for m in ('mitsuba', 'drjit') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]", out.stderr


def test_bench_loader_prints_the_ratio(fake, capsys) -> None:
    from bench.cli.main import main

    assert main(["bench", "loader", str(fake), "--repeats", "1", "--random-frames", "5"]) == 0
    out = capsys.readouterr().out
    assert "loader / OpenCV: " in out and "random access: 4 frames" in out
    assert main(["bench", "loader", str(fake / "absent")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("whiskerbench bench loader: error: DATASET:") and "\n" not in err
    assert main(["bench", "loader", str(fake), "--sample", "nope"]) == 2


@pytest.mark.slow
def test_a_rendered_dataset_reads_back(rendered_pair, pair_config) -> None:
    """``whiskerbench dataset`` writes the format version (not in the settings hash) and the
    loader reads what it wrote: verified, every frame the video's, the camera the profile's."""
    from scenes.profile import load_profile

    manifest = json.loads((rendered_pair / "manifest.json").read_text())
    assert manifest["format_version"] == FORMAT_VERSION
    assert manifest["settings_sha256"] == pair_config.settings_hash()
    assert "format_version" not in json.dumps(pair_config.to_json())
    ds = open_dataset(rendered_pair, verify=True)
    assert list(ds.sample_ids) == [s.sample_id for s in pair_config.samples()]
    sample = ds[1]
    assert sample.camera == load_profile(rendered_pair / sample.id / "camera.json").lens
    truth = list(read_video(rendered_pair / sample.id / "video.mp4"))
    assert len(truth) == len(sample) == sample.meta["frames"]
    for frame, image in zip(sample.frames(), truth, strict=True):
        assert np.array_equal(frame.image, image)
        assert len(frame.labels) == pair_config.array.n_whiskers
    for index in np.random.default_rng(0).permutation(len(truth))[:8]:
        assert np.array_equal(sample.frame(int(index)).image, truth[index])

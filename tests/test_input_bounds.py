"""Every file a user hands over is bounded by its header or size before it is decoded or parsed
(issue 24, part 3): images by their header's size, depth and channels; videos by their
container's frame size and count and every frame header against the first; YAML and JSON by
size, depth, node count and aliases. Each refusal is one line naming the file, exit code 2,
nothing written; the header checks are compared with what OpenCV decodes.
"""

from __future__ import annotations

import json
import os
import re
import struct
import subprocess
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import pytest

from bench.cli.main import main
from bench.common import image_header as image_header_module
from bench.common import video_bounds
from bench.common.grey_video import GreyVideo
from bench.common.image_header import ImageHeaderError, image_header, read_bounded_image
from bench.common.video import check_video, read_video, write_video
from scenes.bounded_read import BoundedReadError, BoundedSafeLoader, parse_json, read_json
from scenes.calibration_import import CalibrationError, import_calibration
from scenes.input_limits import FRAME_PIXELS, SETTINGS_BYTES, SETTINGS_DEPTH

FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()
KALIBR = (
    "cam0:\n  camera_model: pinhole\n  intrinsics: {intrinsics}\n"
    "  distortion_model: equidistant\n  distortion_coeffs: [0, 0, 0, 0]\n"
    "  resolution: [640, 480]\n"
)


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p): (p.lstat().st_size, p.lstat().st_mtime_ns) for p in [folder, *folder.rglob("*")]
    }


def refused(argv: list, pattern: str, capsys, folder: Path) -> str:
    """Run the command; it must exit 2 with one stderr line matching ``pattern`` and leave
    ``folder`` as it was."""
    before = snapshot(folder)
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err.strip().split("\n")
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("whiskerbench "), err
    assert re.search(pattern, err[0]), (pattern, err[0])
    assert snapshot(folder) == before, "something was written"
    return err[0]


# --- images: the header parsed here agrees with OpenCV's decode, and a lying one is refused


def _encoded(ext: str, shape: tuple, dtype) -> bytes:
    image = np.random.default_rng(0).integers(0, 200, shape).astype(dtype)
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tif"])
@pytest.mark.parametrize("shape", [(37, 53), (37, 53, 3), (37, 53, 4)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_header_agrees_with_opencv(ext, shape, dtype):
    data = _encoded(ext, shape, dtype)
    header = image_header(data)
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert (header.width, header.height) == (decoded.shape[1], decoded.shape[0])
    assert (header.bits <= 8) == (decoded.dtype == np.uint8)
    channels = 1 if decoded.ndim == 2 else decoded.shape[2]
    assert header.channels == channels or ext == ".bmp"  # a grey BMP: an 8-bit palette


def _lying_png(width: int, height: int) -> bytes:
    """A small real PNG whose IHDR is rewritten to claim width x height (CRC left wrong)."""
    data = bytearray(_encoded(".png", (16, 16), np.uint8))
    struct.pack_into(">II", data, 16, width, height)
    return bytes(data) + b"\0" * 4000  # a few kB


def _lying_jpeg(width: int, height: int) -> bytes:
    data = bytearray(_encoded(".jpg", (16, 16), np.uint8))
    at = data.find(b"\xff\xc0")
    struct.pack_into(">HH", data, at + 5, height, width)
    return bytes(data)


@pytest.mark.parametrize("make", [_lying_png, _lying_jpeg], ids=["png", "jpeg"])
def test_huge_header_refused_before_decoding(make, tmp_path, monkeypatch):
    path = tmp_path / "huge.img"
    path.write_bytes(make(60000, 60000))

    def no_decode(*args):
        raise AssertionError("decoded before the header was checked")

    monkeypatch.setattr(image_header_module.cv2, "imdecode", no_decode)
    pattern = rf"60000 x 60000 px is over the limit of {FRAME_PIXELS / 1e6:g} MP"
    with pytest.raises(ImageHeaderError, match=pattern):
        read_bounded_image(path)
    if make is _lying_png:  # a side over JPEG's 16 bits, the area small
        path.write_bytes(make(100_000, 1))
        with pytest.raises(ImageHeaderError, match=r"100000 x 1 px: each side must be 1\.\.65535"):
            read_bounded_image(path)


@pytest.mark.parametrize(
    "name, content, pattern",
    [
        ("huge.png", _lying_png(60000, 60000), r"huge\.png: PNG of 60000 x 60000 px"),
        ("huge.jpg", _lying_jpeg(30000, 30000), r"huge\.jpg: JPEG of 30000 x 30000 px"),
        ("deep.png", _encoded(".png", (8, 8), np.uint16), r"deep\.png: .*16-bit samples"),
        ("webp.png", b"RIFF\0\0\0\0WEBPVP8 " + b"\0" * 64, r"webp\.png: not a readable image"),
    ],
)
def test_images_refused_by_the_commands(name, content, pattern, tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / name).write_bytes(content)
    argv = ["detect-images", folder / name, "--pipelines", "paper", "--out", tmp_path / "o"]
    refused(argv, pattern, capsys, tmp_path)
    argv = ["lens", "measure", folder, "--camera", "ideal", "--out", tmp_path / "p.json"]
    refused(argv, pattern, capsys, tmp_path)


# --- videos: frame size and count from the container, every frame header against the first


def _concat(parts: list[Path], out: Path) -> Path:
    """One H.264 stream of the parts' frames, remuxed without re-encoding (the frame size
    changes where a part starts)."""
    streams = []
    for part in parts:
        annexb = part.with_suffix(".h264")
        cmd = [FFMPEG, "-y", "-v", "error", "-i", part, "-c", "copy", "-bsf:v", "h264_mp4toannexb"]
        subprocess.run([*map(str, cmd), str(annexb)], check=True)
        streams.append(annexb.read_bytes())
    joined = out.with_suffix(".h264")
    joined.write_bytes(b"".join(streams))
    cmd = [FFMPEG, "-y", "-v", "error", "-r", "10", "-i", joined, "-c", "copy", out]
    subprocess.run(list(map(str, cmd)), check=True)
    return out


def _mjpeg(frames: list[np.ndarray], out: Path) -> Path:
    """An MJPEG AVI of the frames as given (sizes may differ), muxed without re-encoding."""
    raw = out.with_suffix(".mjpeg")
    raw.write_bytes(b"".join(cv2.imencode(".jpg", f)[1].tobytes() for f in frames))
    cmd = [FFMPEG, "-y", "-v", "error", "-f", "mjpeg", "-r", "10", "-i", raw, "-c:v", "copy", out]
    subprocess.run(list(map(str, cmd)), check=True)
    return out


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("videos")
    small = [np.full((48, 64), 90, np.uint8)] * 3
    large = [np.full((96, 128), 180, np.uint8)] * 3
    write_video(folder / "small.mp4", small, 10.0)
    write_video(folder / "large.mp4", large, 10.0)
    return {
        "small": folder / "small.mp4",
        "h264_change": _concat([folder / "small.mp4", folder / "large.mp4"], folder / "hc.mp4"),
        "mjpeg": _mjpeg(small, folder / "same.avi"),
        "mjpeg_change": _mjpeg(small + large, folder / "mc.avi"),
    }


def test_opencv_rescales_a_changing_video_silently(videos):
    """Why the check is needed: OpenCV hands over the second part at the first part's size."""
    cap = cv2.VideoCapture(str(videos["mjpeg_change"]), cv2.CAP_FFMPEG)
    shapes = []
    while (frame := cap.read()[1]) is not None:
        shapes.append(frame.shape[:2])
    assert shapes == [(48, 64)] * 6


@pytest.mark.parametrize("name", ["h264_change", "mjpeg_change"])
def test_frame_size_change_refused(name, videos, tmp_path, capsys):
    path = videos[name]
    pattern = r"frame 3 is 128 x 96 px where the video starts at 64 x 48 px"
    with pytest.raises(ValueError, match=pattern):
        check_video(path)
    with pytest.raises(ValueError, match=pattern):
        next(read_video(path))
    with pytest.raises(ValueError, match=pattern):
        GreyVideo(path)
    shutil_copy = tmp_path / path.name
    shutil_copy.write_bytes(path.read_bytes())
    refused(
        ["detect", shutil_copy, "--camera", "ideal"], rf"{path.name}: {pattern}", capsys, tmp_path
    )
    argv = ["lens", "measure", shutil_copy, "--camera", "ideal", "--out", tmp_path / "p.json"]
    refused(argv, rf"{path.name}: {pattern}", capsys, tmp_path)


def test_steady_videos_pass_with_their_frame_count(videos):
    for name in ("small", "mjpeg"):
        facts = check_video(videos[name])
        assert (facts.width, facts.height, facts.frames) == (64, 48, 3)
        assert sum(1 for _ in read_video(videos[name])) == 3


@pytest.mark.parametrize(
    "size, options",
    [
        ((100, 50), []),  # cropped: 50 is not a multiple of 16
        ((98, 62), ["-pix_fmt", "yuv444p", "-qp", "0"]),  # High 4:4:4 Predictive
        ((130, 34), ["-pix_fmt", "gray"]),  # monochrome
        ((320, 240), ["-x264opts", "interlaced=1"]),  # field macroblocks
        ((160, 96), ["-x264opts", "cqm=jvt"]),  # scaling matrices in the SPS
    ],
)
def test_sps_sizes_agree_with_the_container(size, options, tmp_path):
    out = tmp_path / "t.mp4"
    source = f"testsrc=s={size[0]}x{size[1]}:d=0.3"
    cmd = [FFMPEG, "-y", "-v", "error", "-f", "lavfi", "-i", source, "-c:v", "libx264", *options]
    subprocess.run([*cmd, str(out)], check=True)
    facts = check_video(out)
    assert (facts.width, facts.height) == size
    cap = cv2.VideoCapture(str(out), cv2.CAP_FFMPEG)
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == size


def test_frame_size_bound_checked_before_decoding(videos, monkeypatch):
    monkeypatch.setattr(video_bounds, "FRAME_PIXELS", 1000)
    monkeypatch.setattr(video_bounds, "_PASSED", {})
    with pytest.raises(ValueError, match=r"64 x 48 px is over the limit of 0\.001 MP"):
        next(read_video(videos["small"]))
    monkeypatch.setattr(video_bounds, "FRAME_PIXELS", FRAME_PIXELS)
    monkeypatch.setattr(video_bounds, "VIDEO_FRAMES", 2)
    with pytest.raises(ValueError, match=r"3 frames declared; at most 2"):
        check_video(videos["small"])


def test_unknown_codec_refused_naming_the_fix(tmp_path):
    path = tmp_path / "mpeg4.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FMP4"), 10, (64, 48))
    for _ in range(3):
        writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    with pytest.raises(ValueError, match=r"codec 'FMP4'.*re-encode"):
        check_video(path)


# --- YAML and JSON: size, depth, nodes, aliases


def _bomb(levels: int = 9) -> str:
    lines = ['l0: &l0 ["x","x","x","x","x","x","x","x","x"]']
    lines += [f"l{i}: &l{i} [{','.join([f'*l{i - 1}'] * 9)}]" for i in range(1, levels)]
    return "\n".join(lines) + "\n" + KALIBR.format(intrinsics=f"*l{levels - 1}")


def test_yaml_alias_bomb_refused(tmp_path, capsys):
    path = tmp_path / "bomb.yaml"
    path.write_text(_bomb())
    assert path.stat().st_size < 1000  # 9**9 strings once walked
    with pytest.raises(CalibrationError, match=r"alias \*l0 at line 2: aliases are refused"):
        import_calibration(path, "kalibr")
    argv = ["camera", "import", path, "--format", "kalibr", "--out", tmp_path / "p.json"]
    refused(argv, r"FILE: .*bomb\.yaml: file: refused YAML: alias", capsys, tmp_path)


@pytest.mark.parametrize(
    "text, pattern",
    [
        ("a: " + "[" * 50 + "]" * 50, r"nested deeper than 8"),
        ("a: [" + ", ".join(["1"] * 20000) + "]", r"more than 10000 YAML nodes"),
        ("a: &x 1\nb: *x\n", r"alias \*x"),
    ],
)
def test_yaml_bounds(text, pattern):
    import yaml

    with pytest.raises(yaml.YAMLError, match=pattern):
        yaml.load(text, Loader=BoundedSafeLoader)


@pytest.mark.parametrize(
    "content, pattern",
    [
        ("[" * 100_000, r"not valid JSON"),  # a RecursionError in json.loads
        ('{"a": ' + "1" * 5000 + "}", r"not valid JSON \(Exceeds the limit"),
        ('{"a": ' + "[" * 20 + "]" * 20 + "}", rf"nested deeper than {SETTINGS_DEPTH}"),
        (" " * (SETTINGS_BYTES + 1), rf"larger than {SETTINGS_BYTES} bytes"),
        (b"\xff\xfe\x00", r"not valid JSON|not UTF-8 text"),
    ],
)
def test_json_bounds(content, pattern, tmp_path, capsys):
    path = tmp_path / "bad.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(BoundedReadError, match=pattern):
        read_json(path, SETTINGS_BYTES, SETTINGS_DEPTH)
    refused(["camera", "show", path], rf"bad\.json: {pattern}", capsys, tmp_path)
    refused(
        ["camera", "import", path, "--format", "basalt", "--out", tmp_path / "p.json"],
        pattern,
        capsys,
        tmp_path,
    )


def test_fifo_is_refused_not_waited_on(tmp_path, capsys):
    fifo = tmp_path / "camera.json"
    os.mkfifo(fifo)
    with pytest.raises(BoundedReadError, match="not a regular file"):
        read_json(fifo, SETTINGS_BYTES, SETTINGS_DEPTH)  # would block on open() otherwise
    refused(
        ["camera", "show", fifo],
        r"camera\.json': not a regular file \(a named pipe\)$",
        capsys,
        tmp_path,
    )
    argv = ["camera", "import", fifo, "--format", "basalt", "--out", tmp_path / "p.json"]
    refused(argv, r"camera\.json: file: not a regular file \(a named pipe\)$", capsys, tmp_path)


@pytest.mark.parametrize(
    "argv",
    [
        ["detect", "{}", "--camera", "prototype", "--out", "o"],
        ["detect", "v.mp4", "--camera", "{}", "--out", "o"],
        ["detect-images", "{}", "--pipelines", "fast", "--out", "o"],
        ["camera", "show", "{}"],
        ["camera", "import", "{}", "--format", "kalibr", "--out", "p.json"],
        ["lens", "measure", "{}", "--camera", "prototype", "--out", "p.json"],
    ],
)
def test_a_fifo_or_a_link_loop_is_named_not_missing(argv, tmp_path, capsys, monkeypatch):
    """The shared check (scenes.bounded_read.input_problem) says what is there instead of "no
    such file", in every command that reads an input file."""
    monkeypatch.chdir(tmp_path)
    os.mkfifo("fifo.mp4")
    os.symlink("loop2", "loop1")
    os.symlink("loop1", "loop2")
    os.symlink("nowhere", "dangling.mp4")
    Path("v.mp4").touch()
    for name, says in (
        ("fifo.mp4", "not a regular file \\(a named pipe\\)"),
        ("loop1", "a symlink loop"),
        ("dangling.mp4", "a dangling symbolic link \\(to nowhere\\)"),
    ):
        pattern = rf"{name}'?: (file: )?{says}$"
        line = refused([a.format(name) for a in argv], pattern, capsys, tmp_path)
        assert "no such file" not in line and "neither" not in line


def test_parse_json_takes_what_the_readers_wrote():
    record = {"a": [1, 2, {"b": "c"}], "d": 1.5}
    assert parse_json(json.dumps(record), SETTINGS_DEPTH) == record


def test_fifo_truth_file_named_as_such(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    cv2.imwrite(str(tmp_path / "photos" / "a.png"), np.full((48, 64), 128, np.uint8))
    os.mkfifo(tmp_path / "truth.csv")
    argv = ["detect-images", tmp_path / "photos", "--pipelines", "paper"]
    argv += ["--truth", tmp_path / "truth.csv", "--out", tmp_path / "o"]
    refused(argv, r"--truth: .*truth\.csv: not a regular file", capsys, tmp_path)

"""``whiskerbench detect-images`` on images drawn here: exact markers (OpenCV's own bit patterns)
under known homographies, area-sampled in linear light and sRGB-encoded, with their true corners;
run in-process through ``main``."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pandas as pd
import pytest

from bench.cli.main import main
from bench.evaluate import images as job
from pipeline import backends
from scenes.camera import pinhole_camera
from scenes.marker import get_dictionary

SUPERSAMPLE = 8
SHAPE = (240, 360)  # (H, W) px
#: image -> markers (id, true corners (4, 2): ArUco order, pixel centres at integers)
MARKERS = {
    "a.png": [
        (3, [[40.3, 30.2], [160.1, 40.7], [150.4, 160.6], [30.5, 150.2]]),
        (7, [[220.0, 60.0], [330.0, 60.0], [330.0, 170.0], [220.0, 170.0]]),
    ],
    "b.png": [(11, [[60.7, 50.2], [200.3, 70.1], [190.2, 190.4], [50.1, 180.6]])],
    "c.jpg": [(20, [[100.2, 40.8], [250.6, 52.3], [240.1, 200.5], [95.3, 190.9]])],
    "empty.png": [],
}
HEADER = "image,marker_id,x0,y0,x1,y1,x2,y2,x3,y3"


def _srgb(linear: np.ndarray) -> np.ndarray:
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def draw(markers, family: str = "4x4_50", shape=SHAPE) -> np.ndarray:
    """(H, W) uint8: white paper with the markers, each pixel the area mean of a supersampled
    binary image in linear light, then sRGB-encoded (what ``lines`` with transfer=srgb reads)."""
    h, w = shape
    k = SUPERSAMPLE
    hi = np.ones((h * k, w * k), np.float32)
    dictionary = get_dictionary(family)
    modules = int(dictionary.markerSize) + 2
    centre = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])  # pixel index -> edge-at-0 coords
    for marker_id, quad in markers:
        bits = cv2.aruco.generateImageMarker(dictionary, marker_id, modules, borderBits=1)
        grid = np.float32([[0, 0], [modules, 0], [modules, modules], [0, modules]])
        H = cv2.getPerspectiveTransform(grid, ((np.float32(quad) + 0.5) * k).astype(np.float32))
        M = np.linalg.inv(centre) @ H @ centre  # bit index -> supersampled pixel index
        size = (w * k, h * k)
        inside = cv2.warpPerspective(np.ones_like(bits, np.float32), M, size, flags=0)
        value = cv2.warpPerspective(bits.astype(np.float32) / 255, M, size, flags=0)
        hi = np.where(inside > 0, value, hi)
    linear = cv2.resize(hi, (w, h), interpolation=cv2.INTER_AREA)
    return np.round(255 * _srgb(np.clip(linear, 0.0, 1.0))).astype(np.uint8)


def truth_rows(markers: dict) -> list[str]:
    return [
        f"{name},{marker_id}," + ",".join(f"{v:g}" for v in np.ravel(quad))
        for name, found in markers.items()
        for marker_id, quad in found
    ]


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """A folder of the drawn images (b.png in colour, c.jpg JPEG quality 90) and the truth
    file beside it."""
    root = tmp_path_factory.mktemp("photos")
    (root / "images").mkdir()
    for name, markers in MARKERS.items():
        image = draw(markers)
        if name == "b.png":  # colour: equal channels, so grey is the same image
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        cv2.imwrite(str(root / "images" / name), image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    (root / "truth.csv").write_text("\n".join([HEADER, *truth_rows(MARKERS)]) + "\n")
    return root


def run(argv, capsys) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's refusals
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def detect(photos, tmp_path, capsys, pipelines: str, *extra) -> tuple[pd.DataFrame, pd.DataFrame]:
    argv = ["detect-images", photos / "images", "--pipelines", pipelines, "--out", tmp_path]
    code, out, err = run([*argv, "--truth", photos / "truth.csv", *extra], capsys)
    assert code == 0, err
    summary = pd.read_csv(tmp_path / "summary.csv").set_index("pipeline")
    for name in summary.index:
        assert name in out  # the printed table names every pipeline
    return summary, pd.read_csv(tmp_path / "detections.csv", keep_default_na=False)


def test_scores_against_the_truth(photos, tmp_path, capsys):
    summary, detections = detect(photos, tmp_path, capsys, "paper,robust")
    markers = sum(len(m) for m in MARKERS.values())
    assert (summary.images == len(MARKERS)).all()
    assert (summary.markers == markers).all()
    assert (summary.recall == 1.0).all() and (summary.false_ids == 0).all()
    assert summary.loc["robust", "corner_err_max_px"] < 0.05  # lines: exact edges, exact corners
    assert summary.loc["robust", "lines_fallbacks"] == 0
    # subpix pulls the outer corners inside by 0.35-0.5 px (pipeline.detect): a real difference
    assert (
        summary.loc["paper", "corner_err_median_px"]
        > 5 * summary.loc["robust", "corner_err_max_px"]
    )
    truth = pd.read_csv(photos / "truth.csv")
    robust = detections[detections.pipeline == "robust"].merge(truth, on=["image", "marker_id"])
    columns = list(job.CORNER_COLUMNS)
    err = (
        robust[[c + "_x" for c in columns]].to_numpy()
        - robust[[c + "_y" for c in columns]].to_numpy()
    )
    assert len(robust) == markers and np.abs(err).max() < 0.05
    assert (tmp_path / "manifest.json").is_file()


def test_without_truth_and_with_overlays(photos, tmp_path, capsys):
    argv = ["detect-images", photos / "images" / "a.png", "--pipelines", "naive"]
    code, out, err = run([*argv, "--out", tmp_path, "--overlays"], capsys)
    assert code == 0, err
    summary = pd.read_csv(tmp_path / "summary.csv")
    assert "recall" not in summary.columns and summary.detections.tolist() == [2]
    overlay = cv2.imread(str(tmp_path / "overlays" / "naive" / "a.png"))
    assert overlay.shape == (*SHAPE, 3)


def test_camera_from_a_calibration_file(photos, tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    K = [[300.0, 0.0, 179.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]
    calibration.write_text(json.dumps({"K": K, "D": [0.1, 0, 0, 0], "size": [360, 240]}))
    argv = ["detect-images", photos / "images", "--pipelines", "naive", "--out", tmp_path / "o"]
    code, _, err = run([*argv, "--camera", calibration, "--camera-format", "opencv"], capsys)
    assert code == 0, err
    camera = json.loads((tmp_path / "o" / "manifest.json").read_text())["config"]["camera"]
    assert camera["model"] == "kannala_brandt" and camera["params"][0] == 0.1


@pytest.mark.skipif(not backends.available("locus"), reason="locus-tag not installed")
def test_a_peer_and_lines_on_its_corners(photos, tmp_path, capsys):
    summary, _ = detect(photos, tmp_path, capsys, "locus,robust/detector=locus")
    assert (summary.recall == 1.0).all()
    assert summary.loc["robust/detector=locus", "corner_err_max_px"] < 0.05


def test_family_replaces_the_pipelines_dictionary(tmp_path, capsys):
    quad = [[50.5, 40.5], [190.5, 40.5], [190.5, 180.5], [50.5, 180.5]]
    cv2.imwrite(str(tmp_path / "tag.png"), draw([(5, quad)], "apriltag_36h11"))
    truth = tmp_path / "truth.csv"
    truth.write_text("\n".join([HEADER, *truth_rows({"tag.png": [(5, quad)]})]) + "\n")
    argv = ["detect-images", tmp_path / "tag.png", "--pipelines", "robust", "--truth", truth]
    code, _, err = run([*argv, "--family", "apriltag_36h11", "--out", tmp_path / "o"], capsys)
    assert code == 0, err
    summary = pd.read_csv(tmp_path / "o" / "summary.csv")
    assert summary.recall.tolist() == [1.0] and summary.corner_err_max_px[0] < 0.05


def test_a_crash_costs_the_image_not_the_run(photos, tmp_path, capsys, monkeypatch):
    real, b_image = job.detect_markers, draw(MARKERS["b.png"])

    def crash_on_b(image, config, **kwargs):
        if np.array_equal(image, b_image):
            raise backends.BackendCrashError("detector opencv crashed (signal 11)")
        return real(image, config, **kwargs)

    monkeypatch.setattr(job, "detect_markers", crash_on_b)
    summary, _ = detect(photos, tmp_path, capsys, "paper")
    assert summary.loc["paper", "failed_images"] == 1
    markers = sum(len(m) for m in MARKERS.values())
    assert summary.loc["paper", "recall"] == pytest.approx((markers - 1) / markers)
    failures = pd.read_csv(tmp_path / "failures.csv")
    assert failures.image.tolist() == ["b.png"] and "signal 11" in failures.failure[0]


def test_pinhole_camera_projects_as_a_pinhole():
    camera = pinhole_camera(360, 240)
    points = np.array([[10.0, -20.0, 100.0], [-35.0, 12.0, 80.0], [0.0, 0.0, 5.0]])
    expected = camera.fx_px * points[:, :2] / points[:, 2:] + [camera.cx_px, camera.cy_px]
    assert np.allclose(camera.project(points), expected, atol=1e-9)
    corners = np.array([[-0.5, -0.5], [359.5, 239.5]])
    assert camera.unproject(corners)[1].all()  # the whole image is inside its circle


# --- refused: exit code 2, one line naming the culprit, nothing written


@pytest.fixture
def hostile(photos, tmp_path):
    """Files each refusal needs, in tmp_path."""
    cv2.imwrite(str(tmp_path / "deep.png"), np.zeros((8, 8), np.uint16))
    (tmp_path / "text.png").write_text("not an image")
    (tmp_path / "empty").mkdir()
    (tmp_path / "again").mkdir()
    cv2.imwrite(str(tmp_path / "again" / "a.png"), np.zeros((8, 8), np.uint8))
    rows = truth_rows(MARKERS)
    bad = {
        "nocol": "image,marker_id,x0\na.png,3,1\n",
        "nan": "\n".join([HEADER, rows[0].replace(",40.3,", ",nan,")]),
        "word": "\n".join([HEADER, rows[0].replace(",40.3,", ",left,")]),
        "far": "\n".join([HEADER, rows[0].replace(",40.3,", ",1e300,")]),
        "other": "\n".join([HEADER, rows[0].replace("a.png", "z.png")]),
        "twice": "\n".join([HEADER, rows[0], rows[1], rows[0]]),
        "id": "\n".join([HEADER, rows[0].replace("a.png,3,", "a.png,50,")]),
        "binary": "\x00\xff" * 50,
        "extra": "\n".join([HEADER + ",score", rows[0] + ",0.9"]),
        "outside": "\n".join([HEADER, rows[0].replace(",40.3,", ",60000,")]),  # within 65535
        "cut": "\n".join([HEADER, rows[0].replace(",30.2,", ",-9,")]),  # 8.5 px above the top
    }
    for name, text in bad.items():
        (tmp_path / f"{name}.csv").write_text(text)
    return tmp_path


IMAGES = "{photos}/images"
REFUSED = [
    ("{t}/deep.png --pipelines paper", r"deep\.png: PNG of .* 16-bit samples: refused"),
    ("{t}/text.png --pipelines paper", r"text\.png: not a readable image"),
    ("{t}/empty --pipelines paper", r"empty: no images"),
    (IMAGES + " {t}/again --pipelines paper", r"a\.png: 2 images have this file name"),
    (IMAGES + " --pipelines paper,nosuch", r"--pipelines.*unknown preset 'nosuch'"),
    (IMAGES + " --pipelines locus --family 4x4_1000", r"--family.*locus cannot detect"),
    (IMAGES + " --pipelines paper --family 5x5", r"--family.*unknown"),
    (IMAGES + " --pipelines robust --camera ideal", r"a\.png: 360 x 240 px, but the camera"),
    (IMAGES + " --pipelines paper --camera-format kalibr", r"--camera-format: needs --camera"),
    (IMAGES + " --pipelines paper --truth {t}/nocol.csv", r"--truth.*missing column.*y0"),
    (IMAGES + " --pipelines paper --truth {t}/nan.csv", r"--truth.*line 2: x0='nan' is not a fin"),
    (IMAGES + " --pipelines paper --truth {t}/word.csv", r"--truth.*line 2: x0='left'"),
    (IMAGES + " --pipelines paper --truth {t}/far.csv", r"--truth.*x0='1e300' is outside -65535"),
    (IMAGES + " --pipelines paper --truth {t}/other.csv", r"--truth.*'z\.png' is not among"),
    (IMAGES + " --pipelines paper --truth {t}/twice.csv", r"--truth.*line 4: marker 3 of a\.png"),
    (IMAGES + " --pipelines paper --truth {t}/id.csv", r"--truth.*marker_id='50'.*0\.\.49"),
    (IMAGES + " --pipelines paper --truth {t}/binary.csv", r"--truth.*missing column"),
    (IMAGES + " --pipelines paper --truth {t}/nosuch.csv", r"--truth.*no such file"),
    (IMAGES + " --pipelines paper --truth {t}/extra.csv", r"--truth.*column 'score' is not in"),
    (
        IMAGES + " --pipelines paper --truth {t}/outside.csv",
        r"--truth.*line 2: x0=60000 is outside image a\.png \(360 x 240 px\): expected -0\.5 ",
    ),
    (IMAGES + " --pipelines paper --truth {t}/cut.csv", r"--truth.*line 2: y0=-9 is outside image"),
]


def snapshot(*folders) -> dict:
    return {str(p): p.stat().st_mtime_ns for f in folders for p in [f, *f.rglob("*")]}


def check_refused(argv, pattern, capsys, *folders) -> None:
    before = snapshot(*folders)
    code, _, err = run(argv, capsys)
    lines = err.strip().split("\n")
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("whiskerbench detect-images: error: "), lines
    assert re.search(pattern, lines[0]), (pattern, lines[0])
    assert snapshot(*folders) == before, "something was written"


@pytest.mark.parametrize("line, pattern", REFUSED, ids=[c[0][:60] for c in REFUSED])
def test_refused(line, pattern, photos, hostile, capsys, monkeypatch):
    monkeypatch.chdir(hostile)  # the default --out lands here
    argv = ["detect-images", *line.format(photos=photos, t=hostile).split(" ")]
    check_refused([*argv, "--out", hostile / "out"], pattern, capsys, hostile, photos)


@pytest.mark.parametrize(
    "limit, value, pattern",
    [
        ("MAX_IMAGE_PIXELS", 1000, r"a\.png: PNG of 360 x 240 px is over"),
        ("MAX_IMAGES", 2, r"over 2"),
    ],
)
def test_limits(limit, value, pattern, photos, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(job, limit, value)
    argv = ["detect-images", photos / "images", "--pipelines", "paper", "--out", tmp_path / "o"]
    check_refused(argv, pattern, capsys, tmp_path, photos)


def test_missing_peer_says_how_to_install(photos, tmp_path, capsys, monkeypatch):
    from pipeline.backends import locus

    def missing():
        raise backends.missing_library("locus", "locus-tag")

    monkeypatch.setattr(locus, "load", missing)
    argv = ["detect-images", photos / "images", "--pipelines", "paper,locus", "--out", tmp_path]
    check_refused(argv, r"--pipelines: detector locus needs.*pip install", capsys, tmp_path)

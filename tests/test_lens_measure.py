"""``whiskerbench lens measure``: PSF, photon transfer and JPEG quality measured back from
footage synthesized with known values."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.cli.lens import add_lens_parser
from bench.cli.main import _Parser, main
from bench.lens.calibrate import lens_variance, marker_sheet
from bench.lens.jpeg import ANNEX_K_LUMA, ijg_table, read_jpeg_header, stream_report
from bench.lens.measure import FootageError, MeasureConfigError, measure_lens
from bench.lens.noise import PhotonTransfer
from renderers.camera_twin import record
from scenes.camera import FisheyeCamera
from scenes.profile import CameraProfile, Processing, PsfTable, Sensor, Stream

# A half-size prototype-like camera: equidistant, f = 400 px, so 70 deg lands 489 px out.
LENS = FisheyeCamera(
    width_px=1296, height_px=972, fx_px=400.0, fy_px=400.0, cx_px=647.5, cy_px=485.5
)
# The PSF to measure back: isotropic on the axis (symmetry), wider radially toward the rim.
TRUE_PSF = PsfTable(
    theta_deg=(0.0, 20.0, 40.0, 60.0, 80.0),
    sigma_radial_px=(0.6, 0.7, 0.95, 1.35, 1.8),
    sigma_tangential_px=(0.6, 0.65, 0.75, 0.9, 1.1),
)
PROFILE = CameraProfile(name="test", lens=LENS, processing=Processing(transfer="srgb"))
# A colour camera like the prototype: Bayer, bilinear demosaicing, MJPEG at quality 90.
TWIN = CameraProfile(
    name="twin",
    lens=LENS,
    sensor=Sensor(cfa="RGGB"),
    stream=Stream(codec="mjpeg", quality=90, chroma_subsampling="4:2:0"),
)
BLACK, WHITE = 0.03, 0.7  # linear reflectance x exposure of toner and paper
SIDE_PX = 72.0  # marker side: 12 px modules, over 6 sigma of the widest PSF
SUPERSAMPLE = 4
# Rings of markers at these field angles (deg) and azimuths, inside 20-degree bins.
RINGS = ((10, (0, 120, 240)), (30, range(0, 360, 45)), (50, range(22, 360, 45)),
         (70, (0, 40, 140, 180, 220, 320)))  # fmt: skip


def _srgb_codes(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding and rounding to 8 bits."""
    x = np.clip(linear, 0.0, 1.0)
    return np.rint(255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055))


def _kernel(sigma_r: float, sigma_t: float, radial: np.ndarray, scale: int) -> np.ndarray:
    """Anisotropic Gaussian sampled at 1/scale px: covariance R diag(sr^2, st^2) R^T."""
    R = np.array([[radial[0], -radial[1]], [radial[1], radial[0]]])
    inv = np.linalg.inv(scale**2 * R @ np.diag([sigma_r**2, sigma_t**2]) @ R.T)
    h = math.ceil(4 * scale * max(sigma_r, sigma_t))
    pts = np.stack(np.meshgrid(np.arange(-h, h + 1), np.arange(-h, h + 1)), -1).astype(float)
    k = np.exp(-0.5 * np.einsum("...i,ij,...j->...", pts, inv, pts))
    return (k / k.sum()).astype(np.float32)


def _markers(rng: np.random.Generator, blur: bool) -> np.ndarray:
    """Linear radiance of a white sheet with markers on the rings, area-sampled; with ``blur``
    each is blurred on the fine grid by TRUE_PSF at its centre (the local PSF)."""

    def local_psf(centre: np.ndarray) -> np.ndarray:
        theta_deg = np.degrees(LENS.theta_of_pixel(centre))
        sr, st = (float(v) for v in TRUE_PSF.at(theta_deg))
        radial = centre - [LENS.cx_px, LENS.cy_px]
        return _kernel(sr, st, radial / np.linalg.norm(radial), SUPERSAMPLE)

    placements = []
    for theta_deg, azimuths in RINGS:
        for az_deg in azimuths:
            t, a = math.radians(theta_deg), math.radians(az_deg + rng.uniform(-5, 5))
            ray = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
            placements.append((LENS.project(ray), rng.uniform(0, 90), len(placements)))
    shape = (LENS.height_px, LENS.width_px)
    return marker_sheet(
        shape, placements, SIDE_PX, (BLACK, WHITE), blur=local_psf if blur else None
    )


def _frames(blur: str, n: int, seed: int) -> list[np.ndarray]:
    """n frames (uint8) of differently placed markers: blurred on the supersampled grid, grey
    sRGB with a little noise; or recorded by the whole camera twin (PSF, Bayer, noise, MJPEG)."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        if blur == "supersampled":
            noisy = _markers(rng, blur=True) + rng.normal(
                0.0, 0.003, (LENS.height_px, LENS.width_px)
            )
            frames.append(_srgb_codes(noisy).astype(np.uint8))
        else:
            radiance = np.repeat(_markers(rng, blur=False)[..., None], 3, axis=-1)
            frames.append(record(radiance, dataclasses.replace(TWIN, psf=TRUE_PSF), rng)[0])
    return frames


def _write(folder: Path, frames: list[np.ndarray], suffix: str = ".png", params=()) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"frame{i:03d}{suffix}"), frame, list(params))
    return folder


# --- PSF ----------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("blur", ["supersampled", "camera_twin"])
def test_psf_measured_back_within_10_percent_per_bin(tmp_path, blur):
    """Through the twin, the blur its Bayer demosaicing and MJPEG add is taken off again."""
    footage = _write(tmp_path / "frames", _frames(blur, 2, seed=1))
    camera = PROFILE if blur == "supersampled" else TWIN
    profile, report = measure_lens(footage, camera, bin_deg=20.0)
    bins = [b for b in report["psf_bins"] if "sigma_radial_px" in b]
    assert [b["theta_lo_deg"] for b in bins] == [0.0, 20.0, 40.0, 60.0]
    for b in bins:
        assert b["mode"] == "anisotropic"
        truth_r, truth_t = TRUE_PSF.at(np.array(b["theta_mean_deg"]))
        assert b["sigma_radial_px"] == pytest.approx(float(truth_r), rel=0.10), b
        assert b["sigma_tangential_px"] == pytest.approx(float(truth_t), rel=0.10), b
    # The outer bins are clearly anisotropic, and the profile carries the measured table.
    assert bins[-1]["sigma_radial_px"] > 1.3 * bins[-1]["sigma_tangential_px"]
    assert profile.psf.theta_deg == tuple(b["theta_mean_deg"] for b in bins)
    assert profile.psf.sigma_radial_px == tuple(b["sigma_radial_px"] for b in bins)
    assert profile.sources["psf"].startswith(
        f"measured by whiskerbench lens measure from {footage}"
    )
    assert profile.sensor == camera.sensor  # two different frames: no still run, no noise fit
    assert "skipped" in report["noise"] and report["stream"]["codec"] == "none"  # PNG frames
    assert ("note" in report["processing_calibration"]) == (camera is PROFILE)
    if camera is TWIN:  # a sharp lens still gives wide edges through bilinear demosaicing
        assert report["processing_calibration"]["lens_variance_px2"][0] == 0.0
        assert report["processing_calibration"]["measured_variance_px2"][0] > 0.1


def test_processing_curve_is_inverted_and_extended_linearly():
    curve = {"lens_variance_px2": [0.0, 1.0, 4.0], "measured_variance_px2": [0.3, 1.3, 4.3]}
    measured = np.array([0.1, 0.3, 2.8, 5.3])  # below, at, inside and beyond the probed range
    np.testing.assert_allclose(lens_variance(measured, curve), measured - 0.3)
    unusable = {**curve, "note": "not usable"}
    np.testing.assert_array_equal(lens_variance(measured, unusable), measured)


# --- Photon transfer ----------------------------------------------------------------------------


def _still_frames(rng, signal, full_well_e, read_noise_e, n) -> list[np.ndarray]:
    """Linear 8-bit frames: Poisson electrons plus Gaussian read noise, full well = 255."""
    out = []
    for _ in range(n):
        electrons = rng.poisson(signal * full_well_e) + rng.normal(0, read_noise_e, signal.shape)
        out.append(np.clip(np.rint(electrons / full_well_e * 255), 0, 255).astype(np.uint8))
    return out


@pytest.mark.parametrize("full_well_e, read_noise_e", [(2000.0, 15.0), (800.0, 6.0)])
def test_photon_transfer_recovers_full_well_and_read_noise(full_well_e, read_noise_e):
    rng = np.random.default_rng(2)
    ramp = np.tile(np.linspace(0.01, 0.97, 320), (240, 1))
    moving = [rng.uniform(0, 1, ramp.shape) for _ in range(3)]  # a changing scene first
    frames = _still_frames(rng, moving[0], full_well_e, read_noise_e, 1)
    frames += _still_frames(rng, moving[1], full_well_e, read_noise_e, 1)
    frames += _still_frames(rng, ramp, full_well_e, read_noise_e, 10)
    ptc = PhotonTransfer(np.arange(256) / 255.0)
    for frame in frames:
        ptc.add(frame)
    result = ptc.result()
    assert result["runs_frames"] == [10]  # the changing frames are no still run
    assert result["full_well_e"] == pytest.approx(full_well_e, rel=0.10)
    assert result["read_noise_e"] == pytest.approx(read_noise_e, rel=0.10)


def test_photon_transfer_ignores_a_moving_object():
    rng = np.random.default_rng(5)
    ramp = np.tile(np.linspace(0.01, 0.97, 320), (240, 1))
    ptc = PhotonTransfer(np.arange(256) / 255.0)
    for i, frame in enumerate(_still_frames(rng, ramp, 2000.0, 15.0, 10)):
        frame[100:130, 20 + 10 * i : 50 + 10 * i] = 200  # a bright square crossing the scene
        ptc.add(frame)
    result = ptc.result()
    assert result["runs_frames"] == [10]
    assert result["full_well_e"] == pytest.approx(2000.0, rel=0.10)
    assert sum(b["moved_pixels"] for b in result["bins"]) > 0


def test_photon_transfer_skips_without_still_frames():
    rng = np.random.default_rng(3)
    ptc = PhotonTransfer(np.arange(256) / 255.0)
    for _ in range(6):
        ptc.add(rng.integers(0, 256, (50, 60), dtype=np.uint8))
    assert "still frames" in ptc.result()["skipped"]
    forced = PhotonTransfer(np.arange(256) / 255.0, all_still=True)
    for _ in range(6):
        forced.add(rng.integers(0, 256, (50, 60), dtype=np.uint8))
    assert forced.result()["runs_frames"] == [6]


# --- JPEG ---------------------------------------------------------------------------------------


def _colour_image(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (64, 96, 3), dtype=np.uint8), (0, 0), 1.5)


@pytest.mark.parametrize("quality", [50, 75, 90])
@pytest.mark.parametrize(
    "sampling, name",
    [
        (cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, "4:2:0"),
        (cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444, "4:4:4"),
    ],
)
def test_jpeg_quality_and_subsampling_read_back(tmp_path, quality, sampling, name):
    path = tmp_path / "frame.jpg"
    cv2.imwrite(
        str(path),
        _colour_image(),
        [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, sampling],
    )
    report = stream_report(path)
    assert (report["quality"], report["chroma_subsampling"]) == (quality, name)
    assert report["luma_match_mean_abs_error"] == 0.0 and report["chroma_quality"] == quality


def test_ijg_table_is_annex_k_at_quality_50_and_halved_at_75():
    assert ijg_table(50).tolist() == list(ANNEX_K_LUMA)
    assert ijg_table(75).tolist() == [(q * 50 + 50) // 100 for q in ANNEX_K_LUMA]


def test_first_jpeg_frame_found_inside_a_container(tmp_path):
    ok, jpeg = cv2.imencode(".jpg", _colour_image(1), [cv2.IMWRITE_JPEG_QUALITY, 60])
    junk = b"RIFF\x00\x00\x00\x00AVI LIST" + b"\xff\xd8\xff\x00 not a frame" + bytes(1000)
    path = tmp_path / "clip.avi"
    path.write_bytes(junk + jpeg.tobytes() + jpeg.tobytes())
    header = read_jpeg_header(path)
    assert header.offset == len(junk)
    assert stream_report(path)["quality"] == 60


def test_opencv_mjpeg_avi_is_read_and_flagged_when_not_ijg_scaled(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (96, 64))
    for seed in range(3):
        writer.write(_colour_image(seed))
    writer.release()
    report = stream_report(path)
    assert report["codec"] == "mjpeg" and report["chroma_subsampling"] == "4:2:0"
    # OpenCV's own MJPEG encoder does not use the IJG tables: the match error says so.
    assert report["ijg_scaled"] == (report["luma_match_mean_abs_error"] == 0.0)


def test_png_footage_has_no_stream(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), _colour_image())
    assert stream_report(tmp_path / "a.png")["codec"] == "none"


# --- Command line and bad input -----------------------------------------------------------------


def _cli(argv: list[str]) -> int:
    return main(argv)


@pytest.fixture(scope="module")
def still_marker_footage(tmp_path_factory) -> tuple[Path, Path, float, float]:
    """Five JPEG frames (q 95, 4:4:4) of one blurred marker scene with shot and read noise; and
    its camera file. Returns (footage, camera, full_well_e, read_noise_e)."""
    rng = np.random.default_rng(4)
    radiance = _markers(rng, blur=True)
    full_well_e, read_noise_e = 3000.0, 12.0
    frames = []
    for _ in range(5):
        electrons = rng.poisson(radiance * full_well_e) + rng.normal(
            0, read_noise_e, radiance.shape
        )
        grey = _srgb_codes(electrons / full_well_e).astype(np.uint8)
        frames.append(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))  # a colour stream, grey scene
    folder = tmp_path_factory.mktemp("still")
    params = (cv2.IMWRITE_JPEG_QUALITY, 95, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
              cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444)  # fmt: skip
    footage = _write(folder / "frames", frames, ".jpg", params)
    camera = folder / "camera.json"
    camera.write_text(json.dumps(PROFILE.to_json()))
    return footage, camera, full_well_e, read_noise_e


@pytest.mark.slow
def test_cli_writes_profile_and_report(tmp_path, still_marker_footage, capsys):
    footage, camera, full_well_e, _ = still_marker_footage
    out = tmp_path / "measured.json"
    assert _cli(["lens", "measure", str(footage), "--camera", str(camera), "--out", str(out),
                 "--bin-deg", "20"]) == 0  # fmt: skip
    assert "wrote" in capsys.readouterr().out
    report = json.loads((tmp_path / "measured.report.json").read_text())
    profile = CameraProfile.from_json(json.loads(out.read_text()))
    assert profile.psf.on and len(profile.psf.theta_deg) == 4
    assert report["noise"]["runs_frames"] == [5]
    assert profile.sensor.full_well_e == pytest.approx(full_well_e, rel=0.10)
    assert (profile.stream.codec, profile.stream.quality) == ("mjpeg", 95)
    assert profile.stream.chroma_subsampling == "4:4:4"
    for key in ("psf", "sensor.full_well_e", "sensor.read_noise_e", "stream"):
        assert profile.sources[key].startswith("measured by whiskerbench lens measure from")


@pytest.mark.slow
def test_mjpeg_video_footage_read_up_to_max_frames(tmp_path, still_marker_footage):
    footage = still_marker_footage[0]
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(
        str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15, (LENS.width_px, LENS.height_px)
    )
    for path in sorted(footage.iterdir())[:3]:
        writer.write(cv2.imread(str(path)))
    writer.release()
    profile, report = measure_lens(video, PROFILE, bin_deg=40.0, max_frames=2)
    assert report["frames_read"] == 2 and profile.psf.on
    assert report["stream"]["codec"] == "mjpeg" and profile.stream.codec == "mjpeg"
    assert "still frames" in report["noise"]["skipped"]  # 2 frames: no run of 5


@pytest.mark.slow
@pytest.mark.parametrize(
    "option, value, message",
    [
        ("--bin-deg", "0", "--bin-deg: 0.0: allowed range"),
        ("--max-frames", "0", "--max-frames: 0: allowed range"),
        ("--dictionary", "5x5_nope", "--dictionary:"),
        ("--camera", "no-such-profile", "--camera: 'no-such-profile' is neither"),
    ],
)
def test_bad_option_one_line_exit_2_nothing_written(
    tmp_path, still_marker_footage, capsys, option, value, message
):
    footage, camera, _, _ = still_marker_footage
    argv = ["lens", "measure", str(footage), "--camera", str(camera), "--out",
            str(tmp_path / "p.json"), option, value]  # fmt: skip
    assert _cli(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert list(tmp_path.iterdir()) == []


def test_footage_without_markers_says_so(tmp_path, capsys):
    blank = np.full((LENS.height_px, LENS.width_px), 200, np.uint8)
    footage = _write(tmp_path / "blank", [blank, blank, blank])
    with pytest.raises(
        FootageError, match=r"no usable marker edges in .*: 3 frames read, 0 markers"
    ):
        measure_lens(footage, PROFILE)
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps(PROFILE.to_json()))
    argv = ["lens", "measure", str(footage), "--camera", str(camera), "--out", str(tmp_path / "o")]
    assert _cli(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no usable marker edges" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["broken.avi", "broken.png"])
def test_unreadable_footage(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"this is not a video or an image")
    with pytest.raises(FootageError, match="not a readable"):
        measure_lens(path, PROFILE)


def test_frame_size_must_match_the_lens(tmp_path):
    footage = _write(tmp_path / "small", [np.zeros((100, 120), np.uint8)])
    with pytest.raises(
        FootageError, match="120 x 100 px but the camera profile's lens is 1296 x 972"
    ):
        measure_lens(footage, PROFILE)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"bin_deg": 0.1}, "bin_deg"),
        ({"max_frames": 0}, "max_frames"),
        ({"dictionary": "x"}, "dictionary"),
    ],
)
def test_bad_settings_name_their_field(tmp_path, kwargs, field):
    with pytest.raises(MeasureConfigError) as info:
        measure_lens(tmp_path, PROFILE, **kwargs)
    assert info.value.field == field


def test_parser_registers_lens_measure():
    parser = _Parser(prog="whiskerbench")
    add_lens_parser(parser.add_subparsers(dest="command", parser_class=_Parser), _Parser)
    args = parser.parse_args(["lens", "measure", "f.avi", "--camera", "c", "--out", "o.json"])
    assert (args.bin_deg, args.max_frames, args.dictionary, args.still) == (
        10.0,
        300,
        "4x4_50",
        False,
    )
    assert isinstance(args.footage, Path) and callable(args.func)
    assert isinstance(parser, argparse.ArgumentParser)


@pytest.mark.slow
def test_a_colour_sensors_photon_transfer_is_reported_not_written(still_marker_footage):
    """Demosaicing mixes photosites: the fit on the frames is not the sensor's noise."""
    footage = still_marker_footage[0]
    colour = dataclasses.replace(PROFILE, sensor=dataclasses.replace(PROFILE.sensor, cfa="RGGB"))
    profile, report = measure_lens(footage, colour, bin_deg=20.0)
    assert "full_well_e" in report["noise"] and "demosaiced" in report["noise"]["not_applied"]
    assert profile.sensor == colour.sensor

"""``whiskerbench camera show|project|import`` from the command line."""

import csv
import io
import json
import math

import pytest
import yaml
from test_calibration_import import kalibr_camchain
from test_lens_models import TUM_DS, tum

from bench.cli.main import main
from scenes.calibration_import import import_calibration
from scenes.camera import default_camera
from scenes.profile import CameraProfile, Sensor, load_profile


def run(argv: list[str]) -> int:
    """The ``whiskerbench`` command line, in-process."""
    return main(argv)


def write_profile(tmp_path, lens, **sections):
    path = tmp_path / "profile.json"
    path.write_text(json.dumps(CameraProfile(name="twin", lens=lens, **sections).to_json()))
    return path


def test_show_summarizes_lens_field_of_view_and_sections(tmp_path, capsys):
    lens = tum(TUM_DS, 118.0)
    path = write_profile(tmp_path, lens, sensor=Sensor(cfa="RGGB", full_well_e=7100.0))
    assert run(["camera", "show", str(path)]) == 0
    out = capsys.readouterr().out
    h, v, diag = lens.fov_in_image_deg()
    assert "profile: twin" in out
    assert "lens model: double_sphere (xi=-0.17213086 alpha=0.593117759)" in out
    assert "image size: 512 x 512 px" in out
    assert "model valid limit: 126.1200 deg" in out and "theta_max (image circle): 118.0000" in out
    assert f"horizontal {h:.2f} deg, vertical {v:.2f} deg, diagonal {diag:.2f} deg" in out
    assert "sensor: pixel_pitch_um 2.2, cfa RGGB, full_well_e 7100" in out
    for section in ("psf:", "lateral_colour:", "relative_illumination:", "stream:"):
        assert section in out


def test_project_prints_csv_of_the_equidistant_projection(tmp_path, capsys):
    lens = default_camera()
    path = write_profile(tmp_path, lens)
    argv = ["camera", "project", str(path), "--theta-deg", "0,30,60,90", "--azimuth-deg", "0,90"]
    assert run(argv) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(rows) == 8 and list(rows[0]) == ["theta_deg", "azimuth_deg", "x_px", "y_px"]
    for row in rows:
        t, a = math.radians(float(row["theta_deg"])), math.radians(float(row["azimuth_deg"]))
        # independent: equidistant radius f theta along the azimuth
        assert float(row["x_px"]) == pytest.approx(
            lens.cx_px + lens.fx_px * t * math.cos(a), abs=1e-5
        )
        assert float(row["y_px"]) == pytest.approx(
            lens.cy_px + lens.fy_px * t * math.sin(a), abs=1e-5
        )


@pytest.mark.parametrize(
    "extra, option",
    [(["--theta-deg", "30,96"], "--theta-deg: 96: allowed range is [0, 95]"),
     (["--theta-deg", "30", "--azimuth-deg", "400"], "--azimuth-deg: 400")],
)  # fmt: skip
def test_project_outside_the_image_circle_is_refused(tmp_path, capsys, extra, option):
    path = write_profile(tmp_path, default_camera())
    assert run(["camera", "project", str(path), *extra]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and option in captured.err and captured.err.count("\n") == 1


def test_unknown_camera_is_refused_naming_camera(tmp_path, capsys):
    assert run(["camera", "show", str(tmp_path / "none.json")]) == 2
    assert "error: CAMERA:" in capsys.readouterr().err


def test_import_writes_a_profile_that_loads_back_and_shows(tmp_path, capsys):
    calib, _ = kalibr_camchain(tmp_path)
    out = tmp_path / "profiles" / "tumvi.json"
    argv = ["camera", "import", str(calib), "--format", "kalibr", "--camera-index", "1"]
    assert run([*argv, "--out", str(out)]) == 0
    profile = load_profile(out)
    assert profile.name == "tumvi"
    assert profile.lens == import_calibration(calib, "kalibr", camera_index=1)
    assert str(calib) in profile.sources["lens"]
    capsys.readouterr()
    assert run(["camera", "show", str(out)]) == 0
    assert "lens model: eucm" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, expected",
    [
        (["--theta-max-deg", "130"], "--theta-max-deg: 130.0: the double_sphere model is valid up "
         "to 126.1200 deg"),
        (["--theta-max-deg", "1e-300"], "--theta-max-deg: 1e-300: the double_sphere model is "
         "valid up to 126.1200 deg, and a field under 1 deg off axis is no fisheye's; allowed "
         "range is [1, 126.1200]"),  # it wrote a profile with a 0-degree field before
        (["--theta-max-deg", "0.5"], "allowed range is [1, 126.1200]"),
        (["--theta-max-deg", "nan"], "--theta-max-deg: nan: "),
        (["--camera-index", "7"], "--camera-index: 7: no 'cam7'"),
        (["--format", "basalt"], "FILE: "),
    ],
)  # fmt: skip
def test_import_errors_name_the_option_and_write_nothing(tmp_path, capsys, extra, expected):
    calib, _ = kalibr_camchain(tmp_path)
    out = tmp_path / "camera.json"
    argv = ["camera", "import", str(calib), "--format", "kalibr", "--out", str(out), *extra]
    assert run(argv) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1
    assert not out.exists()


def test_import_of_a_malformed_file_names_the_file_and_field(tmp_path, capsys):
    calib, chain = kalibr_camchain(tmp_path)
    chain["cam0"]["intrinsics"] = [1.0]
    calib.write_text(yaml.safe_dump(chain))
    out = tmp_path / "camera.json"
    assert run(["camera", "import", str(calib), "--format", "kalibr", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"FILE: {calib}: cam0.intrinsics" in err and not out.exists()

"""Importers: calibration files written here in each tool's layout, with the TUM-VI numbers."""

import json
import math

import cv2
import numpy as np
import pytest
import yaml
from test_lens_models import (
    OCAM_AFFINE,
    OCAM_CENTRE,
    OCAM_POL,
    TUM_DS,
    TUM_EUCM,
    TUM_KB4,
    ocam_cam2world,
    random_directions,
    rays,
    tum,
)

from scenes.calibration_import import CalibrationError, import_calibration
from scenes.camera import FisheyeCamera

FX, FY, CX, CY = "fx_px", "fy_px", "cx_px", "cy_px"


def kalibr_camchain(tmp_path):
    """Kalibr's camchain layout (kalibr_common/ConfigReader.py): ds, eucm, pinhole-equidistant."""
    ds, eu, kb = TUM_DS, TUM_EUCM, TUM_KB4
    chain = {
        "cam0": {
            "camera_model": "ds",
            "intrinsics": [*ds["params"], ds[FX], ds[FY], ds[CX], ds[CY]],
            "distortion_model": "none",
            "distortion_coeffs": [],
            "resolution": [512, 512],
            "rostopic": "/cam0/image_raw",
        },
        "cam1": {
            "camera_model": "eucm",
            "intrinsics": [*eu["params"], eu[FX], eu[FY], eu[CX], eu[CY]],
            "distortion_model": "none",
            "distortion_coeffs": [],
            "resolution": [512, 512],
        },
        "cam2": {
            "camera_model": "pinhole",
            "intrinsics": [kb[FX], kb[FY], kb[CX], kb[CY]],
            "distortion_model": "equidistant",
            "distortion_coeffs": list(kb["params"]),
            "resolution": [512, 512],
        },
    }
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump(chain))
    return path, chain


def basalt_calib(tmp_path, intrinsics):
    """Basalt's calibration JSON layout (basalt data/tumvi_512_ds_calib.json)."""
    data = {
        "value0": {
            "T_imu_cam": [{"px": 0, "py": 0, "pz": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1}],
            "intrinsics": intrinsics,
            "resolution": [[512, 512]] * len(intrinsics),
            "vignette": [],
        }
    }
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(data, indent=4))
    return path


def basalt_entry(camera_type, lens, names, values=None):
    entry = {"fx": lens[FX], "fy": lens[FY], "cx": lens[CX], "cy": lens[CY]}
    entry.update(zip(names, values if values is not None else lens["params"], strict=True))
    return {"camera_type": camera_type, "intrinsics": entry}


def same_lens(a: FisheyeCamera, b: FisheyeCamera):
    assert a.model == b.model
    for name in ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px"):
        assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-12), name
    assert a.params == pytest.approx(b.params, rel=1e-12)


def farthest_corner_deg(lens: dict, n: int = 200001) -> float:
    """Independent: invert d(theta) on a dense grid at the farthest image corner's radius."""
    corners = np.array([[-0.5, -0.5], [511.5, -0.5], [-0.5, 511.5], [511.5, 511.5]])
    d = np.hypot((corners[:, 0] - lens[CX]) / lens[FX], (corners[:, 1] - lens[CY]) / lens[FY])
    probe = tum(lens, 90.0)
    theta = np.linspace(0.0, probe.theta_valid_max_rad, n)
    return math.degrees(np.interp(d.max(), probe.distort(theta), theta))


@pytest.mark.parametrize("index, lens", [(0, TUM_DS), (1, TUM_EUCM), (2, TUM_KB4)])
def test_kalibr_camchain_gives_the_published_cameras(tmp_path, index, lens):
    path, _ = kalibr_camchain(tmp_path)
    camera = import_calibration(path, "kalibr", camera_index=index)
    same_lens(camera, tum(lens))
    assert camera.theta_max_deg == pytest.approx(farthest_corner_deg(lens), abs=1e-3)
    assert import_calibration(path, "kalibr", index, theta_max_deg=100.0).theta_max_deg == 100.0


def test_basalt_json_gives_the_same_cameras_as_kalibr(tmp_path):
    path = basalt_calib(
        tmp_path,
        [
            basalt_entry("ds", TUM_DS, ("xi", "alpha")),
            basalt_entry("eucm", TUM_EUCM, ("alpha", "beta")),
            basalt_entry("kb4", TUM_KB4, ("k1", "k2", "k3", "k4")),
        ],
    )
    kalibr, _ = kalibr_camchain(tmp_path)
    for index in range(3):
        a = import_calibration(path, "basalt", camera_index=index)
        b = import_calibration(kalibr, "kalibr", camera_index=index)
        assert a == b


def test_basalt_ucm_is_kalibr_omni_and_eucm_with_beta_one(tmp_path):
    # Basalt's UCM with alpha is Basalt's EUCM with the same alpha and beta = 1 (same formula)
    alpha = TUM_EUCM["params"][0]
    basalt = basalt_calib(tmp_path, [basalt_entry("ucm", TUM_EUCM, ("alpha",), (alpha,))])
    ucm = import_calibration(basalt, "basalt", theta_max_deg=110.0)
    eucm = tum({**TUM_EUCM, "params": (alpha, 1.0)}, 110.0)
    dirs = random_directions(5000, math.radians(110.0), seed=7)
    assert np.abs(ucm.project(dirs) - eucm.project(dirs)).max() < 1e-9
    # Kalibr's omni is Mei's form: xi = alpha / (1 - alpha), focal f / (1 - alpha)
    xi, f = alpha / (1 - alpha), np.array([TUM_EUCM[FX], TUM_EUCM[FY]]) / (1 - alpha)
    chain = {
        "cam0": {
            "camera_model": "omni",
            "intrinsics": [xi, *f.tolist(), TUM_EUCM[CX], TUM_EUCM[CY]],
            "distortion_model": "none",
            "distortion_coeffs": [],
            "resolution": [512, 512],
        }
    }
    kalibr = tmp_path / "omni.yaml"
    kalibr.write_text(yaml.safe_dump(chain))
    omni = import_calibration(kalibr, "kalibr", theta_max_deg=110.0)
    assert np.abs(omni.project(dirs) - eucm.project(dirs)).max() < 1e-9


def ocam_text(pol, centre, affine, size_hw, invpol=(1.0, 2.0, 3.0)):
    """calib_results.txt as OCamCalib's export_data.m writes it."""
    return (
        "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). "
        "These are used by cam2world\n\n"
        f"{len(pol)} {' '.join(f'{a:e}' for a in pol)} \n\n"
        "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in "
        "MATLAB). These are used by world2cam\n\n"
        f"{len(invpol)} {' '.join(f'{a:f}' for a in invpol)} \n\n"
        '#center: "row" and "column", starting from 0 (C convention)\n\n'
        f"{centre[0]:f} {centre[1]:f}\n\n"
        '#affine parameters "c", "d", "e"\n\n'
        f"{affine[0]:f} {affine[1]:f} {affine[2]:f}\n\n"
        '#image size: "height" and "width"\n\n'
        f"{size_hw[0]} {size_hw[1]}\n\n"
    )


def test_ocamcalib_file_matches_its_cam2world_with_rows_and_columns(tmp_path):
    path = tmp_path / "calib_results.txt"
    path.write_text(ocam_text(OCAM_POL, OCAM_CENTRE, OCAM_AFFINE, (480, 752)))
    camera = import_calibration(path, "ocamcalib", theta_max_deg=170.0)
    assert (camera.width_px, camera.height_px) == (752, 480)
    rng = np.random.default_rng(8)
    pixels = rng.uniform(-0.5, [751.5, 479.5], (5000, 2))
    dirs, _ = camera.unproject(pixels)
    ref = ocam_cam2world(pixels[:, 1], pixels[:, 0], OCAM_POL, *OCAM_CENTRE, *OCAM_AFFINE)
    assert np.abs(dirs - np.stack([ref[:, 1], ref[:, 0], -ref[:, 2]], -1)).max() < 1e-12


def test_ocamcalib_fit_of_the_tum_vi_lens_lands_within_a_pixel_of_it(tmp_path):
    # OCamCalib's polynomial (a1 = 0) fitted here to the published Kannala-Brandt form
    kb = tum(TUM_KB4)
    theta = np.linspace(0.01, math.radians(115.0), 400)
    rho = kb.fx_px * kb.distort(theta)
    basis = np.stack([rho**j for j in (0, 2, 3, 4, 5)], axis=-1)
    a0, *rest = np.linalg.lstsq(basis, -rho / np.tan(theta), rcond=None)[0]
    pol = (a0, 0.0, *rest)
    centre = (TUM_KB4[CY], TUM_KB4[CX])  # row, column
    path = tmp_path / "calib_results.txt"
    path.write_text(ocam_text(pol, centre, (kb.fy_px / kb.fx_px, 0.0, 0.0), (512, 512)))
    camera = import_calibration(path, "ocamcalib", theta_max_deg=95.0)
    for azimuth in (0.0, 45.0, 90.0, 180.0):
        r = rays(np.radians(np.arange(0.0, 95.5, 0.5)), np.full(191, math.radians(azimuth)))
        assert np.abs(camera.project(r) - kb.project(r)).max() < 1.0


def write_opencv_storage(path, K, D, size):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", size[0])
    fs.write("image_height", size[1])
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(4, 1))
    fs.release()


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_opencv_filestorage_files_give_the_exact_kannala_brandt_camera(tmp_path, suffix):
    expected = tum(TUM_KB4, 100.0)
    cv = expected.to_opencv()
    path = tmp_path / f"fisheye{suffix}"
    write_opencv_storage(path, cv["K"], cv["D"], cv["size"])
    assert import_calibration(path, "opencv", theta_max_deg=100.0) == expected


def test_opencv_plain_json_and_ros_camera_info(tmp_path):
    expected = tum(TUM_KB4, 100.0)
    cv = expected.to_opencv()
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"K": cv["K"].tolist(), "D": cv["D"].tolist(), "size": [512, 512]}))
    assert import_calibration(plain, "opencv", theta_max_deg=100.0) == expected
    ros = tmp_path / "camera_info.yaml"
    ros.write_text(
        yaml.safe_dump(
            {
                "image_width": 512,
                "image_height": 512,
                "distortion_model": "equidistant",
                "camera_matrix": {"rows": 3, "cols": 3, "data": cv["K"].ravel().tolist()},
                "distortion_coefficients": {"rows": 1, "cols": 4, "data": cv["D"].tolist()},
            }
        )
    )
    assert import_calibration(ros, "opencv", theta_max_deg=100.0) == expected


def test_theta_max_beyond_the_model_limit_is_refused_with_the_limit(tmp_path):
    path, _ = kalibr_camchain(tmp_path)
    with pytest.raises(CalibrationError, match=r"theta_max_deg: 130.*126\.1200 deg"):
        import_calibration(path, "kalibr", camera_index=0, theta_max_deg=130.0)


def _edit(chain, key, value):
    chain = json.loads(json.dumps(chain))
    if value is None:
        del chain["cam0"][key]
    else:
        chain["cam0"][key] = value
    return chain


@pytest.mark.parametrize(
    "key, value, field",
    [
        ("intrinsics", [1.0, 2.0], "cam0.intrinsics"),
        ("intrinsics", None, "cam0.intrinsics: missing"),
        ("camera_model", "omni", "cam0.intrinsics"),  # omni needs 5 intrinsics
        ("distortion_model", "radtan", "ds-radtan is not supported"),
        ("resolution", [512], "cam0.resolution"),
        ("intrinsics", [1.5, 0.5, 158.0, 158.0, 255.0, 255.0], "xi"),  # xi outside (-1, 1)
    ],
)
def test_malformed_kalibr_files_name_the_file_and_field(tmp_path, key, value, field):
    path, chain = kalibr_camchain(tmp_path)
    path.write_text(yaml.safe_dump(_edit(chain, key, value)))
    with pytest.raises(ValueError, match=field) as info:
        import_calibration(path, "kalibr")
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_kalibr_omni_radtan_is_refused_naming_the_model(tmp_path):
    path, chain = kalibr_camchain(tmp_path)
    chain = _edit(_edit(chain, "camera_model", "omni"), "distortion_model", "radtan")
    path.write_text(yaml.safe_dump(chain))
    with pytest.raises(CalibrationError, match="omni-radtan is not supported"):
        import_calibration(path, "kalibr")


@pytest.mark.parametrize(
    "fmt, text, field",
    [
        ("basalt", '{"value0": {"intrinsics": [{"camera_type": "fov"}], "resolution": [[9, 9]]}}',
         "camera_type"),
        ("basalt", '{"value0": {"intrinsics": []}}', "value0.intrinsics"),
        ("basalt", "{not json", "not valid JSON"),
        ("kalibr", "cam0: [unclosed", "not valid YAML"),
        ("ocamcalib", "# only a comment\n5 -200 0 1e-3\n", "polynomial"),
        ("ocamcalib", "2 -200 0\n1 3.0\n240 320\n1 0 0\n480\n", "image size"),
        ("ocamcalib", "2 200 0\n1 3.0\n240 320\n1 0 0\n480 640\n", "a0"),
        ("opencv", '{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "D": [0, 0, 0, 0, 0], "size": [9, 9]}',
         "D"),
        ("opencv", '{"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "D": [0, 0, 0, 0]}', "size"),
        ("opencv", "distortion_model: plumb_bob\nK: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
         "D: [0, 0, 0, 0]\nsize: [9, 9]\n", "plumb_bob"),
    ],
)  # fmt: skip
def test_malformed_files_of_every_format_name_the_file_and_field(tmp_path, fmt, text, field):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=field) as info:
        import_calibration(path, fmt)
    assert str(path) in str(info.value)


def test_camera_index_beyond_the_file_and_oversized_files_are_refused(tmp_path):
    path, _ = kalibr_camchain(tmp_path)
    with pytest.raises(CalibrationError, match="camera_index: 5.*cam0, cam1, cam2"):
        import_calibration(path, "kalibr", camera_index=5)
    with pytest.raises(CalibrationError, match="camera_index"):
        import_calibration(path, "opencv", camera_index=1)
    big = tmp_path / "big.yaml"
    big.write_bytes(b"#" * ((1 << 20) + 1))
    with pytest.raises(CalibrationError, match="larger than"):
        import_calibration(big, "kalibr")
    with pytest.raises(CalibrationError, match="format"):
        import_calibration(path, "colmap")

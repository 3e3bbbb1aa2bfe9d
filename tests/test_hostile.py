"""Hostile input, table-driven: every command answers a bad option or file with exit code 2 and
one line naming the culprit, and writes nothing; a bug gives a short report and exit code 1;
Ctrl-C gives exit code 130 and says what is kept.

Every case runs ``main(argv)`` in this process; validation happens before any work, so nothing
here renders (the doctored-dataset cases copy the session's rendered pair).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.cli.main import main
from renderers.variant import gpu_present
from scenes.profile import CameraProfile

pytestmark = pytest.mark.usefixtures("figures_not_drawn")  # answers, not figures

PROFILE = CameraProfile().to_json()


def _profile(**changes) -> str:
    data = json.loads(json.dumps(PROFILE))
    for dotted, value in changes.items():
        *path, key = dotted.split("__")
        node = data
        for part in path:
            node = node[part]
        node[key] = value
    return json.dumps(data)


#: Hostile files: name -> content (bytes or text); a name ending in "/" is a folder.
FILES: dict[str, str | bytes] = {
    "empty.json": "",
    "trunc.json": '{"format": "whiskerbench-camera-profile", "vers',
    "binary.json": bytes(range(256)) * 8,
    "list.json": "[1, 2, 3]",
    "huge.json": " " * (2 << 20),
    "folder.json/": "",
    "nolens.json": '{"format": "whiskerbench-camera-profile", "version": 1}',
    "strlens.json": '{"format": "whiskerbench-camera-profile", "version": 1, "lens": "x"}',
    "bare.json": '{"model": {}}',
    "version9.json": _profile(version=9),
    "unknown.json": _profile(colour="red"),
    "nanpsf.json": _profile(psf__sigma_radial_px=[float("nan")]),
    "quality0.json": _profile(stream__quality=0),
    "giant.json": _profile(
        lens__model__width_px=10**9, lens__model__height_px=10**9, lens__model__cx_px=5e8
    ),
    "cal_empty.yaml": "",
    "cal_binary.yaml": b"\x00\xff" * 100,
    "cal_list.yaml": "- 1\n- 2\n",
    "cal_trunc.json": '{"value0": {"intrinsics": [',
    "cal_ocam.txt": "#pol\n5 1 2\n",
    "cal_nan.yaml": "cam0:\n  camera_model: pinhole\n  intrinsics: [.nan, 1, 2, 3]\n"
    "  distortion_model: equidistant\n  distortion_coeffs: [0, 0, 0, 0]\n"
    "  resolution: [640, 480]\n",
    "cal_opencv.yaml": "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n"
    "  dt: d\n  data: [1, 0, 0]\n",
    "notavideo.mp4": "not a video",
    "empty.mp4": b"",
    "afile": "a plain file",
    "nodataset/": "",
}


@pytest.fixture(scope="module")
def fx(tmp_path_factory) -> Path:
    """The hostile files, a small camera (64 x 48 px) and a 20-frame black video that fits it:
    a video in which no marker is ever seen."""
    from bench.common.video import write_video

    folder = tmp_path_factory.mktemp("hostile")
    for name, content in FILES.items():
        if name.endswith("/"):
            (folder / name).mkdir()
        elif isinstance(content, bytes):
            (folder / name).write_bytes(content)
        else:
            (folder / name).write_text(content)
    lens = CameraProfile().lens.to_dict()["model"]
    lens.update(width_px=64, height_px=48, cx_px=31.5, cy_px=23.5, fx_px=15.0, fy_px=15.0)
    (folder / "small.json").write_text(json.dumps({"model": lens}))
    write_video(folder / "black.mp4", (np.zeros((48, 64), np.uint8) for _ in range(20)), 15.0)
    return folder


# (argv, regex the single stderr line must match: it names the option or the file)
S = "detectability"
BIG = "9" * 400  # an integer no float holds
CASES: list[tuple[str, str]] = [
    # --- detectability: lists, numbers, names, files, outputs
    (f"{S} --sizes=", r"--sizes.*at least one"),
    (f"{S} --sizes=8.8,8.8", r"--sizes.*twice"),
    (f"{S} --sizes=nan", r"--sizes.*finite"),
    (f"{S} --sizes=1e308", r"--sizes.*distance"),
    (f"{S} --alphas=,,", r"--alphas.*at least one"),
    (f"{S} --alphas=0,0", r"--alphas.*twice"),
    (f"{S} --alphas=500", r"--alphas.*theta_max"),
    (f"{S} --phis=10,10", r"--phis.*twice"),
    (f"{S} --phis=inf", r"--phis.*finite"),
    (f"{S} --images=-5", r"--images.*1\.\.800"),
    (f"{S} --images=100000", r"--images.*1\.\.800"),
    (f"{S} --images=1.5", r"--images.*invalid int"),
    (f"{S} --distance=nan", r"--distance.*allowed range"),
    (f"{S} --distance=1e300", r"--distance.*10000"),
    (f"{S} --lighting=", r"--lighting.*at least one"),
    (f"{S} --lighting sun sun", r"--lighting.*twice"),
    (f"{S} --lighting=sun,fog", r"--lighting.*fog"),
    (f"{S} --dictionary=nan", r"--dictionary.*unknown"),
    (f"{S} --seed=-1", r"--seed.*0\.\.4294967295"),
    (f"{S} --seed=99999999999999999999", r"--seed.*0\.\.4294967295"),
    (f"{S} --seed=one", r"--seed.*not an integer"),
    (f"{S} --spp=0", r"--spp.*>= 1"),
    (f"{S} --spp=100000000", r"--spp.*would take.*limit \d+"),
    (f"{S} --workers=0", r"--workers.*>= 1"),
    (f"{S} --workers=1000000", r"--workers.*GiB; limit \d+ \(memory budget"),
    (f"{S} --psf-scale=1,1", r"--psf-scale.*twice"),
    (f"{S} --psf-scale=-1", r"--psf-scale.*0\.\.10"),
    (f"{S} --psf-scale=0.5,0.75", r"--psf-scale.*needs 1"),
    (f"{S} --cell-px=1000000", r"--cell-px.*2\.\.32"),
    (f"{S} --exposure=nan", r"--exposure.*allowed range"),
    (f"{S} --exposure=-1", r"--exposure.*allowed range"),
    (f"{S} --variant=cpu", r"--variant.*invalid choice"),
    (f"{S} --camera=nosuch", r"--camera.*neither a shipped profile"),
    (f"{S} --camera={{fx}}/empty.json", r"--camera.*empty\.json: not valid JSON"),
    (f"{S} --camera={{fx}}/trunc.json", r"--camera.*trunc\.json: not valid JSON"),
    (f"{S} --camera={{fx}}/binary.json", r"--camera.*binary\.json: not valid JSON"),
    (f"{S} --camera={{fx}}/list.json", r"--camera.*must be a JSON object"),
    (f"{S} --camera={{fx}}/huge.json", r"--camera.*huge\.json: larger than"),
    (f"{S} --camera={{fx}}/folder.json", r"--camera.*folder\.json.*neither"),
    (f"{S} --camera={{fx}}/nolens.json", r"--camera: lens: missing"),
    (f"{S} --camera={{fx}}/strlens.json", r"--camera: lens: must be a JSON object"),
    (f"{S} --camera={{fx}}/bare.json", r"--camera: lens:.*lacks"),
    (f"{S} --camera={{fx}}/version9.json", r"--camera: version: 9"),
    (f"{S} --camera={{fx}}/unknown.json", r"--camera: colour: unknown field"),
    (f"{S} --camera={{fx}}/nanpsf.json", r"--camera: psf\.sigma_radial_px: nan"),
    (f"{S} --camera={{fx}}/quality0.json", r"--camera: stream\.quality: 0"),
    (f"{S} --camera={{fx}}/giant.json", r"--camera.*px frame would need.*limit"),
    ("detectability --out={fx}/afile", r"--out:.*afile: is a file"),
    ("detectability --out={fx}/afile/run", r"--out:.*not writable"),
    ("detectability --out=", r"--out: must name a folder"),
    # --- bench detectability / dataset / pipeline
    ("bench detectability --full-frame-cells=0", r"--full-frame-cells.*1\.\.256"),
    ("bench detectability --full-frame-cells=100000", r"--full-frame-cells.*1\.\.256"),
    ("bench detectability --sizes=1,1", r"--sizes.*twice"),
    ("bench detectability --workers=-3", r"--workers.*>= 1"),
    ("bench dataset --frames=0", r"--frames.*>= 1"),
    ("bench dataset --frames=100000000", r"--frames.*GiB; limit \d+"),
    ("bench dataset --foliage=soft,soft", r"--foliage.*twice"),
    ("bench dataset --out={fx}/afile", r"--out:.*is a file"),
    ("bench pipeline --frames=1", r"--frames.*>= 2"),
    ("bench pipeline --frames=100000000", r"--frames.*GiB; limit \d+"),
    ("bench pipeline --pipelines=", r"--pipelines.*at least one"),
    ("bench pipeline --pipelines=paper,paper", r"--pipelines.*twice"),
    ("bench pipeline --pipelines=nan", r"--pipelines.*unknown preset 'nan'"),
    ("bench pipeline --pipelines=paper/refine=nan", r"--pipelines.*refine=nan"),
    ("bench pipeline --pipelines=paper/constant=nan", r"--pipelines.*constant=nan.*-255"),
    ("bench pipeline --pipelines=paper/cell=nan", r"--pipelines.*cell=nan.*not an integer"),
    ("bench pipeline --pipelines=paper/window=3-100000-1", r"--pipelines.*window.*1001"),
    ("bench pipeline --pipelines=paper/window=3-999-1", r"--pipelines.*windows: at most"),
    ("bench pipeline --pipelines=paper/margin=-5", r"--pipelines.*margin=-5"),
    ("bench pipeline --pipelines=paper/refine", r"--pipelines.*not CHOICE=VALUE"),
    ("bench pipeline --variant=nosuch", r"--variant.*invalid choice"),
    ("bench pipeline --out={fx}/afile", r"--out:.*is a file"),
    ("bench render --spp=0", r"--spp.*>= 1"),
    ("bench render --spp=nan", r"--spp.*invalid integer value"),
    ("bench render --spp=100000000", r"--spp.*GiB; limit \d+"),
    ("bench render --threads=0", r"--threads.*allowed range is 1\.\.\d+"),
    ("bench render --threads=100000", r"--threads.*allowed range is 1\.\.\d+"),
    ("bench render --scene=foliage", r"--scene.*invalid choice"),
    ("bench render --scene=array --spp=1000", r"--spp.*every ray of a full frame.*GiB; limit \d+"),
    ("bench render --variant=nosuch", r"--variant.*invalid choice"),
    ("bench render --out={fx}/afile", r"--out:.*is a file"),
    ("bench loader {fx}/nosuch", r"DATASET: .*nosuch: not a dataset folder"),
    ("bench loader {fx}/afile", r"DATASET: .*afile: not a dataset folder"),
    ("bench loader {fx}/nodataset", r"DATASET: .*nodataset/manifest\.json: missing"),
    ("bench loader {fx}/nodataset --repeats=0", r"--repeats: 0: must be >= 1"),
    ("bench loader {fx}/nodataset --random-frames=-1", r"--random-frames: -1: must be >= 0"),
    # --- bench scale
    ("bench scale --executors=", r"--executors.*at least one"),
    ("bench scale --executors=pool,pool", r"--executors.*twice"),
    ("bench scale --executors=mpi", r"--executors: unknown 'mpi'; choose from inline, pool, dask"),
    ("bench scale --workers-max=0", r"--workers-max: 0: must be >= 1"),
    ("bench scale --workers-max=100000", r"--workers-max.*limit \d+"),
    ("bench scale --workers-max=two", r"--workers-max.*invalid int"),
    ("bench scale --variant=nosuch", r"--variant.*invalid choice"),
    ("bench scale --out={fx}/afile", r"--out:.*is a file"),
    # --- bench targets
    ("bench targets --out={fx}/afile", r"--out:.*is a file"),
    ("bench targets --out=", r"--out: must name a folder"),
    ("bench targets --quick=yes", r"--quick.*ignored explicit argument"),
    # --- dataset
    ("dataset --foliage=", r"--foliage.*at least one"),
    ("dataset --foliage=soft,soft", r"--foliage.*twice"),
    ("dataset --foliage=moss", r"--foliage.*moss"),
    ("dataset --distance=close,close", r"--distance.*twice"),
    ("dataset --branches=", r"--branches.*at least one"),
    ("dataset --branches=0,0", r"--branches.*twice"),
    ("dataset --branches=0+50,50+0", r"--branches.*twice"),
    ("dataset --branches=0+nan", r"--branches.*not finite"),
    ("dataset --branches=1e9", r"--branches.*out of reach"),
    ("dataset --branches=1e308", r"--branches.*1e\+308 mm is out of reach"),  # no overflow
    # the option that was changed is named, not the default it collides with
    ("dataset --amplitude=0.001", r"--amplitude: branch at x = 50 mm .*0\.001 mm sweep"),
    (f"{S} --distance=5", r"--distance: 5: closer than the largest marker, 17\.6 mm"),
    (f"{S} --distance=5 --sizes=8", r"--sizes: 8: larger than the 5 mm distance"),
    ("dataset --protocol=", r"--protocol.*at least one"),
    ("dataset --lighting=sun,sun", r"--lighting.*twice"),
    ("dataset --frames-step=0", r"--frames-step.*>= 1"),
    ("dataset --mechanics=springy", r"--mechanics.*'springy'.*dynamic, quasi-static"),
    # integers and numbers beyond floats (the limits weigh options in floats)
    (f"dataset --workers={BIG}", r"--workers: an integer of 400 digits: at most 9007199254740992"),
    (f"dataset --frames-step={BIG}", r"--frames-step: an integer of 400 digits"),
    (f"dataset --spp={BIG}", r"--spp: an integer of 400 digits"),
    (f"dataset --subframes=-{BIG}", r"--subframes: an integer of 400 digits"),
    (f"{S} --spp={BIG}", r"--spp: an integer of 400 digits"),
    (f"score {{fx}}/nodataset --workers={BIG}", r"--workers: an integer of 400 digits"),
    (f"compare {{fx}}/nodataset --seeds={BIG}", r"--seeds: an integer of 400 digits"),
    ("dataset --passes=2000000000", r"--passes: must be an integer 1\.\.1000000000"),
    ("dataset --speed=1e-320", r"--speed: .*inf frames.*lowest allowed about 0\.0\d+"),
    ("dataset --speed=1e-100", r"--speed: .*lowest allowed about 0\.0\d+"),
    (f"dataset --camera={BIG}", r"--camera: 9{40}\.\.\.: File name too long"),
    (f"{S} --camera={BIG}", r"--camera: 9{40}\.\.\.: File name too long"),
    (  # a path a command builds from the name it was given: still the argument's fault
        f"camera calibrate prototype --param=psf_scale --observations={BIG} --out={{out}}",
        r"9{40}.*File name too long \(ENAMETOOLONG\)",
    ),
    ("dataset --foliage-detail=ultra", r"--foliage-detail.*'ultra'.*coarse, default, fine"),
    ("dataset --integrator=whitted", r"--integrator.*'whitted'"),
    ("dataset --integrator=path --path-depth=9", r"--path-depth.*1\.\.8"),
    ("dataset --frames-step=100000000", r"--frames-step.*allowed range is 1\.\.\d+"),
    ("dataset --speed=nan", r"--speed.*finite"),
    ("dataset --speed=1e-9", r"--speed.*GiB.*lowest allowed"),
    ("dataset --amplitude=1e9", r"--amplitude.*\(0, 1000\]"),
    ("dataset --passes=0", r"--passes.*1\.\.1000000000"),
    ("dataset --passes=1000000", r"--passes.*GiB.*limit about"),
    ("dataset --passes=800", r"--passes: 800: .*would take .*days.*limit \d+"),  # not --spp
    ("dataset --fps=1e9", r"--fps: 1e\+09: one frame lasts 1e-06 ms, shorter than the default"),
    ("dataset --fps=1e9 --exposure-ms=8", r"--exposure-ms.*one frame"),
    ("dataset --exposure-ms=nan", r"--exposure-ms"),
    ("dataset --spp=100000000", r"--spp.*would take.*limit \d+"),
    ("dataset --subframes=0", r"--subframes.*>= 1"),
    ("dataset --subframes=100000000", r"--subframes.*GiB.*limit \d+"),
    ("dataset --seed=-1", r"--seed.*0\.\."),
    ("dataset --workers=0", r"--workers.*>= 1"),
    ("dataset --workers=100000", r"--workers.*limit \d+"),
    ("dataset --camera={fx}/trunc.json", r"--camera.*not valid JSON"),
    ("dataset --out={fx}/afile", r"--out:.*is a file"),
    ("dataset --camera={fx}/giant.json", r"--camera.*px frame would need.*limit"),
    ("bench detectability --camera={fx}/giant.json", r"--camera.*px frame"),
    # --- detect
    ("detect {fx}/black.mp4 --camera=ideal --out={fx}/afile", r"--out:.*is a file"),
    ("detect {fx}/nosuch.mp4 --camera=ideal", r"nosuch\.mp4: no such file"),
    ("detect {fx} --camera=ideal", r"hostile\d*: is a folder"),
    ("detect {fx}/notavideo.mp4 --camera=ideal", r"notavideo\.mp4: not a readable video"),
    ("detect {fx}/empty.mp4 --camera=ideal", r"empty\.mp4: not a readable video"),
    ("detect {fx}/black.mp4 --camera=ideal", r"black\.mp4: frame 0 is 64x48 px"),
    ("detect {fx}/black.mp4 --camera={fx}/small.json", r"black\.mp4: no marker seen"),
    ("detect {fx}/black.mp4 --camera={fx}/trunc.json", r"--camera.*not valid JSON"),
    ("detect {fx}/black.mp4 --camera=ideal --foliage-threshold=nan", r"--foliage-threshold"),
    ("detect {fx}/black.mp4 --camera=ideal --foliage-threshold=inf", r"--foliage-threshold"),
    ("detect {fx}/black.mp4 --camera=ideal --foliage-threshold=1e308", r"0 \.\. 1000 mm"),
    ("detect {fx}/black.mp4 --camera=ideal --pipeline=paper/aruco3=maybe", r"--pipeline.*aruco3"),
    # --- score and compare: folders that are not datasets
    ("score {fx}/nosuch", r"nosuch: not a dataset folder"),
    ("score {fx}/afile", r"afile: not a dataset folder"),
    ("score {fx}/nodataset", r"manifest\.json: no dataset manifest"),
    ("score {fx}/nodataset --out={fx}/afile", r"--out:.*is a file"),
    ("score {fx}/nodataset --pipeline=bogus", r"--pipeline.*unknown preset"),
    ("compare {fx}/nosuch", r"nosuch: not a dataset folder"),
    ("compare {fx}/nodataset", r"manifest\.json: no dataset manifest"),
    ("compare {fx}/nodataset --out={fx}/afile", r"--out:.*is a file"),
    ("compare {fx}/nodataset --seeds=3", r"--seeds: 3: must be >= 5"),
    ("compare {fx}/nodataset --seeds=100000000", r"--seeds.*would take.*limit \d+"),
    ("compare {fx}/nodataset --pipelines=fast,fast", r"--pipelines.*twice"),
    ("compare {fx}/nodataset --variant=gpu", r"--variant.*invalid choice"),
    # --- executors: a bad or unreachable Dask scheduler is refused before any work
    (f"{S} --executor=threads", r"--executor.*invalid choice"),
    (f"{S} --scheduler=localhost:8786", r"--scheduler.*must be tcp://HOST:PORT"),
    (f"{S} --scheduler=tcp://host:99999", r"--scheduler.*PORT in 1\.\.65535"),
    (f"{S} --executor=pool --scheduler=tcp://127.0.0.1:1", r"--scheduler.*--executor dask"),
    ("dataset --executor=inline --scheduler=tcp://127.0.0.1:1", r"--scheduler.*--executor dask"),
    ("dataset --scheduler=tcp://127.0.0.1:1", r"--scheduler.*no scheduler answers"),
    ("dataset --executor=inline --workers=4", r"--workers: 4: --executor inline runs one task"),
    (f"{S} --executor=inline --workers=2", r"--workers: 2: --executor inline runs one task"),
    ("score {fx}/nodataset --scheduler=tcp://127.0.0.1:1", r"--scheduler.*no scheduler"),
    ("score {fx}/nodataset --workers=0", r"--workers.*>= 1"),
    ("compare {fx}/nodataset --scheduler=http://127.0.0.1:1", r"--scheduler.*tcp://HOST:PORT"),
    ("compare {fx}/nodataset --workers=100000", r"--workers.*limit \d+"),
    # --- camera
    ("camera show nosuch", r"CAMERA.*neither a shipped profile"),
    ("camera show {fx}/binary.json", r"CAMERA.*not valid JSON"),
    ("camera show {fx}/folder.json", r"CAMERA.*neither"),
    ("camera project ideal --theta-deg=", r"--theta-deg.*at least one"),
    ("camera project ideal --theta-deg=10,10", r"--theta-deg.*twice"),
    ("camera project ideal --theta-deg=nan", r"--theta-deg.*finite"),
    ("camera project ideal --theta-deg=1000", r"--theta-deg.*image circle"),
    ("camera project ideal --theta-deg=10 --azimuth-deg=0,0", r"--azimuth-deg.*twice"),
    ("camera project ideal --theta-deg=10 --azimuth-deg=720", r"--azimuth-deg.*-360, 360"),
    ("camera import {fx}/cal_empty.yaml --format=kalibr --out={out}.json", r"FILE"),
    ("camera import {fx}/cal_binary.yaml --format=kalibr --out={out}.json", r"FILE.*UTF-8"),
    ("camera import {fx}/cal_list.yaml --format=kalibr --out={out}.json", r"FILE"),
    ("camera import {fx}/cal_trunc.json --format=basalt --out={out}.json", r"FILE.*JSON"),
    ("camera import {fx}/cal_ocam.txt --format=ocamcalib --out={out}.json", r"FILE"),
    ("camera import {fx}/cal_nan.yaml --format=kalibr --out={out}.json", r"FILE.*intrinsics"),
    ("camera import {fx}/cal_opencv.yaml --format=opencv --out={out}.json", r"FILE"),
    ("camera import {fx}/nosuch.yaml --format=kalibr --out={out}.json", r"FILE.*not a readable"),
    ("camera import {fx}/folder.json --format=basalt --out={out}.json", r"FILE.*not a readable"),
    ("camera import {fx}/cal_nan.yaml --format=matlab --out={out}.json", r"--format.*choice"),
    (
        "camera import {fx}/cal_nan.yaml --format=kalibr --camera-index=-1 --out={out}.json",
        r"--camera-index",
    ),  # fmt: skip
    ("camera import {fx}/cal_nan.yaml --format=kalibr --out={fx}/folder.json", r"--out.*folder"),
    ("camera import {fx}/cal_nan.yaml --format=kalibr --out={fx}/afile/p.json", r"--out.*not wr"),
    ("camera import {fx}/cal_nan.yaml --format=kalibr --out={out}.json --name=", r"--name"),
    # --- lens measure
    ("lens measure {fx}/black.mp4 --camera=ideal --out={out}.json --bin-deg=nan", r"--bin-deg"),
    ("lens measure {fx}/black.mp4 --camera=ideal --out={out}.json --max-frames=0", r"--max-fr"),
    (
        "lens measure {fx}/black.mp4 --camera=ideal --out={out}.json --max-frames=1000000000",
        r"--max-frames.*1\.\.100000",
    ),  # fmt: skip
    ("lens measure {fx}/black.mp4 --camera=ideal --out={out}.json --dictionary=x", r"--dictionary"),
    ("lens measure {fx}/black.mp4 --camera=nosuch --out={out}.json", r"--camera"),
    ("lens measure {fx}/black.mp4 --camera=ideal --out={fx}/folder.json", r"--out.*folder"),
    (
        "lens measure {fx}/black.mp4 --camera=ideal --out={out}.json --report={out}.json",
        r"--report.*differ",
    ),  # fmt: skip
    ("lens measure {fx}/nosuch.mp4 --camera=ideal --out={out}.json", r"nosuch\.mp4: no such"),
    ("lens measure {fx}/notavideo.mp4 --camera=ideal --out={out}.json", r"notavideo\.mp4"),
    ("lens measure {fx}/black.mp4 --camera=ideal --out={out}.json", r"black\.mp4.*64 x 48"),
    ("lens measure {fx}/black.mp4 --camera={fx}/small.json --out={out}.json", r"no usable marker"),
    ("lens measure {fx}/nodataset --camera=ideal --out={out}.json", r"nodataset: no images"),
    # issue 12: detect-images
    ("detect-images {fx}/nodataset --pipelines=paper --out={out}", r"nodataset: no images"),
    ("detect-images {fx}/nosuch.png --pipelines=paper --out={out}", r"nosuch\.png: no such"),
    ("detect-images {fx}/afile --pipelines=paper --out={out}", r"afile: not an image name"),
    ("detect-images {fx}/afile --pipelines=paper,paper --out={out}", r"--pipelines.*twice"),
    ("detect-images {fx}/afile --pipelines=x --out={out}", r"--pipelines.*unknown preset"),
    ("detect-images {fx}/afile --pipelines=paper --family=x --out={out}", r"--family.*unknown"),
    (
        "detect-images {fx}/afile --pipelines=locus --family=4x4_1000 --out={out}",
        r"--family.*locus cannot detect family 4x4_1000",
    ),  # fmt: skip
    ("detect-images {fx}/afile --pipelines=paper --camera=nosuch --out={out}", r"--camera.*nosuch"),
    (
        "detect-images {fx}/afile --pipelines=paper --camera={fx}/cal_nan.yaml "
        "--camera-format=kalibr --out={out}",
        r"--camera.*intrinsics",
    ),  # fmt: skip
    ("detect-images {fx}/afile --pipelines=paper --camera-format=kalibr", r"--camera-format"),
    # issue 12: --detector / --family (study, dataset)
    (f"{S} --detector=aruco", r"--detector.*aruco.*built-in detectors: opencv"),
    (f"{S} --family=nan", r"--family/--dictionary.*unknown"),
    (f"{S} --detector=locus --family=apriltag_25h9", r"--family.*locus cannot detect family"),
    (f"{S} --detector=locus --dictionary=7x7_50", r"--dictionary.*locus cannot detect"),
    (f"{S} --detector=locus --cell-px=8", r"--cell-px: 8: applies to --detector opencv only"),
    ("bench detectability --detector=locus --family=5x5_100", r"--family.*locus cannot"),
    ("dataset --family=nan", r"--family: .*unknown; choose one of"),
    ("dataset --family=", r"--family: .*unknown"),
    ("bench dataset --family=apriltag_99h1", r"--family: .*unknown"),
    # issue 13: ladder
    ("ladder --out={out} --images=0", r"--images: 0: allowed range is 1\.\.800"),
    ("ladder --out={out} --frames-step=99", r"--frames-step: 99: allowed range is 1\.\.30"),
    ("ladder --out={out} --profile=nope", r"--profile: 'nope'"),
    ("ladder --out={out} --parts=study,film", r"--parts: .*choose from study, video"),
    ("ladder --out={out} --spp=0,4", r"--spp: .*each an integer in 1\.\.64"),
    ("ladder --out={out} --spp=a", r"--spp: 'a': integers"),
    ("ladder --out={out} --reference-spp=0", r"--reference-spp: 0: allowed range is 1\.\.1024"),
    ("ladder --out={out} --path-depth=9", r"--path-depth: 9: allowed range is 1\.\.8"),
    ("ladder --out={out} --pipeline=nope", r"--pipeline: .*nope"),
    ("ladder --out={out} --workers=0", r"--workers: 0: must be >= 1"),
    ("ladder --out={fx}/afile", r"--out: .*is a file"),
    ("ladder --images=10", r"--out"),
]


def snapshot(*folders: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder under ``folders``: (size, mtime in ns)."""
    out = {}
    for folder in folders:
        for path in [folder, *folder.rglob("*")]:
            stat = path.stat()
            out[str(path)] = (stat.st_size, stat.st_mtime_ns)
    return out


def run(argv: list[str], capsys) -> tuple[int, list[str]]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    return code, capsys.readouterr().err.strip().split("\n")


def check_refused(argv: list[str], pattern: str, capsys, *folders: Path) -> None:
    before = snapshot(*folders)
    code, err = run(argv, capsys)
    assert code == 2, (argv, err)
    assert len(err) == 1, err
    assert err[0].startswith("whiskerbench "), err
    assert re.search(pattern, err[0]), (pattern, err[0])
    assert snapshot(*folders) == before, "something was written"


def _argv(line: str, fx: Path, tmp_path: Path) -> list[str]:
    out = tmp_path / "out"
    return [part.format(fx=fx, out=out) for part in line.split(" ")]


@pytest.mark.parametrize("line, pattern", CASES, ids=[c[0][:70] for c in CASES])
def test_refused(line, pattern, fx, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # default outputs (results/, data/) land in tmp_path
    check_refused(_argv(line, fx, tmp_path), pattern, capsys, fx, tmp_path)


def test_enough_cases():
    commands = {" ".join(line.split(" ")[:2]) for line, _ in CASES}
    assert len(CASES) >= 80
    for command in ("detectability", "dataset", "detect", "score", "compare", "camera show",
                    "camera project", "camera import", "lens measure", "bench detectability",
                    "bench dataset", "bench pipeline", "bench render", "bench loader",
                    "bench targets"):  # fmt: skip
        assert any(c.startswith(command) for c in commands), command


# --- a doctored copy of a real dataset: refused naming the file, before any scoring


def _doctor(dataset: Path, how: str) -> str:
    """Damage one file of the copy; return the regex its refusal must match."""
    sample = next(p for p in sorted(dataset.iterdir()) if (p / "sample.json").is_file())
    if how == "labels":
        (sample / "labels.parquet").write_bytes(b"PAR1 not a table")
        return r"labels\.parquet"
    if how == "truncated-record":
        text = (sample / "sample.json").read_text()
        (sample / "sample.json").write_text(text[: len(text) // 2])
        return r"sample\.json"
    if how == "no-video":
        (sample / "video.mp4").unlink()
        return r"video\.mp4"
    if how == "swapped-videos":
        other = next(p for p in sorted(dataset.glob("*/sample.json")) if p.parent != sample).parent
        a, b = sample / "video.mp4", other / "video.mp4"
        data = a.read_bytes()
        a.write_bytes(b.read_bytes())
        b.write_bytes(data)
        return r"video\.mp4"
    if how == "manifest":
        (dataset / "manifest.json").write_text("{")
        return r"manifest\.json"
    if how == "rehashed-record":  # edited values, hashes made to agree: still refused
        from bench.common.manifest import sha256

        record = json.loads((sample / "sample.json").read_text())
        record.update(branch_gaps="nonsense", protocol=5, branches_mm=[float("nan")])
        (sample / "sample.json").write_text(json.dumps(record))
        manifest = json.loads((dataset / "manifest.json").read_text())
        manifest["files"][f"{sample.name}/sample.json"] = sha256(sample / "sample.json")
        (dataset / "manifest.json").write_text(json.dumps(manifest))
        return r"sample\.json"
    raise AssertionError(how)


@pytest.mark.slow  # the session's rendered pair: about 15-70 s once, shared with other tests
@pytest.mark.parametrize("command", ["score", "compare"])
@pytest.mark.parametrize(
    "how",
    [
        "labels",
        "truncated-record",
        "no-video",
        "swapped-videos",
        "manifest",
        "rehashed-record",
    ],
)
def test_doctored_dataset(rendered_pair, tmp_path, capsys, command, how):
    dataset = tmp_path / "data"
    shutil.copytree(rendered_pair, dataset)
    pattern = _doctor(dataset, how)
    argv = [command, str(dataset), "--out", str(tmp_path / "out")]
    check_refused(argv, pattern, capsys, tmp_path)


# --- a bug, and Ctrl-C


def test_a_crash_in_native_code_prints_the_python_stack(tmp_path):
    """A segfault (in Dr.Jit, OpenCV, a peer) after a command has started shows where it was:
    the command line enables faulthandler."""
    script = (
        "import ctypes; from bench.cli.main import main; main(['camera', 'show', 'ideal']); "
        "ctypes.string_at(0)"
    )
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
        env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(root)},
    )  # fmt: skip
    assert done.returncode < 0 and "Fatal Python error: Segmentation fault" in done.stderr
    assert 'File "<string>", line 1' in done.stderr  # the Python stack, to the crash


def test_internal_error_is_a_short_bug_report(tmp_path, capsys, monkeypatch):
    import bench.study.run

    def broken(*args, **kwargs):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(bench.study.run, "run_study", broken)
    code, err = run(["detectability", "--quick", "--out", str(tmp_path / "run")], capsys)
    assert code == 1
    assert err[0] == (
        "whiskerbench detectability: internal error: ZeroDivisionError: float division by zero"
    )
    assert err[1].startswith("please report this with the command line")
    assert 3 <= len(err) <= 10 and "in broken" in err[-1], err


@pytest.mark.parametrize(
    "argv, target, kept",
    [
        (["detectability", "--quick"], "bench.study.run.run_study", r"finished cells are kept in "
         r".*run[/\\]cells; rerun the same command to resume"),
        (["dataset", "--quick"], "bench.dataset.generate.run_dataset",
         r"finished samples are kept in .*run[/\\]<sample id>"),
        (["camera", "import", "{fx}/cal_nan.yaml", "--format=kalibr"],
         "scenes.calibration_import.import_calibration", r"nothing was written"),
    ],
)  # fmt: skip
def test_ctrl_c_says_what_is_kept(argv, target, kept, fx, tmp_path, capsys, monkeypatch):
    module, name = target.rsplit(".", 1)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(f"{module}.{name}", interrupted)
    if target.startswith("scenes.calibration_import"):
        monkeypatch.setattr("bench.cli.camera.import_calibration", interrupted)
    argv = [a.format(fx=fx) for a in argv] + ["--out", str(tmp_path / "run")]
    code, err = run(argv, capsys)
    assert code == 130
    assert len(err) == 1 and "interrupted" in err[0] and re.search(kept, err[0]), err


def test_shipped_settings_are_within_the_limits():
    """The limits refuse hostile sizes, never what the project itself runs: the default and
    band studies, the default dataset with full frames, the default sweeps of four presets."""
    import dataclasses

    from bench.cli import limits
    from bench.dataset.config import DatasetConfig
    from bench.evaluate.sweep_config import SweepConfig
    from bench.study.config import StudyConfig
    from scenes.profile import load_profile

    limits.check_study(
        StudyConfig(psf_scales=load_profile("prototype").band.psf_levels()),
        limits.default_workers(),
    )
    dataset = DatasetConfig()
    limits.check_dataset(dataset)
    full = dataclasses.replace(dataset.sampling, full_frame=True)
    limits.check_dataset(dataclasses.replace(dataset, sampling=full))
    limits.check_sweep(SweepConfig(), 4)
    lens = dataset.camera.lens
    limits.check_frames("frames", 30, lens.width_px, lens.height_px, "full frames")


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
@pytest.mark.skipif(gpu_present(), reason="this machine has a GPU: cuda_ad_rgb would run")
@pytest.mark.parametrize(
    "command", ["detectability --quick", "dataset --quick", "bench render", "bench scale"]
)
def test_gpu_variant_without_a_gpu_is_refused(command, tmp_path):
    """--variant cuda_ad_rgb on a machine without a GPU: one line, exit 2, nothing written
    (in a process of its own: the test session's Mitsuba variant stays as it is)."""
    out = tmp_path / "out"
    argv = [*command.split(), "--variant", "cuda_ad_rgb"]
    if command != "bench scale":
        argv += ["--out", str(out)]
    done = subprocess.run(
        [sys.executable, "-m", "bench.cli", *argv], capture_output=True, text=True, cwd=tmp_path
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert re.search(r"--variant: cuda_ad_rgb needs an NVIDIA GPU", lines[0])
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == []

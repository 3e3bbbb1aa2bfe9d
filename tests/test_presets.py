"""Pipeline variants as data: presets, and variant names that change named choices."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from pipeline.detect import DetectorConfig
from pipeline.presets import PRESETS, PipelineConfig, get_pipeline
from pipeline.track import Search


def test_a_preset_name_is_the_preset():
    for name, preset in PRESETS.items():
        assert get_pipeline(name) == preset


def test_a_variant_changes_only_what_it_names():
    v = get_pipeline("paper/refine=contour/aruco3=on/window=31/pose=virtual/aggregation=max")
    paper = PRESETS["paper"]
    assert v.name == "paper/refine=contour/aruco3=on/window=31/pose=virtual/aggregation=max"
    assert v.folder_name == "paper~refine=contour~aruco3=on~window=31~pose=virtual~aggregation=max"
    assert v.detector.corner_refinement == "contour" and v.detector.use_aruco3_detection
    assert (v.detector.adaptive_thresh_win_size_min, v.detector.adaptive_thresh_win_size_max) == (
        31,
        31,
    )
    assert v.pose_method == "virtual" and v.aggregation == "max"
    assert v.search == paper.search and v.threshold == paper.threshold
    assert v.detector.adaptive_thresh_constant == paper.detector.adaptive_thresh_constant
    w = get_pipeline("fast/window=3-23-10/search=full/margin=20/threshold=online/constant=5")
    assert (
        w.detector.adaptive_thresh_win_size_min,
        w.detector.adaptive_thresh_win_size_max,
        w.detector.adaptive_thresh_win_size_step,
    ) == (3, 23, 10)
    assert w.search.mode == "full" and w.search.margin_px == 20 and w.threshold == "online"
    assert w.detector.adaptive_thresh_constant == 5.0


@pytest.mark.parametrize(
    "name, says",
    [
        ("fastest", "unknown preset 'fastest'"),
        ("paper/colour=red", "'colour=red' is not CHOICE=VALUE"),
        ("paper/refine=magic", "corner_refinement='magic'"),
        ("paper/aruco3=maybe", "choose on or off"),
        ("paper/window=1", "need 3 <= MIN <= MAX"),
        ("paper/window=23-3", "need 3 <= MIN <= MAX"),
        ("paper/search=somewhere", "search='somewhere'"),
        ("paper/pose=", "is not CHOICE=VALUE"),
        ("paper/aggregation=sum", "aggregation='sum'"),
        (None, "a pipeline is named by a string"),
    ],
)
def test_bad_variant_names_say_what_is_wrong(name, says):
    with pytest.raises(ValueError, match=None) as info:
        get_pipeline(name)
    assert says in str(info.value) and "\n" not in str(info.value)


@pytest.mark.slow
def test_cli_refuses_a_bad_variant_in_one_line(tmp_path):
    for args in (
        ["detect", "v.mp4", "--camera", "c.json", "--pipeline", "paper/refine=magic"],
        ["score", str(tmp_path), "--pipeline", "fastest"],
        ["compare", str(tmp_path), "--pipelines", "paper,paper"],
        ["bench", "pipeline", "--pipelines", "paper,naive/pose=guess"],
    ):
        run = subprocess.run(
            [sys.executable, "-m", "bench.cli", *args], capture_output=True, text=True, timeout=60
        )
        assert run.returncode == 2, args
        assert len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "fields, says",
    [
        ({"adaptive_thresh_win_size_min": -3}, "windows -3..23 step 10: need 3 <= MIN"),
        ({"adaptive_thresh_win_size_max": 10**9}, "need 3 <= MIN <= MAX <= 1001"),
        ({"adaptive_thresh_win_size_step": 0}, "STEP >= 1"),
        ({"adaptive_thresh_win_size_max": 999, "adaptive_thresh_win_size_step": 1}, "at most 32"),
        ({"adaptive_thresh_win_size_min": 3.5}, "must be integers"),
        ({"adaptive_thresh_constant": float("inf")}, "-255..255 grey levels"),
    ],
)
def test_a_detector_config_refuses_what_opencv_would_assert_on(fields, says):
    """The same rule as the ``window=`` and ``constant=`` choices, for the API's own configs:
    OpenCV would raise its own assertion (a window under 3 px), or threshold a billion times."""
    with pytest.raises(ValueError, match=None) as info:
        DetectorConfig(**fields)
    assert says in str(info.value), str(info.value)


@pytest.mark.parametrize("image", [np.zeros((0, 0), np.uint8), [[0] * 8] * 8, None, "a.png"])
def test_detect_markers_refuses_what_is_no_grey_image(image):
    from pipeline.detect import detect_markers

    with pytest.raises(ValueError, match="need an 8-bit grey image"):
        detect_markers(image, DetectorConfig())


def test_cell_choice_sets_the_bit_sampling():
    import pytest

    from pipeline.presets import get_pipeline

    assert get_pipeline("paper/cell=8").detector.cell_px == 8
    with pytest.raises(ValueError, match="cell_px=1: allowed range is 2..32"):
        get_pipeline("paper/cell=1")


def test_recover_names_a_backend_that_reads_the_family() -> None:
    assert get_pipeline("paper/recover=apriltag").backends == ("opencv", "apriltag")
    assert PRESETS["hybrid"].backends == ("locus", "apriltag")
    assert PRESETS["paper"].backends == ("opencv",)
    with pytest.raises(ValueError, match="recover=foo.*choose from"):
        get_pipeline("paper/recover=foo")
    with pytest.raises(ValueError, match="locus cannot detect family 7x7_50"):
        PipelineConfig("x", DetectorConfig("7x7_50"), Search(recover="locus"))

"""One-axis sweeps: rows, physics the sweep must show, boundaries, validation, the plot."""

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from bench.evaluate.sweep_config import AXES, BOUNDARY_AXES, QUICK_SWEEP, SweepConfig
from bench.evaluate.sweep_report import boundaries, plot_sweeps
from bench.evaluate.sweeps import run_sweeps
from pipeline.presets import PRESETS
from renderers.motion_blur import motion_blur, motion_kernel
from scenes.profile import Band, load_profile

# The mechanics are tested on the ideal camera, whose behaviour at these points is known.
TINY = SweepConfig(
    camera=load_profile("ideal"),
    alphas_deg=(40.0, 92.0),
    phis_deg=(0.0, 30.0),
    lightings=("lab", "sun"),
    blur_px=(0.0, 8.0),
    read_noise_e=(3.0, 100.0),
    seeds=2,
    images=4,
    spp=4,
)
PIPELINES = [PRESETS["paper"], PRESETS["robust"]]


@pytest.fixture(scope="module")
def table(variant):
    return run_sweeps(PIPELINES, TINY, variant=variant, progress=False)


def rows(table, axis, level, pipeline):
    return table[
        (table["axis"] == axis) & (table["level"] == level) & (table["pipeline"] == pipeline)
    ]


@pytest.mark.slow
def test_one_row_per_axis_level_seed_pipeline(table):
    # five axes of two levels; the ideal camera's band is the nominal PSF alone (one level)
    assert len(table) == (5 * 2 + 1) * 2 * 2
    keys = table[["axis", "level", "seed", "pipeline"]].drop_duplicates()
    assert len(keys) == len(table)
    assert list(dict.fromkeys(table["axis"])) == list(AXES)
    assert set(table["pipeline"]) == {"paper", "robust"}
    assert (table["images"] == 4).all()
    lighting = table[table["axis"] == "lighting"]
    assert lighting["level_value"].isna().all()
    assert list(dict.fromkeys(lighting["level"])) == ["lab", "sun"]
    blur = table[table["axis"] == "blur_px"]
    assert set(blur["level"]) == {"0", "8"} and set(blur["level_value"]) == {0.0, 8.0}
    assert set(table[table["axis"] == "psf_scale"]["level"]) == {"1"}
    assert (table["psf_scale"] == 1.0).all()
    assert table["recall"].between(0, 1).all()


@pytest.mark.slow
def test_recall_is_one_at_the_easy_base_point_for_paper_in_lab(table):
    lab = rows(table, "lighting", "lab", "paper")
    assert len(lab) == 2 and (lab["recall"] == 1.0).all()
    assert (lab["false_ids"] == 0).all()
    assert (lab["corner_err_px"] < 1.0).all() and (lab["rot_err_deg"] < 10.0).all()


@pytest.mark.slow
def test_fisheye_pose_fails_past_90_degrees_and_the_virtual_view_does_not(table):
    paper = rows(table, "alpha_deg", "92", "paper")
    robust = rows(table, "alpha_deg", "92", "robust")
    assert (paper["recall"] == 1.0).all() and (robust["recall"] == 1.0).all()
    assert (paper["pose_failures"] == paper["images"]).all()
    assert paper["rot_err_deg"].isna().all() and paper["trans_err_mm"].isna().all()
    assert (robust["pose_failures"] == 0).all()
    assert robust["rot_err_deg"].notna().all() and (robust["rot_err_deg"] < 10.0).all()
    inside = rows(table, "alpha_deg", "40", "paper")
    assert (inside["pose_failures"] == 0).all() and inside["rot_err_deg"].notna().all()


@pytest.mark.slow
def test_eight_px_of_motion_blur_loses_the_marker(table):
    # The base point's modules are about 7 px wide: a smear longer than a module erases the
    # code (recall 1 without blur, 0 at 8 px for every preset on renders of this size).
    for pipeline in ("paper", "robust"):
        sharp = rows(table, "blur_px", "0", pipeline)["recall"].mean()
        blurred = rows(table, "blur_px", "8", pipeline)["recall"].mean()
        assert sharp == 1.0
        assert blurred <= 0.5


@pytest.mark.slow
def test_seeds_differ_and_the_run_is_reproducible(table, variant):
    base = rows(table, "read_noise_e", "100", "robust")
    assert base["corner_err_px"].nunique() == 2  # another seed, other images
    again = run_sweeps(
        [PRESETS["robust"]],
        SweepConfig(
            camera=load_profile("ideal"),
            alphas_deg=(40.0,),
            phis_deg=(30.0,),
            lightings=("sun",),
            blur_px=(0.0,),
            read_noise_e=(100.0,),
            seeds=2,
            images=4,
            spp=4,
        ),
        variant=variant,
        progress=False,
    )
    # The same (point, seed) gives the same images whatever else the sweep contains.
    mine = rows(again, "read_noise_e", "100", "robust").reset_index(drop=True)
    pd.testing.assert_frame_equal(mine, base.reset_index(drop=True))


@pytest.mark.parametrize(
    ("length", "expected"),
    [
        (0.0, [1.0]),
        (1.0, [1.0]),
        (3.0, [1 / 3] * 3),
        (4.0, [1 / 8, 1 / 4, 1 / 4, 1 / 4, 1 / 8]),  # half taps at the ends: still centred
        (5.5, [0.25 / 5.5] + [1 / 5.5] * 5 + [0.25 / 5.5]),
    ],
)
def test_motion_kernel_is_a_centred_box_of_the_given_length(length, expected):
    w = motion_kernel(length)
    np.testing.assert_allclose(w, expected, rtol=1e-6)
    assert math.isclose(w.sum(), 1.0, rel_tol=1e-6)


def test_motion_blur_smears_along_x_only():
    radiance = np.zeros((5, 21, 3), np.float32)
    radiance[2, 10] = 1.0
    out = motion_blur(radiance, 5.0)
    np.testing.assert_allclose(out[2, 8:13, 0], 0.2, rtol=1e-6)
    assert out[2, :8].sum() == 0 and out[2, 13:].sum() == 0
    assert out[[0, 1, 3, 4]].sum() == 0
    stack = np.stack([radiance, 2 * radiance])  # leading axes (N canopy images) pass through
    np.testing.assert_allclose(motion_blur(stack, 5.0)[1], 2 * out, rtol=1e-6)


def _hand_table() -> pd.DataFrame:
    """Two seeds; recall per level chosen so the boundaries are known."""
    recall = {
        # axis: {level: (seed 0, seed 1)}
        "phi_deg": {0: (1.0, 1.0), 20: (1.0, 0.925), 40: (0.5, 0.7), 60: (1.0, 1.0)},
        "blur_px": {0: (1.0, 1.0), 4: (1.0, 1.0), 8: (0.9, 0.92)},
        "read_noise_e": {3: (1.0, 1.0), 100: (1.0, 0.95)},
        "alpha_deg": {0: (0.5, 0.6), 40: (1.0, 1.0)},
        "lighting": {"lab": (1.0, 1.0), "backlit": (0.9, 0.96), "sun": (0.5, 0.0)},
        "psf_scale": {0.5: (1.0, 1.0), 1.25: (0.7, 0.6), 1: (1.0, 0.95), 1.5: (0.2, 0.0)},
    }
    rows = []
    for axis, levels in recall.items():
        for level, per_seed in levels.items():
            for seed, r in enumerate(per_seed):
                numeric = axis != "lighting"
                rows.append(
                    {
                        "axis": axis,
                        "level": f"{level:g}" if numeric else level,
                        "level_value": float(level) if numeric else math.nan,
                        "seed": seed,
                        "pipeline": "p",
                        "recall": r,
                    }
                )
    return pd.DataFrame(rows)


def test_boundaries_of_a_hand_made_table():
    b = boundaries(_hand_table()).set_index("axis")
    assert list(b.index) == list(AXES)
    # phi: means 1, 0.9625, 0.6, 1 -> last ok 20, first fail 40; one seed is below at 20.
    phi = b.loc["phi_deg"]
    assert (phi["last_ok"], phi["first_fail"]) == (20.0, 40.0)
    assert (phi["fail_min"], phi["fail_max"]) == (0.5, 0.7)
    assert math.isclose(phi["fail_std"], 0.1)
    assert not phi["stable"] and phi["recovers"]
    assert phi["failing"] == "40"
    # blur: all seeds agree on both sides of the crossing 4 -> 8.
    blur = b.loc["blur_px"]
    assert (blur["last_ok"], blur["first_fail"]) == (4.0, 8.0)
    assert blur["stable"] and not blur["recovers"]
    # noise: never fails; 0.95 counts as detected.
    noise = b.loc["read_noise_e"]
    assert noise["last_ok"] == 100.0 and math.isnan(noise["first_fail"])
    assert noise["stable"] and noise["failing"] == ""
    # alpha: fails at the first level already, then recovers.
    alpha = b.loc["alpha_deg"]
    assert math.isnan(alpha["last_ok"]) and alpha["first_fail"] == 0.0
    assert alpha["stable"] and alpha["recovers"]
    # lighting: backlit's mean 0.93 fails, but one of its seeds does not -> unstable.
    lighting = b.loc["lighting"]
    assert lighting["failing"] == "backlit,sun"
    assert not lighting["stable"]
    # lens sharpness: levels out of order in the table; the blurriest PSF kept is 1.
    psf = b.loc["psf_scale"]
    assert (psf["last_ok"], psf["first_fail"]) == (1.0, 1.25)
    assert psf["stable"] and not psf["recovers"] and psf["failing"] == "1.25,1.5"


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"seeds": 0}, "seeds"),
        ({"images": 0}, "images"),
        ({"spp": 2.5}, "spp"),
        ({"alphas_deg": (40.0, 120.0)}, "alphas_deg"),
        ({"alphas_deg": ()}, "alphas_deg"),
        ({"phis_deg": (95.0,)}, "phis_deg"),
        ({"lightings": ("lab", "disco")}, "lightings"),
        ({"base_lighting": "disco"}, "base_lighting"),
        ({"blur_px": (-1.0,)}, "blur_px"),
        ({"read_noise_e": (3.0, float("nan"))}, "read_noise_e"),
        ({"read_noise_e": (3.0, 3.0)}, "read_noise_e"),
        ({"size_mm": 0.0}, "size_mm"),
        ({"distance_mm": -5.0}, "distance_mm"),
        ({"base_alpha_deg": 100.0}, "base_alpha_deg"),
        ({"dictionary": "9x9_1"}, "dictionary"),
        ({"base_psf_scale": -0.5}, "base_psf_scale"),
        ({"base_psf_scale": 11.0}, "base_psf_scale"),
        ({"psf_axis": "middle"}, "psf_axis"),
        ({"axes": ("alpha_deg", "focus")}, "axes"),
        ({"axes": ()}, "axes"),
        ({"band_seeds": 0}, "band_seeds"),
        ({"camera": load_profile("prototype").with_psf_scale(0.0)}, "camera"),
    ],
)
def test_bad_configs_are_refused_naming_the_field(change, field):
    with pytest.raises(ValueError, match=f"^{field}: ") as info:
        SweepConfig(**change)
    assert "\n" not in str(info.value)


def test_the_psf_axis_and_the_band_ends_follow_the_profiles_band():
    """Levels from the profile's band, never fixed: a recalibrated band moves them."""
    camera = dataclasses.replace(load_profile("prototype"), band=Band((0.4, 1.2)))
    config = SweepConfig(camera=camera)
    assert config.psf_scales == (0.4, 0.7, 1.0, 1.1, 1.2)
    assert dataclasses.replace(config, psf_axis="ends").psf_scales == (0.4, 1.2)
    assert QUICK_SWEEP.psf_scales == QUICK_SWEEP.camera.band.psf_ends  # 2 levels
    points = config.points()
    base = next(p for p in points if p.axis == "phi_deg" and p.level == 30.0)
    lens = [p for p in points if p.axis == "psf_scale"]
    assert [p.psf_scale for p in lens] == [0.4, 0.7, 1.0, 1.1, 1.2]
    assert {p.render_key for p in lens} == {base.render_key}  # one render for the whole axis
    assert {p.psf_scale for p in points if p.axis != "psf_scale"} == {1.0}
    low, high = config.band_end_sweeps()
    assert (low.base_psf_scale, high.base_psf_scale) == (0.4, 1.2)
    assert low.axes == BOUNDARY_AXES and low.seeds == config.band_seeds
    assert {p.axis for p in low.points()} == set(BOUNDARY_AXES)
    assert {p.psf_scale for p in high.points()} == {1.2}
    assert SweepConfig(camera=load_profile("ideal")).band_end_sweeps() == ()  # no band
    # a profile written at another scale (a dataset's camera.json at --psf-scale 1.5): the
    # levels are still the band's, set against the table as calibrated
    scaled = SweepConfig(camera=camera.with_psf_scale(1.5))
    assert scaled.psf_scales == config.psf_scales
    assert np.allclose(
        scaled.camera.at_psf_scale(0.4).psf.sigma_radial_px,
        camera.with_psf_scale(0.4).psf.sigma_radial_px,
    )


def test_run_sweeps_refuses_an_empty_or_ambiguous_pipeline_list():
    with pytest.raises(ValueError, match="pipelines"):
        run_sweeps([], TINY, progress=False)
    with pytest.raises(ValueError, match="distinct"):
        run_sweeps([PRESETS["paper"], PRESETS["paper"]], TINY, progress=False)


@pytest.mark.slow
def test_plot_is_written(table, tmp_path):
    path = tmp_path / "plots" / "sweeps.png"
    plot_sweeps(table, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in path.parent.iterdir()] == ["sweeps.png"]  # no temporary file left


def test_a_sweep_runs_on_the_prototype_twin_with_its_own_read_noise(variant):
    prototype = load_profile("prototype")
    wide = dataclasses.replace(prototype, band=Band((0.442, 4.0)))  # to where the code is lost
    config = SweepConfig(
        alphas_deg=(40.0,), phis_deg=(30.0,), lightings=("lab",), blur_px=(0.0,),
        read_noise_e=(2.0,), seeds=1, images=3, spp=4, camera=wide,
    )  # fmt: skip
    assert config.camera.name == "prototype"
    table = run_sweeps([PRESETS["robust"]], config, variant=variant, progress=False)
    band = config.camera.band.psf_levels()
    assert len(table) == 5 + len(band) and table["recall"].between(0, 1).all()
    base = table[table["axis"] == "alpha_deg"]
    assert len(base) == 1
    # the lens-sharpness axis: the profile's band levels, the other axes at the nominal PSF
    psf = table[table["axis"] == "psf_scale"]
    assert psf["level_value"].tolist() == psf["psf_scale"].tolist() == list(band)
    assert (table[table["axis"] != "psf_scale"]["psf_scale"] == 1.0).all()
    columns = ["recall", "false_ids", "corner_err_px", "rot_err_deg"]
    at_base = table[table["axis"] == "phi_deg"][columns].to_numpy(float)  # phi 30: the base
    nominal = psf[psf["psf_scale"] == 1.0][columns].to_numpy(float)
    np.testing.assert_array_equal(nominal, at_base)  # the same images: one render, one draw
    # OpenCV's decoder through ever more blur: a sharper lens reads the code, a blurrier one
    # (4x the calibrated table) does not; the boundary is the last level read every time
    recall = psf["recall"].to_numpy()
    assert (np.diff(recall) <= 0).all() and recall[0] == 1.0 and recall[-1] == 0.0
    edge = boundaries(table).set_index("axis").loc["psf_scale"]
    last = np.flatnonzero(recall >= 0.95)[-1]
    assert (edge["last_ok"], edge["first_fail"]) == (band[last], band[last + 1])


def test_a_backend_crash_is_counted_apart_and_not_as_a_miss(monkeypatch):
    from bench.common.marker_score import MarkerTruth
    from bench.evaluate import sweeps
    from pipeline.backends import BackendCrashError
    from pipeline.detect import Detection

    lens = load_profile("ideal").lens
    T = np.diag([1.0, -1.0, -1.0, 1.0])  # facing the camera, 200 mm away
    T[2, 3] = 200.0
    truth = MarkerTruth.of(lens, 0, 13.2, T)
    outcomes = iter(["crash", "hit", "miss", "crash"])
    own = T.copy()
    own[0, 3] += 3.0  # the backend's own pose: 3 mm off, rotation exact

    def detect(image, detector, origin, camera, size_mm):
        outcome = next(outcomes)
        if outcome == "crash":
            raise BackendCrashError("detector locus crashed (signal 6)")
        assert size_mm == 13.2  # the own pose is asked for with the marker's side
        return [Detection(0, truth.corners_px + [0.3, 0.4], own)] if outcome == "hit" else []

    monkeypatch.setattr(sweeps, "detect_markers", detect)
    images = np.zeros((4, 8, 8), np.uint8)
    row = sweeps.score_images(PRESETS["locus"], images, (0, 0), truth, lens)
    assert (row["images"], row["backend_failures"]) == (4, 2)
    assert row["recall"] == 0.5  # one hit of the two images it did not crash on
    assert row["corner_err_px"] == pytest.approx(0.5)
    assert row["own_trans_err_mm"] == pytest.approx(3.0)
    assert row["own_rot_err_deg"] == pytest.approx(0.0, abs=1e-6)
    assert np.isfinite(row["rot_err_deg"])  # the project's pose on the backend's corners

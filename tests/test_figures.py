"""Every saved figure reads without the README: the title it was saved with (read back from the
PNG's metadata) names the run's non-default options, its series are drawn in the Okabe-Ito
palette, and its legends stand clear of the data."""

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.transforms import Bbox
from PIL import Image
from test_report import SMALL_GRID, synthetic_images

from bench.common.figures import PALETTE, colour, marker, titled

#: Okabe & Ito (2008), "Color Universal Design": the eight colours, independently of the module.
OKABE_ITO = {"#e69f00", "#56b4e9", "#009e73", "#0072b2", "#d55e00", "#cc79a7", "#000000", "#f0e442"}


@pytest.fixture
def saved(monkeypatch):
    """The figures saved while the test runs, as they were when saved."""
    figures = []
    real = Figure.savefig

    def savefig(self, *args, **kwargs):
        self.canvas.draw()  # lay it out as saved, so extents are final
        self.saved_renderer = self.canvas.get_renderer()
        figures.append(self)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figures


def png_title(path) -> str:
    with Image.open(path) as image:
        return image.text["Title"]


def series_colours(fig: Figure) -> set[str]:
    """Colours of lines, markers and patches in the axes (a colour bar's scale is not a
    series), greys (black excepted) left out."""
    found = []
    for ax in fig.axes:
        if ax.get_label() == "<colorbar>":
            continue
        found += [line.get_color() for line in ax.lines]
        for collection in ax.collections:
            for rgba in [*collection.get_facecolors(), *collection.get_edgecolors()]:
                if rgba[3] > 0:
                    found.append(rgba)
        found += [patch.get_facecolor() for patch in ax.patches if patch.get_fill()]
    hexes = {to_hex(c) for c in found}
    return {h for h in hexes if h == "#000000" or len({h[1:3], h[3:5], h[5:7]}) > 1}


def assert_legends_clear_of_data(fig: Figure) -> None:
    renderer = fig.saved_renderer
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend())]
    for legend in legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            if ax.get_label() != "<colorbar>":
                # the axes with their labels and titles: a legend covers none of them
                assert not box.overlaps(ax.get_tightbbox(renderer)), "legend over the axes"


def test_the_palette_is_okabe_ito_and_wrapped_series_change_marker():
    assert {c.lower() for c in PALETTE} == OKABE_ITO and len(PALETTE) == 8
    assert colour(0) == colour(8) and marker(0) != marker(8)
    assert len({(colour(i), marker(i)) for i in range(20)}) == 20
    assert titled("T") == "T" and titled("T", ["--quick"]) == "T\noptions: --quick"


@pytest.mark.slow
def test_study_figures_name_their_options(saved, tmp_path):
    from bench.study.config import StudyConfig, nondefault_options
    from bench.study.plots import plot_heatmap, plot_max_phi, plot_pose_error
    from bench.study.report import max_phi, summarize

    assert nondefault_options(StudyConfig()) == []
    config = StudyConfig(sizes_mm=(8.8, 17.6), images=30, spp=4)
    options = nondefault_options(config)
    assert options == ["--sizes 8.8,17.6", "--images 30", "--spp 4"]
    summary = summarize(synthetic_images(SMALL_GRID, seed=17))
    for plot, table in ((plot_max_phi, max_phi(summary)), (plot_heatmap, summary),
                        (plot_pose_error, summary)):  # fmt: skip
        path = tmp_path / f"{plot.__name__}.png"
        plot(table, path, detector="opencv (4x4_50)", options=options)
        assert "options: --sizes 8.8,17.6 --images 30 --spp 4" in png_title(path)
    for fig in saved:
        assert series_colours(fig) <= OKABE_ITO
        assert_legends_clear_of_data(fig)


@pytest.mark.slow
def test_comparison_figures_name_the_dataset_and_options(saved, tmp_path):
    from bench.evaluate.pareto import plot_pareto
    from bench.evaluate.sweep_config import QUICK_SWEEP, SweepConfig, sweep_options
    from bench.evaluate.sweep_report import plot_sweeps

    assert sweep_options(SweepConfig()) == [] and sweep_options(QUICK_SWEEP) == ["--quick"]
    assert sweep_options(SweepConfig(seeds=7)) == ["--seeds 7"]
    names = [f"p{i}" for i in range(9)] + ["locus"]  # the colours wrap; a peer is dashed
    summary = pd.DataFrame(
        {
            "pipeline": names,
            "fps": np.linspace(5, 80, len(names)),
            "correct_rate": np.linspace(0.2, 0.9, len(names))[::-1],
            "recall": np.linspace(0.9, 1.0, len(names)),
            "deflection_err_mm": np.linspace(0.01, 0.1, len(names)),
        }
    )
    plot_pareto(summary, tmp_path / "pareto.png", "quick", ["--quick"])
    assert png_title(tmp_path / "pareto.png").startswith("Accuracy against speed on quick")
    assert "options: --quick" in png_title(tmp_path / "pareto.png")
    rows = [
        {
            "pipeline": p,
            "axis": axis,
            "level": x,
            "level_value": x,
            "seed": s,
            "recall": 1.0 - x / 100,
            "rot_err_deg": 1.0 + x,
        }  # fmt: skip
        for p in names
        for axis in ("alpha_deg", "blur_px")
        for x in (0.0, 4.0, 8.0)
        for s in (0, 1)
    ]
    plot_sweeps(pd.DataFrame(rows), tmp_path / "sweeps.png", ["--seeds 7"])
    assert "options: --seeds 7" in png_title(tmp_path / "sweeps.png")
    for fig in saved:
        assert series_colours(fig) <= OKABE_ITO
        assert_legends_clear_of_data(fig)
    first, ninth = (
        next(line for line in saved[-1].axes[0].lines if line.get_label() == name)
        for name in ("p0", "p8")
    )
    assert first.get_color() == ninth.get_color() and first.get_marker() != ninth.get_marker()


@pytest.mark.slow
def test_point_names_cover_no_other_name_and_coinciding_points_share_one(saved, tmp_path):
    """The comparison's crowd: four pipelines at one accuracy within a few frames/s, two on the
    very same spot (a preset and its alias), one at the left edge with a long name."""
    from bench.evaluate.pareto import plot_pareto

    summary = pd.DataFrame(
        {
            "pipeline": ["robust/detector=locus", "hybrid", "paper", "naive", "fast", "locus"],
            "fps": [7.37, 8.85, 23.7, 23.7, 95.3, 22.5],
            "correct_rate": [0.667, 0.792, 0.75, 0.75, 0.708, 0.75],
            "recall": [0.998, 0.998, 0.989, 0.989, 0.979, 0.998],
            "deflection_err_mm": [0.0088, 0.0088, 0.022, 0.1, 0.048, 0.013],
        }
    )
    plot_pareto(summary, tmp_path / "pareto.png")
    (fig,) = saved
    renderer = fig.saved_renderer
    for ax in fig.axes:
        texts = [t for t in ax.texts if t.get_text()]
        boxes = [t.get_window_extent(renderer) for t in texts]
        for i, a in enumerate(boxes):
            assert not any(a.overlaps(b) for b in boxes[i + 1 :]), texts[i].get_text()
        named = sorted(n.strip() for t in texts for n in t.get_text().split(","))
        assert named == sorted(summary["pipeline"])  # every one named, once
    recall_names = [t.get_text() for t in fig.axes[1].texts]
    assert "paper, naive" in recall_names  # the same spot: one name for both
    frame = fig.axes[1].get_window_extent(renderer)
    for t in fig.axes[1].texts:  # room enough: every name inside the panel
        box = t.get_window_extent(renderer)
        assert frame.x0 <= box.x0 and box.x1 <= frame.x1, t.get_text()


def test_results_grid_and_branch_plot_use_the_palette(saved, tmp_path):
    from bench.evaluate.detect import plot_estimate
    from bench.evaluate.grid_plot import plot_grid
    from pipeline.branches import BranchEstimate

    table = pd.DataFrame(
        {
            "foliage": ["soft"] * 3,
            "distance": ["far"] * 3,
            "branches": ["none", "0", "50"],
            "outcome": ["correct", "false_negative", "refused"],
        }
    )
    plot_grid(table, tmp_path / "grid.png", "paper/refine=contour: outdoor, sun")
    assert png_title(tmp_path / "grid.png") == "paper/refine=contour: outdoor, sun"
    n = 13
    curve = np.sin(np.linspace(0, 3, n)) + 1
    estimate = BranchEstimate(
        gaps=[(5, 6)], peaks=[5], curve=curve, max_deflection=curve, candidate=curve > 1,
        x_integrals=curve, contact=np.zeros((2, n), bool), deflection=np.zeros((2, n)),
        unseen_markers=[], threshold_mm=1.2, aggregation="integration",
    )  # fmt: skip
    plot_estimate(estimate, tmp_path / "branches.png", [[7, 8]], "paper: sample")
    for fig in saved:
        assert series_colours(fig) <= OKABE_ITO
        assert_legends_clear_of_data(fig)


def test_ladder_chart_names_its_options(saved, tmp_path):
    from bench.ladder import report
    from bench.ladder.config import LadderConfig, ladder_options

    assert ladder_options(LadderConfig()) == []
    assert ladder_options(LadderConfig.quick()) == ["--quick"]
    assert ladder_options(LadderConfig.quick(spps=(1, 2), seed=3)) == [
        "--quick", "--seed 3", "--spp 1,2"
    ]  # fmt: skip
    rungs = pd.DataFrame(
        {
            "part": ["study"] * 4,
            "axis": ["reference", "spp", "spp", "spp"],
            "rung": ["reference", "1", "4", "16"],
            "s_per_image": [5.0, 0.05, 0.1, 0.3],
            "rate_err_max": [0.0, 0.3, 0.02, 0.01],
            "corner_err_px": [0.1, 0.5, 0.12, 0.1],
            "matches_reference": [True, False, True, True],
        }
    )
    path = tmp_path / "ladder.png"
    report.plot(rungs, report.defaults_table(rungs), path, ["--quick", "--spp 1,4,16"])
    assert "options: --quick --spp 1,4,16" in png_title(path)
    assert series_colours(saved[-1]) <= OKABE_ITO
    assert_legends_clear_of_data(saved[-1])


@pytest.mark.slow
def test_ladder_rung_names_stay_in_their_panel_clear_of_each_other_and_the_star(saved, tmp_path):
    """The ladder's crowd: camera stages at nearly one cost on the panel's floor, beside the
    reference star, and one far rung that stretches the axes."""
    from bench.ladder import report

    names = ["mosaic", "noise", "lateral_colour", "relative_illumination", "stream"]
    rungs = pd.DataFrame(
        {
            "part": ["study"] * 6,
            "axis": ["reference", *["stage"] * 5],
            "rung": ["reference", *names],
            "s_per_image": [5.4, 4.9, 5.0, 5.1, 5.2, 40.0],
            "rate_err_max": [0.0, 0.0, 0.0, 0.0, 0.0, 0.6],
            "corner_err_px": [0.1] * 6,
            "matches_reference": [True, True, False, True, True, False],
        }
    )
    report.plot(rungs, report.defaults_table(rungs), tmp_path / "ladder.png")
    renderer = saved[-1].saved_renderer
    ax = saved[-1].axes[0]
    texts = [t for t in ax.texts if t.get_text()]
    assert sorted(n.strip() for t in texts for n in t.get_text().split(",")) == sorted(names)
    boxes = [t.get_window_extent(renderer) for t in texts]
    frame = ax.get_window_extent(renderer)
    (x, y), r = ax.transData.transform((5.4, 0.0)), 8  # the star: about 17 px across
    star = Bbox.from_extents(x - r, y - r, x + r, y + r)
    for i, box in enumerate(boxes):
        assert frame.x0 <= box.x0 and box.x1 <= frame.x1, texts[i].get_text()
        assert frame.y0 <= box.y0 and box.y1 <= frame.y1, texts[i].get_text()
        assert not any(box.overlaps(b) for b in [*boxes[i + 1 :], star]), texts[i].get_text()

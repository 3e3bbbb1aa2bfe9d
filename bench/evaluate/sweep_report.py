"""Reading a sweep table (where recall falls below 95 %, do the seeds agree) and writing it."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import matplotlib

from bench.evaluate.leaders import is_peer  # noqa: E402
from bench.evaluate.sweep_config import (  # noqa: E402
    AXES,
    NUMERIC_AXES,
    RECALL_OK,
    SweepConfig,
    sweep_options,
)
from pipeline.presets import PipelineConfig  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from bench.common.atomic import atomic_path, write_json  # noqa: E402
from bench.common.figures import colour, legend_outside, marker, save, titled  # noqa: E402


def boundaries(table: pd.DataFrame, threshold: float = RECALL_OK) -> pd.DataFrame:
    """Where recall falls below ``threshold``, per (pipeline, axis); one row each.

    Numeric axes all get harder as the value grows (and their smallest level is the easy end;
    on ``psf_scale`` ``last_ok`` is the blurriest lens that keeps recall >= ``threshold``),
    so each is walked upward from its smallest level: ``last_ok`` is the last level before the
    first level whose mean recall over seeds is below ``threshold`` (NaN if the first level
    already fails), ``first_fail`` that level (NaN if none fails). ``fail_min``, ``fail_max``,
    ``fail_std`` are the per-seed recall at ``first_fail`` (std over seeds, ddof 0).
    ``stable``: every seed is on the same side of ``threshold`` as the mean at both levels
    (all >= at ``last_ok``, all < at ``first_fail``; a missing level is not checked).
    ``recovers``: some level past ``first_fail`` has a mean recall >= ``threshold`` again
    (the boundary is not a single crossing).

    On the categorical lighting axis ``failing`` lists the lightings with mean recall below
    ``threshold`` (config order), and ``stable`` says every seed agrees with the mean on every
    lighting. ``failing`` is given for numeric axes too (all failing levels).
    """
    rows = []
    for (pipeline, axis), part in table.groupby(["pipeline", "axis"], sort=False):
        numeric = axis in NUMERIC_AXES
        per_level = part.groupby("level", sort=False)["recall"]
        stats = pd.DataFrame(
            {
                "mean": per_level.mean(),
                "min": per_level.min(),
                "max": per_level.max(),
                "std": per_level.std(ddof=0),
            }
        )
        if numeric:
            values = part.groupby("level", sort=False)["level_value"].first()
            stats = stats.assign(value=values).sort_values("value")
        ok = stats["mean"] >= threshold
        agree = np.where(ok, stats["min"] >= threshold, stats["max"] < threshold)
        row = {
            "pipeline": pipeline,
            "axis": axis,
            "last_ok": float("nan"),
            "first_fail": float("nan"),
            "fail_min": float("nan"),
            "fail_max": float("nan"),
            "fail_std": float("nan"),
            "stable": bool(agree.all()),
            "recovers": False,
            "failing": ",".join(stats.index[~ok.to_numpy()]),
        }
        if numeric:
            failing = np.flatnonzero(~ok.to_numpy())
            if len(failing):
                i = int(failing[0])
                first = stats.iloc[i]
                row.update(
                    first_fail=first["value"],
                    fail_min=first["min"],
                    fail_max=first["max"],
                    fail_std=first["std"],
                    recovers=bool(ok.to_numpy()[i + 1 :].any()),
                )
                checked = [i] if i == 0 else [i - 1, i]
                row["last_ok"] = stats["value"].iloc[i - 1] if i > 0 else float("nan")
            else:
                checked = [len(stats) - 1]
                row["last_ok"] = stats["value"].iloc[-1]
            row["stable"] = bool(agree[checked].all())
        rows.append(row)
    out = pd.DataFrame(rows)
    order = {
        "axis": {a: i for i, a in enumerate(AXES)},
        "pipeline": {n: i for i, n in enumerate(dict.fromkeys(table["pipeline"]))},
    }
    return out.sort_values(
        ["pipeline", "axis"], key=lambda c: c.map(order[c.name]), kind="stable"
    ).reset_index(drop=True)


_AXIS_LABELS = {
    "alpha_deg": "alpha (deg), phi 0",
    "phi_deg": "phi (deg)",
    "lighting": "lighting",
    "blur_px": "motion blur (px)",
    "read_noise_e": "read noise (e-)",
    "psf_scale": "lens PSF scale (1: the profile's)",
}


def plot_sweeps(table: pd.DataFrame, path: Path, options: Sequence[str] = ()) -> None:
    """One PNG: recall (top) and median rotation error (bottom, log) against each axis.

    One colour per pipeline (Okabe-Ito; past eight a marker shape tells a repeated colour
    apart): the line is the mean over seeds (dashed for peer detectors), the dots each seed's
    value, so the seed spread is visible; the black dashed line is the 95 % recall threshold.
    The legend stands right of the panels; the title names the run's non-default ``options``.
    Written atomically.
    """
    pipelines = list(dict.fromkeys(table["pipeline"]))
    colours = {p: colour(i) for i, p in enumerate(pipelines)}
    markers = {p: marker(i) for i, p in enumerate(pipelines)}
    axes_present = [a for a in AXES if a in set(table["axis"])]
    fig, grid = plt.subplots(
        2, len(axes_present), figsize=(3.3 * len(axes_present), 6.2), squeeze=False,
        layout="constrained",
    )  # fmt: skip
    for c, axis in enumerate(axes_present):
        part = table[table["axis"] == axis]
        if axis == "lighting":
            categories = list(dict.fromkeys(part["level"]))
            x_of = {name: float(i) for i, name in enumerate(categories)}
            x = part["level"].map(x_of)
        else:
            x = part["level_value"]
        part = part.assign(x=x.to_numpy())
        spread = 0.012 * (part["x"].max() - part["x"].min() or 1.0)
        for k, pipeline in enumerate(pipelines):
            mine = part[part["pipeline"] == pipeline]
            if mine.empty:
                continue
            # Dots are nudged apart per pipeline; mean lines are not (a shifted steep line would
            # show a boundary where there is none); equal lines stay visible as they narrow.
            nudge = (k - (len(pipelines) - 1) / 2) * spread
            width = 1.0 + 2.2 * (len(pipelines) - 1 - k) / max(len(pipelines) - 1, 1)
            # categories are not joined by lines; peers' lines are dashed
            style = "none" if axis == "lighting" else "--" if is_peer(pipeline) else "-"
            for r, column in enumerate(("recall", "rot_err_deg")):
                ax = grid[r, c]
                mean = mine.groupby("x")[column].mean().sort_index()
                label = pipeline if (r, c) == (0, 0) else None
                ax.plot(mean.index, mean.to_numpy(), ls=style, color=colours[pipeline], lw=width,
                        marker=markers[pipeline], ms=2 + 1.5 * width, mfc="none",
                        label=label)  # fmt: skip
                ax.plot(mine["x"] + nudge, mine[column], ".", color=colours[pipeline], ms=3,
                        alpha=0.55)  # fmt: skip
        top, bottom = grid[0, c], grid[1, c]
        top.axhline(RECALL_OK, color="k", ls="--", lw=0.8)
        top.set_ylim(-0.03, 1.03)
        top.set_title(_AXIS_LABELS.get(axis, axis), fontsize=9)
        bottom.set_yscale("log")
        bottom.set_xlabel(_AXIS_LABELS.get(axis, axis), fontsize=8)
        if axis == "lighting":
            for ax in (top, bottom):
                ax.set_xticks(range(len(categories)), categories, fontsize=8)
        for ax in (top, bottom):
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3, lw=0.5)
    grid[0, 0].set_ylabel("recall")
    grid[1, 0].set_ylabel("median rotation error (deg)")
    handles, labels = grid[0, 0].get_legend_handles_labels()
    legend_outside(fig, handles, labels, fontsize=7, title="pipeline", title_fontsize=8)
    title = "Recall and pose error per axis: line = mean over seeds, dots = seeds"
    fig.suptitle(titled(title, options), fontsize=9)
    save(fig, Path(path))


def write_sweeps(
    out_dir: Path, table: pd.DataFrame, config: SweepConfig, pipelines: list[PipelineConfig]
) -> list[Path]:
    """Write the sweep table, its config (``sweep_config.json``: the sweep and the pipelines as
    given; the sweep's ``dictionary`` replaces each pipeline's) and its plot; return the paths.

    The config is a file beside the table, not a table attribute: CSV keeps no attributes.
    """
    out_dir = Path(out_dir)
    with atomic_path(out_dir / "sweeps.csv") as tmp:
        table.to_csv(tmp, index=False)
    record = {"config": config.to_json(), "pipelines": [p.to_json() for p in pipelines]}
    write_json(out_dir / "sweep_config.json", json.loads(json.dumps(record, default=str)))
    plot_sweeps(table, out_dir / "sweeps.png", sweep_options(config))
    return [out_dir / n for n in ("sweeps.csv", "sweep_config.json", "sweeps.png")]

"""Run the detectability study into a folder: cells (resumable), tables, plots, manifest."""

from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import pandas as pd

from bench import report
from bench.atomic import atomic_path, check_writable, write_bytes, write_json
from bench.detectability import Cell, StudyConfig, StudyConfigError, init_worker, run_cell
from bench.executor import run_tasks

PACKAGES = (
    "whiskerbench",
    "mitsuba",
    "drjit",
    "opencv-contrib-python-headless",
    "numpy",
    "pandas",
    "pyarrow",
    "matplotlib",
    "trimesh",
)


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


@dataclass(frozen=True)
class _CellTask:
    config: StudyConfig
    cell: Cell
    out_dir: Path
    save_images: bool


def _run_task(task: _CellTask) -> dict:
    start = time.perf_counter()
    timings = run_cell(task.config, task.cell, task.out_dir, task.save_images)
    timings["cell_s"] = time.perf_counter() - start
    return timings


def _cell_done(out_dir: Path, cell: Cell, config: StudyConfig, save_images: bool) -> bool:
    if not (out_dir / "cells" / f"{cell.key}.parquet").exists():
        return False
    if save_images:
        return len(list((out_dir / "images" / cell.key).glob("*.png"))) == config.images
    return True


def run_study(
    config: StudyConfig,
    out_dir: Path,
    variant: str | None = None,
    workers: int = 1,
    save_images: bool = False,
    progress: bool = True,
) -> dict:
    """Run (or resume) the study into ``out_dir`` and return its manifest.

    Finished cells (``cells/<key>.parquet``) are skipped, so rerunning an interrupted command
    continues it. A folder that holds a study with a different configuration is refused.
    """
    try:
        check_writable(out_dir)
    except ValueError as exc:
        raise StudyConfigError("out", str(exc)) from None
    wall = {}
    t0 = time.perf_counter()
    config_json = json.loads(json.dumps(config.to_json(), default=str))
    config_path = out_dir / "config.json"
    if config_path.exists() and json.loads(config_path.read_text()) != config_json:
        raise StudyConfigError(
            "out",
            f"{out_dir} holds a study with another configuration; "
            "choose another --out or delete that folder",
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(config_path, config_json)

    # --- Cells
    cells = config.cells()
    todo = [c for c in cells if not _cell_done(out_dir, c, config, save_images)]
    threads = 1 if workers > 1 else None
    chosen = init_worker(variant)  # recorded in the manifest; workers are given the same
    stage = {"render_s": 0.0, "response_s": 0.0, "detect_s": 0.0}
    t_cells = time.perf_counter()
    tasks = [_CellTask(config, c, out_dir, save_images) for c in todo]
    for timings in run_tasks(
        _run_task,
        tasks,
        workers,
        init_worker,
        (chosen, threads),
        desc="detectability cells",
        progress=progress,
    ):
        for key in stage:
            stage[key] += timings[key]
    wall["cells_s"] = time.perf_counter() - t_cells

    # --- Tables
    t_tab = time.perf_counter()
    images = pd.concat(
        [pd.read_parquet(out_dir / "cells" / f"{c.key}.parquet") for c in cells], ignore_index=True
    )
    images = images.sort_values(report.CELL_KEYS + ["image_index"], kind="stable")
    with atomic_path(out_dir / "images.parquet") as tmp:
        images.to_parquet(tmp, index=False)
    summary = report.summarize(images)
    write_bytes(out_dir / "summary.csv", report.summary_to_csv_bytes(summary))
    max_phi = report.max_phi(summary)
    write_bytes(out_dir / "max_phi.csv", report.summary_to_csv_bytes(max_phi))
    wall["tables_s"] = time.perf_counter() - t_tab

    # --- Plots
    t_plot = time.perf_counter()
    for name, plot, table in (
        ("max_phi.png", report.plot_max_phi, max_phi),
        ("heatmap.png", report.plot_heatmap, summary),
        ("pose_error.png", report.plot_pose_error, summary),
    ):
        with atomic_path(out_dir / name) as tmp:
            plot(table, tmp)
    wall["plots_s"] = time.perf_counter() - t_plot
    wall["total_s"] = time.perf_counter() - t0

    # --- Manifest
    n_new = len(todo) * config.images
    manifest = {
        "study": "detectability",
        "config": config_json,
        "seed": config.seed,
        "variant": chosen,
        "versions": package_versions(),
        "workers": workers,
        "cells_total": len(cells),
        "cells_computed": len(todo),
        "cells_resumed": len(cells) - len(todo),
        "images_computed": n_new,
        "wall_s": {k: round(v, 3) for k, v in wall.items()},
        "stage_cpu_s": {k: round(v, 3) for k, v in stage.items()},
        "images_per_s": round(n_new / wall["cells_s"], 1) if n_new else None,
    }
    write_json(out_dir / "manifest.json", manifest)
    return manifest

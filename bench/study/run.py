"""Run the detectability study into a folder: cells (resumable), tables, plots, manifest.

The grid's tilts run first; then, per (lighting, PSF scale, size, alpha), a tilt halfway between
the largest passing and the next failing tilt is added, round after round, until the bracket is
no wider than ``phi_resolution_deg``. A cell's geometry is rendered once for every scale that
needs it.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq

from bench.common.atomic import atomic_path, write_bytes, write_json
from bench.common.executor import TaskPool, effective_executor
from bench.common.manifest import hash_files
from bench.common.resumable import finish_run, open_run
from bench.common.units import DAMAGED, DONE
from bench.study import report
from bench.study.cells import cell_state, init_study_worker, run_cell
from bench.study.config import Cell, StudyConfig, StudyConfigError, nondefault_options
from renderers.marker_renderer import MarkerRenderer
from renderers.variant import init_worker


@dataclass(frozen=True)
class _CellTask:
    config: StudyConfig
    cell: Cell
    scales: tuple[float, ...]
    out_dir: Path
    save_images: bool


def _run_task(task: _CellTask, renderer: MarkerRenderer) -> tuple[_CellTask, dict]:
    start = time.perf_counter()
    timings = run_cell(
        task.config, task.cell, renderer, task.out_dir, task.scales, task.save_images
    )
    timings["cell_s"] = time.perf_counter() - start
    return task, timings


def _cell_path(out_dir: Path, cell: Cell, scale: float) -> Path:
    return out_dir / "cells" / f"{cell.output_name(scale)}.parquet"


def _refinement_cells(
    config: StudyConfig, rates: pd.DataFrame
) -> list[tuple[Cell, tuple[float, ...]]]:
    """Tilts to add: halfway between each group's largest passing and next failing tilt."""
    wanted: dict[Cell, list[float]] = {}
    keys = ["lighting", "psf_scale", "size_mm", "alpha_deg"]
    for (lighting, scale, size, alpha), group in rates.groupby(keys, sort=True):
        group = group.sort_values("phi_deg")
        passing = group.loc[report.passes(group["rate"]), "phi_deg"]
        if passing.empty:
            continue
        best = float(passing.max())
        above = group.loc[group["phi_deg"] > best, "phi_deg"]
        if above.empty or float(above.min()) - best <= config.phi_resolution_deg + 1e-9:
            continue
        phi = round((best + float(above.min())) / 2.0, 6)
        wanted.setdefault(Cell(lighting, size, alpha, phi), []).append(scale)
    return [(cell, tuple(sorted(scales))) for cell, scales in wanted.items()]


def _rates(
    out_dir: Path, done: list[tuple[Cell, float]], known: dict[tuple[Cell, float], float]
) -> pd.DataFrame:
    """Detection rate of every finished cell: from this run's results, else from its file."""
    rows = []
    for cell, scale in done:
        if (cell, scale) not in known:  # resumed: computed by an earlier run
            path = _cell_path(out_dir, cell, scale)
            table = pd.read_parquet(path, columns=["id_ok", "backend_failed"])
            known[(cell, scale)] = float(table["id_ok"][~table["backend_failed"]].mean())
        rows.append(
            {
                "lighting": cell.lighting,
                "psf_scale": scale,
                "size_mm": cell.size_mm,
                "alpha_deg": cell.alpha_deg,
                "phi_deg": cell.phi_deg,
                "rate": known[(cell, scale)],
            }
        )
    return pd.DataFrame(rows)


def _backend_failures(summary: pd.DataFrame) -> dict[str, int]:
    """The cells (``<key>_x<scale>``) on whose images the detector's worker crashed: how many."""
    failed = summary[summary["backend_failures"] > 0]
    return {
        Cell(r.lighting, r.size_mm, r.alpha_deg, r.phi_deg).output_name(r.psf_scale): int(
            r.backend_failures
        )
        for r in failed.itertuples()
    }


def run_study(
    config: StudyConfig,
    out_dir: Path,
    variant: str | None = None,
    workers: int = 1,
    save_images: bool = False,
    progress: bool = True,
    inputs: dict[str, str] | None = None,
    executor: str = "pool",
    scheduler: str | None = None,
) -> dict:
    """Run (or resume) the study into ``out_dir`` and return its manifest.

    Finished cells (``cells/<key>_x<scale>.parquet``) whose record verifies are skipped, so
    rerunning an interrupted command continues it; a damaged one is computed again (named in
    the manifest's ``units_redone``). The folder is locked for the whole run; a folder that is
    locked, holds another command's output, or cells of a study with a different configuration
    (by its manifest, lock file or any cell's record) is refused (StudyConfigError on ``out``)
    before anything is written.
    ``inputs`` (path: SHA-256, e.g. the camera profile's file) go into the manifest. The cells
    run on ``executor`` (:class:`~bench.common.executor.TaskPool`), recorded in the manifest but
    not in the settings: any executor resumes the folder.
    """
    out_dir = Path(out_dir)
    wall = {}
    t0 = time.perf_counter()
    config_json = json.loads(json.dumps(config.to_json(), default=str))
    try:
        run = open_run(
            out_dir, "detectability", config_json, config.settings_hash(), units="cells/*",
            written=("", "cells", "images", "images/*"),
        )  # fmt: skip
    except ValueError as exc:
        raise StudyConfigError("out", str(exc)) from None
    with run:  # the folder stays locked until the manifest is written
        settings = run.settings_sha256
        write_json(out_dir / "config.json", config_json)

        # --- Cells: the grid, then refinement rounds between the last pass and the first fail
        threads = None if effective_executor(executor, workers, scheduler) == "inline" else 1
        chosen = init_worker(variant)  # recorded in the manifest; workers are given the same
        stage = {"render_s": 0.0, "optics_s": 0.0, "sensor_s": 0.0, "detect_s": 0.0}
        t_cells = time.perf_counter()
        plan = [(cell, config.psf_scales) for cell in config.cells()]
        done: list[tuple[Cell, float]] = []
        known: dict[tuple[Cell, float], float] = {}
        computed = rounds = 0
        setup_args = (config, chosen, threads)
        with TaskPool(workers, init_study_worker, setup_args, executor, scheduler) as pool:
            ran_on = pool.describe()
            while plan:
                tasks = []
                # Large markers first: they pass, and passing cells draw the most images, so the
                # long tasks start early and the workers finish together.
                for cell, scales in sorted(plan, key=lambda item: -item[0].size_mm):
                    states = {s: cell_state(out_dir, cell.output_name(s), settings) for s in scales}
                    run.redone += [cell.output_name(s) for s, v in states.items() if v == DAMAGED]
                    todo = tuple(s for s in scales if states[s] != DONE)
                    if todo:
                        tasks.append(_CellTask(config, cell, todo, out_dir, save_images))
                desc = "detectability cells" if rounds == 0 else f"refining tilts (round {rounds})"
                for task, timings in pool.map(_run_task, tasks, desc=desc, progress=progress):
                    for key in stage:
                        stage[key] += timings[key]
                    computed += len(timings["images"])
                    known.update({(task.cell, s): r for s, r in timings["rates"].items()})
                done += [(cell, s) for cell, scales in plan for s in scales]
                plan = _refinement_cells(config, _rates(out_dir, done, known))
                rounds += 1
        wall["cells_s"] = time.perf_counter() - t_cells

        # --- Tables
        t_tab = time.perf_counter()
        images = pq.read_table([str(_cell_path(out_dir, c, s)) for c, s in done]).to_pandas()
        images = images.sort_values(report.CELL_KEYS + ["image_index"], kind="stable")
        images.insert(0, "detector", config.detector.backend)
        with atomic_path(out_dir / "images.parquet") as tmp:
            images.to_parquet(tmp, index=False)
        refinements = report.refinements_of(config.detector.backend)
        summary = report.summarize(images, refinements=refinements)
        summary.insert(0, "detector", config.detector.backend)
        write_bytes(out_dir / "summary.csv", report.summary_to_csv_bytes(summary))
        max_phi = report.max_phi(summary)
        write_bytes(out_dir / "max_phi_by_scale.csv", report.summary_to_csv_bytes(max_phi))
        band = report.band(max_phi)
        write_bytes(out_dir / "max_phi.csv", report.summary_to_csv_bytes(band))
        counts = images.groupby(report.CELL_KEYS).size()
        images_used = {
            Cell(lg, sz, al, ph).output_name(sc): int(n)
            for (lg, sc, sz, al, ph), n in counts.items()
        }
        wall["tables_s"] = time.perf_counter() - t_tab

        # --- Plots (pyplot loaded here, not in the pool's workers, which import this module
        # for _run_task: 0.2-0.3 s a worker)
        from bench.study import plots as report_plots

        t_plot = time.perf_counter()
        detector = {"detector": config.detector_label, "options": nondefault_options(config)}
        for name, plot, table, options in (
            ("max_phi.png", report_plots.plot_max_phi, max_phi, detector),
            ("heatmap.png", report_plots.plot_heatmap, summary, detector),
            ("pose_error.png", report_plots.plot_pose_error, summary,
             {**detector, "refinements": refinements}),
        ):  # fmt: skip
            with atomic_path(out_dir / name) as tmp:
                plot(table, tmp, **options)
        wall["plots_s"] = time.perf_counter() - t_plot
        wall["total_s"] = time.perf_counter() - t0

        # --- Manifest
        n_images = int(sum(images_used.values()))
        tables = ["images.parquet", "summary.csv", "max_phi_by_scale.csv", "max_phi.csv"]
        plots = ["max_phi.png", "heatmap.png", "pose_error.png"]
        return finish_run(
            run,
            seed=config.seed,
            variant=chosen,
            inputs=inputs,
            outputs=hash_files([out_dir / n for n in ["config.json", *tables, *plots]], out_dir),
            study="detectability",
            detector=config.detector.backend,
            family=config.dictionary,
            backend_failures=_backend_failures(summary),
            camera_profile=config.camera.name,
            psf_scales=list(config.psf_scales),
            **ran_on,
            cells_total=len(done),
            cells_computed=computed,
            cells_resumed=len(done) - computed,
            refinement_rounds=rounds - 1,
            images_total=n_images,
            images_per_cell=dict(sorted(images_used.items())),
            wall_s={k: round(v, 3) for k, v in wall.items()},  # the phases, with total_s
            stage_cpu_s={k: round(v, 3) for k, v in stage.items()},
            images_per_s=round(n_images / wall["cells_s"], 1) if computed else None,
        )

"""The study ladder: the sensitive cells rendered and scored through the study's own code.

A task is one cell under one render (spp, integrator, region): it renders once
(:func:`bench.study.cells.render_cell`), then, for every rung sharing that render (the
reference and its camera-stage rungs), draws and scores the cell's images with that rung's
profile (:func:`bench.study.cells.run_cell`) into ``study/<rung>/cells/``. A rung's cell is
finished when its ``timing/<cell>.json`` (written last: a unit record of the ladder's settings
and the cell file's hash, :mod:`bench.common.units`) verifies, so a rerun skips it.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from bench.common.manifest import sha256
from bench.common.units import DONE, unit_state, write_unit
from bench.evaluate.score import finite_median
from bench.ladder.config import LadderConfig
from bench.ladder.rungs import Rung, render_groups, stage_off
from bench.study.cells import render_cell, run_cell
from bench.study.config import Cell, StudyConfig
from bench.study.report import wilson_interval
from renderers.marker_renderer import MarkerRenderer
from renderers.variant import init_worker

#: The corners and poses compared: the project's own ``lines`` refinement of OpenCV's corners.
REFINEMENT = "lines"


def study_config(config: LadderConfig) -> StudyConfig:
    """The study's config for the ladder's cells (its default camera, detector and exposure)."""
    cells = config.cells
    return StudyConfig(
        sizes_mm=tuple(sorted({c.size_mm for c in cells})),
        alphas_deg=tuple(sorted({c.alpha_deg for c in cells})),
        phis_deg=tuple(sorted({c.phi_deg for c in cells})),
        lightings=tuple(sorted({c.lighting for c in cells})),
        images=config.images,
        seed=config.seed,
        spp=config.reference_spp,
    )


@dataclass(frozen=True)
class StudyTask:
    """One cell, one render, the rungs drawn from it (picklable)."""

    config: LadderConfig
    cell: Cell
    rungs: tuple[Rung, ...]
    out_dir: Path
    settings: str  # the ladder's settings hash, in each rung's record


def _renderer(study: StudyConfig, options: dict, cache: dict) -> MarkerRenderer:
    """One renderer per (spp, integrator, depth) in a worker: a loaded scene serves many cells."""
    key = (options["spp"], options["integrator"], options["path_depth"])
    if key not in cache:
        cache[key] = MarkerRenderer(
            study.camera.lens,
            study.dictionary,
            study.marker_id,
            key[0],
            integrator=options["integrator"],
            path_depth=max(1, key[2]),
        )
    return cache[key]


def init_ladder_worker(variant: str | None) -> dict:
    """A worker's set-up: the Mitsuba variant, and an empty cache of renderers."""
    init_worker(variant)
    return {}


def timing_path(out_dir: Path, rung: Rung, cell: Cell) -> Path:
    return out_dir / "study" / rung.key / "timing" / f"{cell.key}.json"


def run_study_task(task: StudyTask, cache: dict) -> StudyTask:
    """Render the cell once and score it for each rung that is not finished."""
    options = task.rungs[0].options
    study = study_config(task.config)
    study = dataclasses.replace(study, seed=study.seed + options["seed_offset"])
    renderer = _renderer(study, options, cache)
    render = render_cell(
        renderer, task.cell, study.seed, study.distance_mm, study.camera.crop_grid_px,
        full_frame=options["full_frame"],
    )  # fmt: skip
    for rung in task.rungs:
        stage = rung.options["stage_off"]
        camera = stage_off(study.camera, stage) if stage else study.camera
        rung_study = dataclasses.replace(study, camera=camera)
        folder = task.out_dir / "study" / rung.key
        t0 = time.perf_counter()
        timings = run_cell(rung_study, task.cell, renderer, folder, (1.0,), render=render)
        images = int(sum(timings["images"].values()))
        scored_s = time.perf_counter() - t0
        name = task.cell.output_name(1.0)
        cell_file = folder / "cells" / f"{name}.parquet"
        record = {"render_s": render.render_s, "score_s": scored_s, "images": images}
        record |= {"unit": f"{rung.key}/{task.cell.key}", "settings_sha256": task.settings}
        write_unit(
            timing_path(task.out_dir, rung, task.cell),
            {**record, "files": {f"../cells/{cell_file.name}": sha256(cell_file)}},
        )
    return task


def rung_state(out_dir: Path, rung: Rung, cell: Cell, settings: str) -> str:
    """Whether a rung's cell is done and intact (:func:`bench.common.units.unit_state`)."""
    path = timing_path(out_dir, rung, cell)
    return unit_state(path, settings, {"unit": f"{rung.key}/{cell.key}"})


def study_tasks(config: LadderConfig, rungs: list[Rung], out_dir: Path) -> list[StudyTask]:
    """Tasks for the unfinished (rung, cell) pairs, grouped by render, costly renders first."""
    tasks, settings = [], config.settings_hash()
    for group in render_groups(rungs):
        for cell in config.cells:
            todo = tuple(r for r in group if rung_state(out_dir, r, cell, settings) != DONE)
            if todo:
                tasks.append(StudyTask(config, cell, todo, out_dir, settings))
    return sorted(
        tasks, key=lambda t: (-t.rungs[0].options["full_frame"], -t.rungs[0].options["spp"])
    )


def study_outcomes(config: LadderConfig, rung: Rung, out_dir: Path) -> list[dict]:
    """One row per cell of a finished rung: rate and its Wilson interval, errors, seconds."""
    rows = []
    for cell in config.cells:
        folder = out_dir / "study" / rung.key
        timing = json.loads(timing_path(out_dir, rung, cell).read_text())
        table = pd.read_parquet(folder / "cells" / f"{cell.output_name(1.0)}.parquet")
        scored = table[~table["backend_failed"]]
        k, n = int(scored["id_ok"].sum()), len(scored)
        lo, hi = wilson_interval(k, n)
        rows.append(
            {
                "cell": cell.key,
                "n": n,
                "rate": k / n if n else float("nan"),
                "rate_lo": float(lo),
                "rate_hi": float(hi),
                "corner_err_px": finite_median(table[f"corner_err_px_{REFINEMENT}"]),
                "rot_err_deg": finite_median(table[f"rot_err_deg_{REFINEMENT}"]),
                "trans_err_mm": finite_median(table[f"trans_err_mm_{REFINEMENT}"]),
                "wall_s": timing["render_s"] + timing["score_s"],
            }
        )
    return rows

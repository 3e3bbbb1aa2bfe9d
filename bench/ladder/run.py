"""Run the ladder into a folder: rungs (resumable), then rungs.csv, defaults.csv, table.md,
ladder.png and the manifest (written last, via :mod:`bench.common.resumable`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pandas as pd

from bench.common.atomic import atomic_path, write_bytes, write_json
from bench.common.executor import TaskPool
from bench.common.manifest import hash_files
from bench.common.resumable import ResumableRun, finish_run, open_run
from bench.common.units import payload
from bench.ladder import report, study_part, video_part
from bench.ladder.config import LadderConfig, ladder_options
from bench.ladder.rungs import Rung, study_rungs, video_rungs
from scenes.profile import load_profile

OUTPUTS = ("rungs.csv", "defaults.csv", "table.md", "ladder.png")


def plan(config: LadderConfig) -> list[Rung]:
    """Every rung of the parts asked for (a camera stage already off has none)."""
    rungs = []
    if "study" in config.parts:
        profile = study_part.study_config(config).camera
        rungs += study_rungs(config, profile)
    if "video" in config.parts:
        profile = load_profile(config.profile)
        rungs += video_rungs(config, profile)
    return rungs


def _rows(config: LadderConfig, rungs: list[Rung], out_dir: Path) -> pd.DataFrame:
    rows = []
    for rung in rungs:
        base = {"part": rung.part, "axis": rung.axis, "rung": rung.name}
        if rung.part == "study":
            for cell in study_part.study_outcomes(config, rung, out_dir):
                rows.append({**base, **cell, "n_images": cell["n"]})
        else:
            result = payload(json.loads(video_part.result_path(out_dir, rung).read_text()))
            rows.append({**base, "cell": "clip", **result, "n_images": result["frames"]})
    return pd.DataFrame(rows)


#: The ladder's unit records (a rung's cell's timing, a video rung's result) and the folders
#: it writes.
UNITS = ("study/*/timing/*.json", "video/*/result.json")
WRITTEN = ("", "study", "study/*", "study/*/cells", "study/*/timing", "video", "video/*")


def open_ladder(config: LadderConfig, out_dir: Path) -> ResumableRun:
    """Claim and lock ``out_dir`` for this ladder (until the returned run is closed): a folder
    that is locked, holds another command's output or another ladder (by its manifest, lock
    file or any rung's record) is refused (ValueError naming it) before anything is written."""
    settings = config.settings_hash()
    return open_run(Path(out_dir), "ladder", config.to_json(), settings, UNITS, WRITTEN)


def run_ladder(
    config: LadderConfig,
    out_dir: Path,
    workers: int = 1,
    progress: bool = True,
    variant: str | None = None,
    run: ResumableRun | None = None,
) -> dict:
    """Run (or resume) the ladder into ``out_dir``; return its manifest. Finished rungs whose
    records verify are skipped; ``run``: the folder as :func:`open_ladder` claimed it (the
    caller closes it), else claimed here and released at the end."""
    if run is None:
        with open_ladder(config, out_dir) as run:
            return run_ladder(config, out_dir, workers, progress, variant, run)
    out_dir = Path(out_dir)
    rungs = plan(config)
    t0 = time.perf_counter()
    study = [r for r in rungs if r.part == "study"]
    video = [r for r in rungs if r.part == "video"]
    tasks: list = study_part.study_tasks(config, study, out_dir)
    tasks += video_part.video_tasks(config, video, out_dir)
    computed = len(tasks)
    with TaskPool(workers, study_part.init_ladder_worker, (variant,)) as pool:
        ran_on = pool.describe()
        for _ in pool.map(_run_task, tasks, desc="ladder", progress=progress, unit="task"):
            pass
    rungs_s = time.perf_counter() - t0

    # --- Tables and chart
    cells = _rows(config, rungs, out_dir)
    per_rung = report.per_rung(cells)
    flags = per_rung.set_index(["part", "axis", "rung"])["matches_reference"]
    keys = zip(cells["part"], cells["axis"], cells["rung"], strict=True)
    cells["matches_reference"] = [bool(flags[key]) for key in keys]
    defaults = report.defaults_table(per_rung)
    write_bytes(out_dir / "rungs.csv", cells.to_csv(index=False).encode())
    write_bytes(out_dir / "defaults.csv", defaults.to_csv(index=False).encode())
    write_bytes(out_dir / "table.md", report.markdown(per_rung, defaults).encode())
    with atomic_path(out_dir / "ladder.png") as tmp:
        report.plot(per_rung, defaults, tmp, ladder_options(config))
    write_json(out_dir / "config.json", config.to_json())
    return finish_run(
        run,
        seed=config.seed,
        outputs=hash_files([out_dir / n for n in ("config.json", *OUTPUTS)], out_dir),
        **ran_on,
        rungs_total=len(rungs),
        tasks_computed=computed,
        wall_s={"rungs_s": round(rungs_s, 3), "total_s": round(time.perf_counter() - t0, 3)},
    )


def _run_task(task, cache: dict):
    if isinstance(task, study_part.StudyTask):
        return study_part.run_study_task(task, cache)
    return video_part.run_video_task(task, cache)

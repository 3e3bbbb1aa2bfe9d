"""``whiskerbench compare``: pipeline variants by accuracy and speed, in one run, as a report.

Per variant, measured in the same run on this machine:

* **speed**: frames/s of detection and pose on frames of the dataset compared, one OpenCV
  thread: runs of consecutive frames spread evenly over its samples, the variants alternating,
  in repeated rounds; the median over rounds and the slowest and fastest round
  (:mod:`bench.evaluate.timing`, ``docs/speed.md``; the frames in ``speed_frames.csv``, each
  round in ``speed_rounds.csv``);
* **accuracy on the dataset**: :func:`bench.score.score_dataset` on every sample (branch outcome
  with the none-twin threshold, marker recall, deflection, corner and pose errors);
* **failure boundaries**: detection recall and pose error against angular position, marker tilt,
  lighting, motion blur, sensor noise and lens sharpness (the camera profile's band of PSF
  scales), over several seeds (:mod:`bench.evaluate.sweeps`); the boundary axes again with the
  base point's PSF at each end of the band, so the report can say which leads hold across the
  lens' uncertain blur (:mod:`bench.evaluate.band`).

Peer detectors (the ``locus`` and ``apriltag`` presets, any ``/detector=`` variant) run like
every other pipeline; the report opens with who leads on each measure, peers beside the
project's pipelines (:mod:`bench.evaluate.leaders`, also ``leaders.csv``).

The report (``report.md`` with PNG charts beside it) opens without a server. Per-sample outputs
(detections tables and plots: bulk data) go to ``<dataset>/scores/<variant>/``, not beside the
report.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import time
from pathlib import Path

import cv2
import pandas as pd

from bench.common.atomic import atomic_path, write_bytes
from bench.common.executor import TaskPool, effective_executor
from bench.common.manifest import (
    RunClock,
    build_manifest,
    claim,
    hash_files,
    write_manifest,
)
from bench.evaluate.band import band_section
from bench.evaluate.leaders import is_peer, leader_lines, leaders, spread_verdict
from bench.evaluate.pareto import plot_pareto
from bench.evaluate.timing import (
    RUN_FRAMES,
    SPEED_FRAMES,
    SPEED_ROUNDS,
    dataset_runs,
    one_opencv_thread,
    runs_table,
    speed_figures,
    speed_of,
    time_pipelines,
)
from pipeline.presets import PipelineConfig
from renderers.variant import init_worker

#: The backend's own pose errors in the scores (NaN for OpenCV, which has none).
OWN_POSE = ("own_rot_err_deg", "own_trans_err_mm")


def summarize(name: str, table: pd.DataFrame) -> dict:
    """One variant's dataset accuracy from its ``samples.csv`` table.

    A refused sample counts as not correct. A variant that refuses every sample has no rate
    and no error (NaN; a correct rate of 0 would rank it with one that answers every sample
    wrongly): its row keeps the counts, ``samples`` and ``refused_samples``, which say why."""
    refused = int((table["outcome"] == "refused").sum())
    visible = table["markers_visible"].sum()  # 0 when every sample is refused
    return {
        "pipeline": name,
        "samples": len(table),
        "correct_rate": float((table["outcome"] == "correct").mean())
        if refused < len(table)
        else float("nan"),
        "false_positive_samples": int(table["outcome"].str.contains("false_positive").sum()),
        "false_negative_samples": int(table["outcome"].str.contains("false_negative").sum()),
        "refused_samples": refused,
        "recall": float(table["markers_found"].sum() / visible) if visible else float("nan"),
        "false_detections": int(table["false_detections"].sum()),
        "deflection_err_mm": float(table["deflection_err_mm"].median()),
        "corner_err_px": float(table["corner_err_px"].median()),
        "rot_err_deg": float(table["rot_err_deg"].median()),
        "trans_err_mm": float(table["trans_err_mm"].median()),
        # the backend's own pose (NaN for OpenCV) and its crashes, where the scores have them
        **{c: float(table[c].median()) for c in OWN_POSE if c in table},
        **{c: int(table[c].sum()) for c in ("failed_frames",) if c in table},
    }


def run_compare(
    dataset: Path,
    pipelines: list[PipelineConfig],
    out_dir: Path,
    sweep=None,
    speed_frames: int = SPEED_FRAMES,
    speed_rounds: int = SPEED_ROUNDS,
    variant: str | None = None,
    workers: int = 1,
    executor: str = "pool",
    scheduler: str | None = None,
) -> pd.DataFrame:
    """Measure every variant (speed, dataset accuracy, sweeps) and write the report.

    Speed: up to ``speed_frames`` frames of the dataset timed, the pipelines alternating,
    ``speed_rounds`` rounds (:mod:`bench.evaluate.timing`), after the dataset is verified.
    Before anything is written a peer that is not installed
    (:class:`pipeline.backends.BackendUnavailableError`) or a pipeline whose backend cannot
    detect the sweeps' or the dataset's family (ValueError) is refused; then the report
    folder and every variant's score folder are claimed (ValueError if another command's) and
    the dataset is verified, once (DatasetIntegrityError naming the file); ``manifest.json``
    is written last. Scoring and sweeps run their tasks on ``executor``
    (:class:`~bench.common.executor.TaskPool`), recorded in the manifest.
    """
    from bench.dataset.verify import verify_dataset
    from bench.evaluate.band import band_end_boundaries, sweep_band_values
    from bench.evaluate.score import dataset_family, dataset_psf_scale, for_family, score_dataset
    from bench.evaluate.sweep_config import SweepConfig
    from bench.evaluate.sweep_report import boundaries, write_sweeps
    from bench.evaluate.sweeps import run_sweeps, sweep_pipelines

    dataset, out_dir = Path(dataset), Path(out_dir)
    sweep = sweep or SweepConfig()
    names = [p.name for p in pipelines]
    if len(set(names)) != len(names) or not names:
        raise ValueError(f"--pipelines: need distinct names, got {names}")
    sweep_pipelines(pipelines, sweep)  # a missing peer or a family it cannot detect: refused now
    family = dataset_family(dataset)
    # the dataset's family too, before any claim; timed as they score, keyed by name
    detecting = {p.name: for_family(p, family) for p in pipelines}
    clock = RunClock()
    claim(out_dir, "compare")
    for pipeline in pipelines:
        claim(dataset / "scores" / pipeline.folder_name, "score")
    verified = verify_dataset(dataset)  # every file hashed once, before the speed frames
    chosen = init_worker(variant)
    t_start = time.perf_counter()
    runs = dataset_runs(dataset, speed_frames)
    timing = time_pipelines(runs, detecting, speed_rounds)
    timed = runs_table(runs)
    del runs
    speed = speed_figures(timing.rounds)
    # one pool scores every pipeline: a Dask cluster or worker processes start once
    pool = TaskPool(workers, executor=executor, scheduler=scheduler)
    with pool, one_opencv_thread():
        rows, tables = [], {}
        for pipeline in pipelines:
            scores = dataset / "scores" / pipeline.folder_name
            table = score_dataset(dataset, pipeline, scores, verified, pool=pool)
            tables[pipeline.name] = table
            rows.append({**summarize(pipeline.name, table), **speed_of(speed, pipeline.name)})
    summary = pd.DataFrame(rows)
    pool_options = {"workers": workers, "executor": executor, "scheduler": scheduler}
    t_sweeps = time.perf_counter()
    sweeps = run_sweeps(pipelines, sweep, variant, **pool_options)
    t_band = time.perf_counter()
    band_tables = {  # the boundary axes again, the base point's PSF at each band end
        end.base_psf_scale: run_sweeps(pipelines, end, variant, **pool_options)
        for end in sweep.band_end_sweeps()
    }
    band_s = time.perf_counter() - t_band
    edges = boundaries(sweeps)
    band_edges = band_end_boundaries(band_tables)
    band = sweep_band_values(sweeps, band_edges, tuple(band_tables)) if band_tables else None
    leads = leaders(summary, edges, band)

    out_dir.mkdir(parents=True, exist_ok=True)
    written = write_sweeps(out_dir, sweeps, sweep, pipelines)
    frames = [("summary", summary), ("boundaries", edges), ("leaders", leads)]
    frames += [("speed_frames", timed), ("speed_rounds", timing.rounds)]
    if band_tables:
        frames += [
            ("sweeps_band_ends", pd.concat(band_tables.values(), ignore_index=True)),
            ("boundaries_band_ends", band_edges),
        ]
    for name, frame in frames:
        with atomic_path(out_dir / f"{name}.csv") as tmp:
            frame.to_csv(tmp, index=False)
        written.append(out_dir / f"{name}.csv")
    plot_pareto(summary, out_dir / "pareto.png")
    grids = _copy_grids(dataset, pipelines, out_dir)
    meta = {
        "dataset": str(dataset),
        "samples": int(summary["samples"].iloc[0]),
        "variant": chosen,
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "opencv": cv2.__version__,
        "wall_s": time.perf_counter() - t_start,
        "speed": {
            "frames": int(timed["timed"].sum()),
            "runs": int(timed["run"].nunique()),
            "samples": int(timed["sample_id"].nunique()),
            "rounds": speed_rounds,
        },
        "dataset_psf_scale": dataset_psf_scale(dataset),
        "band": None
        if not band_tables
        else {
            "range": sweep.band_ends,
            "ends": tuple(band_tables),
            "sweeps_s": t_band - t_sweeps,
            "band_sweeps_s": band_s,
            "seeds": sweep.seeds,
            "band_seeds": sweep.band_seeds,
            "images": sweep.images,
            "base": f"alpha {sweep.base_alpha_deg:g} deg, phi {sweep.base_phi_deg:g} deg, "
            f"{sweep.base_lighting}",
        },
    }
    report = render_report(summary, tables, edges, leads, grids, meta)
    write_bytes(out_dir / "report.md", report.encode())
    written += [out_dir / "pareto.png", out_dir / "report.md"]
    written += [out_dir / "grids" / n for names in grids.values() for n in names]
    config = {
        "dataset": str(dataset),
        "pipelines": [p.to_json() for p in pipelines],
        "sweep": sweep.to_json(),  # also in sweep_config.json, beside the sweep table
        "speed_frames": speed_frames,
        "speed_rounds": speed_rounds,
        "speed_run_frames": RUN_FRAMES,
    }
    record = build_manifest(
        "compare",
        clock,
        config,
        variant=chosen,
        inputs=verified.inputs(),
        outputs=hash_files(written, out_dir),
        cpu_count=meta["cpu_count"],
        machine=meta["machine"],
        executor=effective_executor(executor, workers, scheduler),
        workers=workers,
        scheduler=scheduler,
    )
    write_manifest(out_dir, record)
    return summary


def _copy_grids(dataset: Path, pipelines: list[PipelineConfig], out_dir: Path) -> dict:
    """Each variant's results grids, copied beside the report: {variant: [file names]}."""
    grids = {}
    for pipeline in pipelines:
        folder = pipeline.folder_name
        names = []
        for grid in sorted((dataset / "scores" / folder).glob("grid-*.png")):
            name = f"{folder}-{grid.name}"
            write_bytes(out_dir / "grids" / name, grid.read_bytes())
            names.append(name)
        grids[pipeline.name] = names
    stale = {p.name for p in (out_dir / "grids").glob("*.png")} - {
        n for names in grids.values() for n in names
    }
    for name in stale:  # grids of variants no longer compared would mislead
        (out_dir / "grids" / name).unlink()
    if not any(grids.values()) and (out_dir / "grids").is_dir():
        shutil.rmtree(out_dir / "grids")
    return grids


def _markdown_table(frame: pd.DataFrame, floats: str = "{:.3g}") -> str:
    cells = [
        [floats.format(v) if isinstance(v, float) else str(v) for v in row]
        for row in frame.itertuples(index=False)
    ]
    head = "| " + " | ".join(frame.columns) + " |\n|" + "---|" * len(frame.columns) + "\n"
    return head + "".join("| " + " | ".join(row) + " |\n" for row in cells)


def render_report(
    summary: pd.DataFrame,
    tables: dict[str, pd.DataFrame],
    edges: pd.DataFrame,
    leads: pd.DataFrame,
    grids: dict[str, list[str]],
    meta: dict,
) -> str:
    """The report's Markdown: who leads, the figures, the tables, where each variant fails."""
    columns = [
        "pipeline",
        "fps",
        "fps_min",
        "fps_max",
        "correct_rate",
        "recall",
        "deflection_err_mm",
        "corner_err_px",
        "rot_err_deg",
        "trans_err_mm",
        *[c for c in (*OWN_POSE, "failed_frames") if c in summary],
        "false_positive_samples",
        "false_negative_samples",
        "refused_samples",
        "false_detections",
    ]
    lines = [
        "# Pipeline comparison",
        "",
        f"Dataset `{meta['dataset']}` ({meta['samples']} samples); speed on its own frames "
        "(below), one OpenCV thread; "
        f"{meta['cpu_count']} cores, OpenCV {meta['opencv']}, Mitsuba variant {meta['variant']}; "
        f"the whole comparison took {meta['wall_s']:.0f} s.",
        "",
        "## Who leads",
        "",
        "Per measure, the leading pipeline, the best of the project's pipelines and the best "
        "peer detector (`leaders.csv`); failure boundaries: how far recall stays >= 95 %.",
        "",
        *[f"- {line}" for line in leader_lines(leads)],
        *[f"- {line}" for line in failed_frame_lines(tables)],
        *[f"- {line}" for line in refused_lines(summary)],
        "",
        *band_section(leads, meta),
        "## Accuracy against speed",
        "",
        *speed_section(leads, meta["speed"]),
        "![accuracy against speed](pareto.png)",
        "",
        _markdown_table(summary[columns]),
        "## Where each variant fails: recall and pose error against the imaging conditions",
        "",
        "Each axis varies one condition from a base point; dots are single seeds, lines their "
        "mean, so a boundary whose seeds disagree is visible as spread.",
        "",
        "![sweeps](sweeps.png)",
        "",
        _markdown_table(edges),
        "## Samples each variant gets wrong",
        "",
    ]
    for name, table in tables.items():
        wrong = table[table["outcome"] != "correct"]
        lines.append(f"### {name}: {len(table) - len(wrong)}/{len(table)} correct")
        lines.append("")
        if len(wrong):
            lines.append(
                _markdown_table(wrong[["sample_id", "outcome", "estimated_gaps", "true_gaps"]])
            )
        lines += [f"![{name} {g}](grids/{g})" for g in grids.get(name, [])] + [""]
    return "\n".join(lines) + "\n"


def speed_section(leads: pd.DataFrame, speed: dict) -> list[str]:
    """How frames/s was measured, and whether the speed lead is within the spread."""
    lines = [
        f"Frames/s: {speed['frames']} frames of this dataset, in {speed['runs']} runs of "
        f"consecutive frames from {speed['samples']} samples (`speed_frames.csv`), each after an "
        "untimed lead-in frame; the pipelines alternate on every run, each round starting one "
        f"pipeline later, over {speed['rounds']} rounds (`speed_rounds.csv`), so a change in the "
        "machine's load falls on all of them alike. `fps` is the median over rounds, `fps_min` "
        "and `fps_max` the slowest and fastest round (the chart's bars).",
        "",
    ]
    fps = leads[leads["measure"] == "fps"]
    if len(fps) and isinstance(fps["lead_within_spread"].iloc[0], bool):
        row = next(fps.itertuples(index=False))
        lines += [f"The speed lead of {row.leader}: {spread_verdict(row)}.", ""]
    return lines


def refused_lines(summary: pd.DataFrame) -> list[str]:
    """A line per pipeline that refused every sample: it has no accuracy measure, so it leads
    on none and has no point in the accuracy charts; the line says why instead."""
    everything = summary[summary["refused_samples"] == summary["samples"]]
    return [
        f"{row.pipeline}: refused all {row.samples} samples (why: `refused_reason` in its "
        "scores' samples.csv), so it has no accuracy measure"
        for row in everything.itertuples()
    ]


def failed_frame_lines(tables: dict[str, pd.DataFrame]) -> list[str]:
    """A line per peer: the frames its backend crashed on, per sample (from the scores'
    ``failed_frames`` and ``failed_frame_ids``; NaN for a refused sample is no failure)."""
    lines = []
    for name, table in tables.items():
        if not is_peer(name) or "failed_frames" not in table:
            continue
        failed = table[table["failed_frames"] > 0]
        if failed.empty:
            lines.append(f"{name}: no failed frames")
            continue
        where = "; ".join(
            f"{r.sample_id} frames {', '.join(map(str, json.loads(r.failed_frame_ids)))}"
            if "failed_frame_ids" in table
            else f"{r.sample_id} ({int(r.failed_frames)} frames)"
            for r in failed.itertuples()
        )
        lines.append(f"{name}: {int(failed['failed_frames'].sum())} failed frames: {where}")
    return lines

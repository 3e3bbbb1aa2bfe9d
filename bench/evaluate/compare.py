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

Peer detectors (the ``locus`` and ``apriltag`` presets, any ``/detector=`` variant) and detector
plugins (``plugin:SPEC``) run, and are timed, like every other pipeline; results files
(``results:PATH``) and branch finders (``branch-plugin:SPEC``) are scored on the dataset beside
them (:mod:`bench.evaluate.outside`). The report opens with who leads on each measure, peers and
outside methods beside the project's pipelines (:mod:`bench.evaluate.leaders`, also
``leaders.csv``). A method whose backend fails (:class:`pipeline.backends.BackendError`: a
plugin that raises, answers outside its contract, or crashes or hangs on image after image)
keeps a row saying why (``failed``), with no measure, and the others go on; one that fails
while timed drops out of the timing rounds and is not scored.

The report (``report.md`` with PNG charts beside it) opens without a server. Per-sample outputs
(detections tables and plots: bulk data) go to ``<dataset>/scores/<variant>/``, not beside the
report.
"""

from __future__ import annotations

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
    hash_files,
    machine,
    write_manifest,
)
from bench.common.run_folder import claim, open_folder
from bench.evaluate.compare_report import OWN_POSE, render_report
from bench.evaluate.leaders import leaders
from bench.evaluate.outside import Method, OutsideMethod, prepare, score_outside
from bench.evaluate.pareto import plot_pareto
from bench.evaluate.timing import (
    ROUND_COLUMNS,
    RUN_FRAMES,
    SPEED_COLUMNS,
    SPEED_FRAMES,
    SPEED_ROUNDS,
    dataset_runs,
    one_opencv_thread,
    runs_table,
    speed_figures,
    speed_of,
    time_pipelines,
)
from pipeline.backends import BackendError
from pipeline.presets import PipelineConfig
from renderers.variant import init_worker


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
        "failed": "",
    }


def failed_row(name: str, samples: int, reason: str) -> dict:
    """The summary row of a method whose backend failed: its reason, no measure."""
    nan = float("nan")
    return {"pipeline": name, "samples": samples, "refused_samples": 0, "correct_rate": nan,
            "recall": nan, **dict.fromkeys(SPEED_COLUMNS, nan), "failed": reason}  # fmt: skip


def run_compare(
    dataset: Path,
    pipelines: list[Method],
    out_dir: Path,
    sweep=None,
    speed_frames: int = SPEED_FRAMES,
    speed_rounds: int = SPEED_ROUNDS,
    variant: str | None = None,
    workers: int = 1,
    executor: str = "pool",
    scheduler: str | None = None,
) -> pd.DataFrame:
    """Measure every variant (speed, dataset accuracy, sweeps) and every outside method
    (:mod:`bench.evaluate.outside`: dataset accuracy) and write the report.

    Speed: up to ``speed_frames`` frames of the dataset timed, the pipelines (detector
    plugins too) alternating, ``speed_rounds`` rounds (:mod:`bench.evaluate.timing`), after
    the dataset is verified; outside methods are not timed (a results file's own times are
    its speed, else NaN: accuracy only).
    Before anything is written a peer that is not installed
    (:class:`pipeline.backends.BackendUnavailableError`) or a pipeline whose backend cannot
    detect the sweeps' or the dataset's family (ValueError) is refused; then the report
    folder and every variant's score folder are claimed (ValueError if another command's),
    the dataset is verified, once (DatasetIntegrityError naming the file), and the results
    files are read and the branch finders resolved (ValueError); ``manifest.json`` is
    written last. A method whose backend fails (BackendError), while timed or scored, gets a
    ``failed`` row and is left out of the sweeps. Scoring and sweeps run their tasks on
    ``executor`` (:class:`~bench.common.executor.TaskPool`), recorded in the manifest.
    """
    from bench.dataset.verify import verify_dataset
    from bench.evaluate.band import band_end_boundaries, sweep_band_values
    from bench.evaluate.score import dataset_family, dataset_psf_scale, for_family, score_dataset
    from bench.evaluate.score_units import check_own_samples
    from bench.evaluate.sweep_config import SweepConfig, sweep_options
    from bench.evaluate.sweep_report import boundaries, write_sweeps
    from bench.evaluate.sweeps import run_sweeps, sweep_pipelines

    dataset, out_dir = Path(dataset), Path(out_dir)
    sweep = sweep or SweepConfig()
    names = [p.name for p in pipelines]
    if len(set(names)) != len(names) or not names:
        raise ValueError(f"--pipelines: need distinct names, got {names}")
    own = [p for p in pipelines if isinstance(p, PipelineConfig)]  # detected, timed, swept
    if own:  # a missing peer or a family it cannot detect: refused now
        sweep_pipelines(own, sweep)
    family = dataset_family(dataset)
    # the dataset's family too, before any claim; timed as they score, keyed by name
    detecting = {p.name: for_family(p, family) for p in own}
    clock = RunClock()
    claim(out_dir, "compare")
    for pipeline in pipelines:
        claim(dataset / "scores" / pipeline.folder_name, "score")
    verified = verify_dataset(dataset)  # every file hashed once, before the speed frames
    for pipeline in pipelines:  # another dataset's samples there: refused before any write
        check_own_samples(dataset / "scores" / pipeline.folder_name, verified.records)
    prepared = prepare(pipelines, verified)  # results files read, branch finders resolved
    with open_folder(out_dir, "compare", ("", "grids")):  # locked until the manifest is written
        chosen = init_worker(variant)
        t_start = time.perf_counter()
        runs = dataset_runs(dataset, speed_frames) if detecting else []
        rounds = pd.DataFrame(columns=list(ROUND_COLUMNS))  # none when only outside methods
        failed: dict[str, str] = {}  # a method's failure, timed or scored: the others go on
        if detecting:
            timing = time_pipelines(runs, detecting, speed_rounds)
            rounds, failed = timing.rounds, dict(timing.failed)
        timed = runs_table(runs)
        del runs
        speed = speed_figures(rounds)
        # one pool scores every pipeline: a Dask cluster or worker processes start once
        pool = TaskPool(workers, executor=executor, scheduler=scheduler)
        with pool, one_opencv_thread():
            rows, tables = [], {}
            for method in pipelines:
                scores = dataset / "scores" / method.folder_name
                try:
                    if method.name in failed:  # while timed: not scored
                        raise BackendError(failed[method.name])
                    if isinstance(method, OutsideMethod):
                        table, fps = score_outside(
                            method, prepared.get(method.name), dataset, verified, pool
                        )
                        speeds = {**dict.fromkeys(SPEED_COLUMNS, float("nan")), "fps": fps}
                    else:
                        table = score_dataset(dataset, method, scores, verified, pool=pool)
                        speeds = speed_of(speed, method.name)
                except BackendError as exc:
                    failed[method.name] = " ".join(str(exc).split())
                    rows.append(failed_row(method.name, len(verified.records), failed[method.name]))
                    continue
                tables[method.name] = table
                rows.append({**summarize(method.name, table), **speeds})
        summary = pd.DataFrame(rows)
        swept = [p for p in own if p.name not in failed]
        pool_options = {"workers": workers, "executor": executor, "scheduler": scheduler}
        t_sweeps = time.perf_counter()
        sweeps = run_sweeps(swept, sweep, variant, **pool_options) if swept else pd.DataFrame()
        t_band = time.perf_counter()
        band_tables = {  # the boundary axes again, the base point's PSF at each band end
            end.base_psf_scale: run_sweeps(swept, end, variant, **pool_options)
            for end in (sweep.band_end_sweeps() if swept else ())
        }
        band_s = time.perf_counter() - t_band
        edges = boundaries(sweeps) if swept else pd.DataFrame()
        band_edges = band_end_boundaries(band_tables)
        band = sweep_band_values(sweeps, band_edges, tuple(band_tables)) if band_tables else None
        leads = leaders(summary, edges, band)

        out_dir.mkdir(parents=True, exist_ok=True)
        written = write_sweeps(out_dir, sweeps, sweep, swept) if swept else []
        frames = [("summary", summary), ("boundaries", edges), ("leaders", leads)]
        frames += [("speed_frames", timed), ("speed_rounds", rounds)]
        if band_tables:
            frames += [
                ("sweeps_band_ends", pd.concat(band_tables.values(), ignore_index=True)),
                ("boundaries_band_ends", band_edges),
            ]
        for name, frame in frames:
            with atomic_path(out_dir / f"{name}.csv") as tmp:
                frame.to_csv(tmp, index=False)
            written.append(out_dir / f"{name}.csv")
        plot_pareto(summary, out_dir / "pareto.png", dataset.name, sweep_options(sweep))
        grids = _copy_grids(dataset, pipelines, out_dir)
        meta = {
            "dataset": str(dataset),
            "samples": int(summary["samples"].iloc[0]),
            "variant": chosen,
            "cpu_count": machine()["cores"],
            "opencv": cv2.__version__,
            "wall_s": time.perf_counter() - t_start,
            "speed": {
                "frames": int(timed["timed"].sum()) if len(rounds) else 0,  # 0: nothing timed
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
        report = render_report(summary, tables, edges, leads, grids, meta, failed)
        write_bytes(out_dir / "report.md", report.encode())
        written += [out_dir / "pareto.png", out_dir / "report.md"]
        written += [out_dir / "grids" / n for names in grids.values() for n in names]
        config = {
            "dataset": str(dataset),
            "pipelines": [p.to_json() for p in own],
            "outside": [m.name for m in pipelines if isinstance(m, OutsideMethod)],
            "failed": failed,
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
            executor=effective_executor(executor, workers, scheduler),
            workers=workers,
            scheduler=scheduler,
        )
        write_manifest(out_dir, record)
    return summary


def _copy_grids(dataset: Path, pipelines: list[Method], out_dir: Path) -> dict:
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

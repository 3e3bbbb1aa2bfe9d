"""``whiskerbench compare``: pipeline variants by accuracy and speed, in one run, as a report.

Per variant, measured in the same run on this machine:

* **speed**: frames/s of detection and pose on full 2592 x 1944 frames with 13 markers, one
  OpenCV thread (:mod:`bench.evaluate.speed`, the same frames for every variant);
* **accuracy on the dataset**: :func:`bench.score.score_dataset` on every sample (branch outcome
  with the none-twin threshold, marker recall, deflection, corner and pose errors);
* **failure boundaries**: detection recall and pose error against angular position, marker tilt,
  lighting, motion blur, sensor noise and lens sharpness (the camera profile's band of PSF
  scales), over several seeds (:mod:`bench.evaluate.sweeps`); the boundary axes again with the
  base point's PSF at each end of the band, so the report can say which leads hold across the
  lens' uncertain blur (:mod:`bench.evaluate.band`).

Peer detectors (the ``locus`` and ``apriltag`` presets, any ``/detector=`` variant) and detector
plugins (``plugin:SPEC``) run like every other pipeline; results files (``results:PATH``) and
branch finders (``branch-plugin:SPEC``) are scored on the dataset beside them
(:mod:`bench.evaluate.outside`). The report opens with who leads on each measure, peers and
outside methods beside the project's pipelines (:mod:`bench.evaluate.leaders`, also
``leaders.csv``). A method whose backend fails (:class:`pipeline.backends.BackendError`: a
plugin that raises, answers outside its contract, or crashes or hangs on image after image)
keeps a row saying why (``failed``), with no measure, and the others go on.

The report (``report.md`` with PNG charts beside it) opens without a server. Per-sample outputs
(detections tables and plots: bulk data) go to ``<dataset>/scores/<variant>/``, not beside the
report.
"""

from __future__ import annotations

import os
import platform
import shutil
import time
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from bench.common.atomic import atomic_path, write_bytes  # noqa: E402
from bench.common.executor import TaskPool, effective_executor  # noqa: E402
from bench.common.manifest import (  # noqa: E402
    RunClock,
    build_manifest,
    claim,
    hash_files,
    write_manifest,
)
from bench.evaluate.compare_report import OWN_POSE, render_report  # noqa: E402
from bench.evaluate.leaders import is_peer, leaders  # noqa: E402
from bench.evaluate.outside import Method, OutsideMethod, prepare, score_outside  # noqa: E402
from bench.evaluate.speed import (  # noqa: E402
    SPEED_SAMPLE,
    full_frames,
    one_opencv_thread,
    time_pipeline,
)
from pipeline.backends import BackendError  # noqa: E402
from pipeline.presets import PipelineConfig  # noqa: E402
from renderers.variant import init_worker  # noqa: E402

#: Accuracy measures on the dataset: column, label, whether higher is better.
ACCURACY = (
    ("correct_rate", "branch outcome correct (fraction of samples)", True),
    ("recall", "marker recall", True),
    ("deflection_err_mm", "deflection error (mm, median)", False),
)


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
            "recall": nan, "fps": nan, "failed": reason}  # fmt: skip


def pareto_front(speed: np.ndarray, accuracy: np.ndarray, higher_better: bool) -> np.ndarray:
    """(N,) bool: points no other point beats in both speed and accuracy (ties do not beat).

    A point without an accuracy (NaN: its pipeline refused every sample) or without a speed
    (an untimed results file) is not on the front and beats no other."""
    acc = np.asarray(accuracy, float) * (1 if higher_better else -1)
    speed = np.asarray(speed, float)
    front = np.isfinite(acc) & np.isfinite(speed)
    for i in range(len(speed)):
        better = (speed >= speed[i]) & (acc >= acc[i]) & ((speed > speed[i]) | (acc > acc[i]))
        front[i] &= not better.any()
    return front


def plot_pareto(summary: pd.DataFrame, path: Path) -> None:
    """Accuracy against speed, one panel per accuracy measure, the Pareto front drawn.

    The front is computed over every pipeline, peers included; peers are hollow diamonds, the
    project's pipelines filled circles (red on the front, grey behind it). A method with an
    accuracy but no speed (an untimed results file, a branch finder) is a dotted line at its
    accuracy, named "accuracy only". A pipeline without a value for a measure (it refused
    every sample, or failed) cannot be placed: the panel's title names it, so no pipeline
    drops out of the chart unsaid."""
    fig, axes = plt.subplots(1, len(ACCURACY), figsize=(5 * len(ACCURACY), 4), dpi=110)
    speed = summary["fps"].to_numpy()
    peer = summary["pipeline"].map(is_peer).to_numpy(bool)
    for ax, (column, label, higher) in zip(axes, ACCURACY, strict=True):
        acc = summary[column].to_numpy(float)
        untimed = np.isfinite(acc) & ~np.isfinite(speed)
        placed = np.isfinite(acc) & ~untimed
        front = pareto_front(speed, acc, higher)
        for mine, where, colour in (
            (placed & ~front, "behind the front", "#9e9e9e"),
            (front, "Pareto front", "#d62728"),
        ):
            ax.scatter(speed[mine & ~peer], acc[mine & ~peer], c=colour, s=45, label=where)
            ax.scatter(speed[mine & peer], acc[mine & peer], marker="D", s=55, facecolors="none",
                       edgecolors=colour, linewidths=1.6, label=f"peer, {where}")  # fmt: skip
        order = np.argsort(speed[front])
        ax.plot(speed[front][order], acc[front][order], "-", c="#d62728", lw=1)
        names = summary["pipeline"].to_numpy()
        for x, y, name in zip(speed[placed], acc[placed], names[placed], strict=True):
            ax.annotate(name, (x, y), fontsize=7, xytext=(4, 3), textcoords="offset points")
        for y, name in zip(acc[untimed], names[untimed], strict=True):
            ax.axhline(y, ls=":", c="#0072b2", lw=1.2)
            ax.annotate(f"{name} (accuracy only)", (0.01, y), xycoords=("axes fraction", "data"),
                        fontsize=7, xytext=(0, 3), textcoords="offset points")  # fmt: skip
        if not (placed | untimed).all():
            ax.set_title(f"no value: {', '.join(names[~(placed | untimed)])}", fontsize=8)
        if placed.any():  # an empty panel has no range to log-scale
            ax.set_xscale("log")
        ax.set_xlabel("frames/s, full 2592x1944 frames, one core")
        ax.set_ylabel(label + ("" if higher else ", lower is better"))
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    shown = [(h, t) for h, t in zip(handles, labels, strict=True) if len(h.get_offsets())]
    if shown:  # none when every pipeline refused every sample
        axes[0].legend(*zip(*shown, strict=True), fontsize=7)
    fig.suptitle("accuracy against speed (hollow diamonds: peer detectors)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def run_compare(
    dataset: Path,
    pipelines: list[Method],
    out_dir: Path,
    sweep=None,
    speed_frames: int = 30,
    speed_seconds: float = 2.0,
    variant: str | None = None,
    workers: int = 1,
    executor: str = "pool",
    scheduler: str | None = None,
) -> pd.DataFrame:
    """Measure every variant (speed, dataset accuracy, sweeps) and every outside method
    (:mod:`bench.evaluate.outside`: dataset accuracy) and write the report.

    Speed: the best of repeats over ``speed_frames`` full frames, run for ``speed_seconds``.
    Before anything is written a peer that is not installed
    (:class:`pipeline.backends.BackendUnavailableError`) or a pipeline whose backend cannot
    detect the sweeps' or the dataset's family (ValueError) is refused; then the report
    folder and every variant's score folder are claimed (ValueError if another command's),
    the dataset is verified, once (DatasetIntegrityError naming the file), and the results
    files are read and the branch finders resolved (ValueError); ``manifest.json`` is
    written last. A method whose backend fails (BackendError) gets a ``failed`` row and is
    left out of the sweeps. Scoring and sweeps run their tasks on ``executor``
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
    timed = [p for p in pipelines if isinstance(p, PipelineConfig)]
    if timed:  # a missing peer or a family it cannot detect: refused now
        sweep_pipelines(timed, sweep)
    family = dataset_family(dataset)
    for pipeline in timed:
        for_family(pipeline, family)  # the dataset's family too, before any claim
    clock = RunClock()
    claim(out_dir, "compare")
    for pipeline in pipelines:
        claim(dataset / "scores" / pipeline.folder_name, "score")
    verified = verify_dataset(dataset)  # every file hashed once, before the speed frames
    prepared = prepare(pipelines, verified)  # results files read, branch finders resolved
    chosen = init_worker(variant)
    t_start = time.perf_counter()
    # one pool scores every pipeline: a Dask cluster or worker processes start once
    pool = TaskPool(workers, executor=executor, scheduler=scheduler)
    failed: dict[str, str] = {}
    with pool, one_opencv_thread():
        images = full_frames(SPEED_SAMPLE, speed_frames)[0][1.0] if timed else []
        rows, tables = [], {}
        for method in pipelines:
            scores = dataset / "scores" / method.folder_name
            try:
                if isinstance(method, OutsideMethod):
                    table, fps = score_outside(
                        method, prepared.get(method.name), dataset, verified, pool
                    )
                else:
                    fps, _ = time_pipeline(images, SPEED_SAMPLE, method, speed_seconds)
                    table = score_dataset(dataset, method, scores, verified, pool=pool)
            except BackendError as exc:  # that method's failure: the others go on
                failed[method.name] = " ".join(str(exc).split())
                rows.append(failed_row(method.name, len(verified.records), failed[method.name]))
                continue
            tables[method.name] = table
            rows.append({**summarize(method.name, table), "fps": fps})
        del images
    summary = pd.DataFrame(rows)
    swept = [p for p in timed if p.name not in failed]
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
        "speed_frames": speed_frames,
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
        "pipelines": [p.to_json() for p in timed],
        "outside": [m.name for m in pipelines if isinstance(m, OutsideMethod)],
        "failed": failed,
        "sweep": sweep.to_json(),  # also in sweep_config.json, beside the sweep table
        "speed_frames": speed_frames,
        "speed_seconds": speed_seconds,
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

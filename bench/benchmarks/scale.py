"""``whiskerbench bench scale``: images/s and frames/s against executor and worker count.

A small fixed study and a small fixed dataset run from scratch in temporary folders once per
(executor, workers) row; each row's rates are divided by the in-process, one-worker row of the
same run (the baseline), and the tables and videos of every row are hashed: outputs never
depend on the executor, and the benchmark says whether they were identical. The rates are then
extrapolated to the default grids: the study's image cap and the dataset's frame count, counted
without rendering (:func:`default_dataset_frames`).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from bench.common.atomic import write_json
from bench.common.manifest import RunClock, build_manifest, hash_files, write_manifest
from bench.common.run_folder import claim_out
from bench.dataset.config import SAMPLE_FILES, DatasetConfig
from bench.dataset.generate import run_dataset
from bench.study.config import StudyConfig
from bench.study.run import run_study
from renderers.variant import init_worker

#: The fixed dataset of the benchmark: four short outdoor samples (two per worker of two), every
#: second frame, on the default (prototype) camera.
SCALE_DATASET = {
    "foliage": ("soft",),
    "distances": ("intermediate",),
    "branches": ((), (0.0,), (50.0,), (0.0, 100.0)),
    "protocols": ("outdoor",),
    "passes": 1,
    "frames_step": 2,
}
#: Tables whose bytes must not depend on the executor (plots are left out: images of them).
STUDY_TABLES = ("images.parquet", "summary.csv", "max_phi_by_scale.csv", "max_phi.csv")
#: Issue 11's target: the default dataset grid in about 35 minutes, i.e. 45 frames/s.
TARGET_FRAMES_PER_S = 45.0


def scale_rows(executors: tuple[str, ...], workers_max: int) -> list[tuple[str, int]]:
    """(executor, workers) to time: in-process with one worker first (the baseline), then the
    pool and Dask with 2..``workers_max`` workers (a pool of one is the in-process row)."""
    rows = [("inline", 1)]
    for executor in ("pool", "dask"):
        if executor in executors:
            rows += [(executor, w) for w in range(2, workers_max + 1)]
    return rows


def default_dataset_frames(config: DatasetConfig | None = None) -> int:
    """Frames of every sample of ``config`` (default: the default grid), counted as the
    simulation counts them (every ``frames_step``-th frame of the path): nothing rendered."""
    config = config or DatasetConfig()
    return sum(
        int(-(-config.motion(s.protocol, s.distance).frame_count // config.frames_step))
        for s in config.samples()
    )


def default_study_images(config: StudyConfig | None = None) -> int:
    """Images of ``config`` (default: the default grid) at its cap: cells x images x PSF scales;
    cells that settle early draw fewer, refinement rounds add cells."""
    config = config or StudyConfig()
    return len(config.cells()) * config.images * len(config.psf_scales)


def _hms(seconds: float) -> str:
    minutes = round(seconds / 60)
    return f"{minutes // 60} h {minutes % 60} min"


def _time_row(
    study: StudyConfig, dataset: DatasetConfig, executor: str, workers: int, variant: str | None
) -> dict:
    """Run both fixed grids on one executor; their rates and their outputs' digests."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        m_study = run_study(
            study, out / "study", variant, workers, progress=False, executor=executor
        )
        m_data = run_dataset(
            dataset, out / "data", variant, workers, progress=False, executor=executor
        )
        tables = hash_files([out / "study" / n for n in STUDY_TABLES], out / "study")
        videos = hash_files(
            [out / "data" / s.sample_id / n for s in dataset.samples() for n in SAMPLE_FILES],
            out / "data",
        )
    study_s, data_s = m_study["wall_s"]["cells_s"], m_data["wall_s"]
    return {
        "executor": executor,
        "workers": workers,
        "images": m_study["images_total"],
        "study_s": study_s,
        "images_per_s": m_study["images_total"] / study_s,
        "frames": m_data["frames_rendered"],
        "dataset_s": data_s,
        "frames_per_s": m_data["frames_rendered"] / data_s,
        "digests": {"study": tables, "dataset": videos},
    }


def _print_table(rows: list[dict]) -> None:
    base = rows[0]
    print(
        f"{'executor':>8} {'workers':>7} | {'images':>6} {'wall s':>7} {'images/s':>9} {'ratio':>6}"
        f" | {'frames':>6} {'wall s':>7} {'frames/s':>9} {'ratio':>6}"
    )
    for r in rows:
        print(
            f"{r['executor']:>8} {r['workers']:>7} | {r['images']:>6} {r['study_s']:>7.1f} "
            f"{r['images_per_s']:>9.1f} {r['images_per_s'] / base['images_per_s']:>5.2f}x | "
            f"{r['frames']:>6} {r['dataset_s']:>7.1f} {r['frames_per_s']:>9.2f} "
            f"{r['frames_per_s'] / base['frames_per_s']:>5.2f}x"
        )


def _extrapolate(rows: list[dict]) -> dict:
    """The default grids' time at each row's rates, the dataset's against the target."""
    images, frames = default_study_images(), default_dataset_frames()
    cells = len(StudyConfig().cells())
    out = {"default_study_images_max": images, "default_dataset_frames": frames, "rows": []}
    for r in rows:
        study_s, data_s = images / r["images_per_s"], frames / r["frames_per_s"]
        met = r["frames_per_s"] >= TARGET_FRAMES_PER_S
        label = f"{r['workers']} worker{'s' if r['workers'] > 1 else ''} ({r['executor']})"
        print(
            f"default study: at most {images:,} images ({cells} cells x {StudyConfig().images}), "
            f"at {r['images_per_s']:.1f} images/s with {label}: at most {_hms(study_s)}"
        )
        print(
            f"default dataset: {frames:,} frames, at {r['frames_per_s']:.2f} frames/s with "
            f"{label}: {_hms(data_s)}; target about 35 min ({TARGET_FRAMES_PER_S:g} frames/s): "
            f"{'met' if met else 'missed'}"
        )
        out["rows"].append(
            {
                "executor": r["executor"],
                "workers": r["workers"],
                "default_study_s_max": study_s,
                "default_dataset_s": data_s,
                "dataset_target_met": met,
            }
        )
    return out


def bench_scale(
    study: StudyConfig,
    dataset: DatasetConfig,
    executors: tuple[str, ...] = ("inline", "pool", "dask"),
    workers_max: int = 2,
    variant: str | None = None,
    out_dir: Path | None = None,
) -> dict:
    """Time ``study`` and ``dataset`` per (executor, workers) row (:func:`scale_rows`); print
    the table, whether the outputs were identical, and the default grids' extrapolated times.

    With ``out_dir`` (claimed before any work), also write ``bench.json`` and ``manifest.json``.
    """
    clock = RunClock()
    if out_dir is not None:
        claim_out(Path(out_dir), "bench-scale")
    chosen = init_worker(variant)
    plan = scale_rows(executors, workers_max)
    print(
        f"scale benchmark: study {len(study.cells())} cells x up to {study.images} images, "
        f"dataset {len(dataset.samples())} samples (every {dataset.frames_step} frame(s)), "
        f"camera {dataset.camera.name}, variant {chosen}, {os.cpu_count()} cores; rows "
        + ", ".join(f"{e} {w}" for e, w in plan)
    )
    rows = []
    for executor, workers in plan:
        t0 = time.perf_counter()
        rows.append(_time_row(study, dataset, executor, workers, chosen))
        print(f"  {executor} {workers}: done in {time.perf_counter() - t0:.1f} s", flush=True)
    _print_table(rows)
    print(
        "(walls include starting the workers and each sample's set-up: fixed costs that the "
        "default grids spread over more work)"
    )
    identical = all(r["digests"] == rows[0]["digests"] for r in rows)
    print(f"outputs identical: {'yes' if identical else 'no'} (study tables, dataset videos)")
    figures = {
        "variant": chosen,
        "cpu_count": os.cpu_count(),
        "rows": [{k: v for k, v in r.items() if k != "digests"} for r in rows],
        "outputs_identical": identical,
        "extrapolation": _extrapolate(rows),
        "target_frames_per_s": TARGET_FRAMES_PER_S,
    }
    if out_dir is not None:
        out_dir = Path(out_dir)
        write_json(out_dir / "bench.json", figures)
        config = {
            "study": study.to_json(),
            "dataset": dataset.to_json(),
            "executors": list(executors),
            "workers_max": workers_max,
        }
        record = build_manifest(
            "bench-scale",
            clock,
            config,
            variant=chosen,
            outputs=hash_files([out_dir / "bench.json"], out_dir),
        )
        write_manifest(out_dir, record)
        print(f"wrote {out_dir}/bench.json")
    return figures

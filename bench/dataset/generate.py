"""Generate a dataset into a folder: every sample (skipping verified ones), then the manifest."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from bench.common.executor import TaskPool, effective_executor
from bench.common.manifest import sha256
from bench.common.resumable import ResumableRun, finish_run, open_run
from bench.common.units import DAMAGED, DONE
from bench.dataset.config import DatasetConfig, DatasetConfigError, SampleSpec
from bench.dataset.core_share import CoreShare, core_share
from bench.dataset.format import FORMAT_VERSION
from bench.dataset.sample import run_sample, sample_state
from renderers.variant import init_worker


@dataclass(frozen=True)
class _SampleTask:
    config: DatasetConfig
    sample: SampleSpec
    out_dir: Path
    share: CoreShare | None  # a local pool's cores, split between the samples in progress


def _run_task(task: _SampleTask, _variant: str) -> dict:
    return run_sample(task.config, task.sample, task.out_dir, task.share)


def foliage_groups(records: list[dict]) -> dict[str, list[str]]:
    """{foliage group: its sample ids}: the samples that share one vegetation layout."""
    groups: dict[str, list[str]] = {}
    for r in records:
        groups.setdefault(r["foliage_group"], []).append(r["sample_id"])
    return groups


def run_dataset(
    config: DatasetConfig,
    out_dir: Path,
    variant: str | None = None,
    workers: int = 1,
    progress: bool = True,
    inputs: dict[str, str] | None = None,
    executor: str = "pool",
    scheduler: str | None = None,
) -> dict:
    """Make (or finish) the dataset in ``out_dir``; return its manifest.

    Samples whose ``sample.json`` is intact and lists files that verify are skipped; a damaged
    one is made again (named in the manifest's ``units_redone``). The folder is locked for the
    whole run; a locked folder, one holding another command's output, samples made with other
    settings, or a damaged sample outside this run's grid (it cannot be made again here) is
    refused (DatasetConfigError on ``out``) before anything is written. The manifest lists every
    sample in the folder, those of earlier runs with other grids included: a partial rerun adds
    to the dataset, never drops what it did not touch. ``inputs`` (path: SHA-256, e.g. the camera
    profile's file) go into the manifest. The samples run on ``executor``
    (:class:`~bench.common.executor.TaskPool`), recorded in the manifest but not in the
    settings: any executor resumes the folder.
    """
    out_dir = Path(out_dir)
    settings = config.settings_hash()
    samples = config.samples()
    ids = [s.sample_id for s in samples]
    others: list[str] = []

    def check(folder: Path) -> None:  # the samples outside the grid, before anything is written
        others.extend(_other_samples(folder, set(ids), settings))

    try:
        run = open_run(
            out_dir, "dataset", config.to_json(), settings, units="*/sample.json",
            written=("", *ids), check=check,
        )  # fmt: skip
    except ValueError as exc:
        raise DatasetConfigError("out", str(exc)) from None
    with run:  # the folder stays locked until the manifest is written
        try:
            states = {s.sample_id: sample_state(out_dir / s.sample_id, settings) for s in samples}
        except ValueError as exc:  # a sample.json from before record hashes, other settings
            raise DatasetConfigError("out", str(exc)) from None
        run.redone += [i for i, state in states.items() if state == DAMAGED]
        todo = [s for s in samples if states[s.sample_id] != DONE]
        return _make(run, config, samples + others, todo, variant, workers, progress, inputs,
                     executor, scheduler)  # fmt: skip


def _other_samples(out_dir: Path, grid: set[str], settings: str) -> list[str]:
    """The finished samples in ``out_dir`` outside this run's grid (kept in the manifest);
    ValueError naming one that is damaged."""
    others = (
        sorted(p.parent.name for p in out_dir.glob("*/sample.json")) if out_dir.is_dir() else []
    )
    others = [i for i in others if i not in grid]
    for sample_id in others:
        if sample_state(out_dir / sample_id, settings) != DONE:
            raise ValueError(
                f"{out_dir / sample_id}: a damaged sample outside this run's grid; rerun with "
                "a grid that includes it, or delete it"
            )
    return others


def _make(
    run: ResumableRun,
    config: DatasetConfig,
    listed: list,
    todo: list[SampleSpec],
    variant: str | None,
    workers: int,
    progress: bool,
    inputs: dict[str, str] | None,
    executor: str,
    scheduler: str | None,
) -> dict:
    """Make the ``todo`` samples into the opened run's folder, then write the manifest of every
    ``listed`` sample (specs of this grid, ids of earlier runs)."""
    out_dir = run.folder
    samples = [s for s in listed if isinstance(s, SampleSpec)]
    ran_by = effective_executor(executor, workers, scheduler)
    # Inline, this process keeps every core; workers on this machine split them between the
    # samples in progress (bench/dataset/core_share.py).
    threads = None if ran_by == "inline" else (os.cpu_count() or 1)
    chosen = init_worker(variant)
    start = time.perf_counter()
    pool_workers = min(workers, len(todo)) or 1
    folders = [out_dir / s.sample_id for s in todo]
    share = core_share(ran_by, scheduler, folders, pool_workers)
    tasks = [_SampleTask(config, s, out_dir, share) for s in todo]
    with TaskPool(pool_workers, init_worker, (chosen, threads), executor, scheduler) as pool:
        ran_on = pool.describe()
        new = list(pool.map(_run_task, tasks, desc="samples", unit="sample", progress=progress))
    wall_s = time.perf_counter() - start
    ids = [s.sample_id if isinstance(s, SampleSpec) else s for s in listed]
    records = [json.loads((out_dir / i / "sample.json").read_text()) for i in ids]
    frames_new = sum(r["frames"] for r in new)
    # seconds in each stage of the samples made in this run (summed over workers); other:
    # setting up the renderer, labels and the preview. The twin (optics, sensor) runs in its
    # own thread beside the render: its time is inside render and encode, not added to them.
    stages = ("simulate_s", "render_s", "optics_s", "sensor_s", "encode_s")
    stage_s = {k: sum(r["timing_s"][k] for r in new) for k in stages}
    serial = stage_s["simulate_s"] + stage_s["render_s"] + stage_s["encode_s"]
    stage_s["other_s"] = sum(r["timing_s"]["total_s"] for r in new) - serial
    files = {  # every sample's files, sample.json included: what score and compare verify
        f"{r['sample_id']}/{name}": digest
        for r in records
        for name, digest in {
            **r["files"],
            "sample.json": sha256(out_dir / r["sample_id"] / "sample.json"),
        }.items()
    }
    return finish_run(  # "config": its "camera" is the whole profile
        run,
        format_version=FORMAT_VERSION,  # docs/dataset_format.md; not in the settings hash
        seed=config.seed,
        variant=chosen,
        inputs=inputs,
        outputs=files,
        camera_profile=config.camera.name,
        samples=[r["sample_id"] for r in records],
        foliage_groups=foliage_groups(records),
        skipped=len(samples) - len(todo),
        files=files,
        wall_s=wall_s,
        frames=sum(r["frames"] for r in records),
        frames_rendered=frames_new,
        frames_per_s=frames_new / wall_s if frames_new else None,
        stage_s=stage_s,
        **ran_on,
    )

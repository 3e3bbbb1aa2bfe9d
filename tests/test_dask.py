"""Outputs never depend on the executor: the same bytes in-process, on a process pool and on
Dask, a run resumed under another executor, and a Dask run that loses a worker mid-run."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from bench.common.executor import TaskPool
from bench.dataset.generate import run_dataset
from bench.study.config import StudyConfig
from bench.study.run import run_study

pytestmark = pytest.mark.slow  # each test starts worker processes and renders

STUDY = StudyConfig(sizes_mm=(13.2,), alphas_deg=(0.0, 60.0), phis_deg=(0.0,), images=10)
STUDY_TABLES = ("images.parquet", "summary.csv", "max_phi_by_scale.csv", "max_phi.csv")


def _setup(tag: str) -> tuple[str, int, int]:
    return tag, os.getpid(), time.monotonic_ns()


def _task(n: int, context: tuple[str, int, int]) -> tuple[int, str, int, int]:
    return n * n, *context


def test_dask_builds_each_workers_context_once():
    with TaskPool(2, _setup, ("dask",), executor="dask") as pool:
        results = list(pool.map(_task, range(8), progress=False))
        assert pool.describe() == {"executor": "dask", "workers": 2, "scheduler": None}
    assert sorted(r[0] for r in results) == [n * n for n in range(8)]
    assert {r[1] for r in results} == {"dask"}
    workers = {r[2] for r in results}
    assert os.getpid() not in workers and 1 <= len(workers) <= 2
    for pid in workers:  # one context per worker process, built on its first task
        assert len({r[3] for r in results if r[2] == pid}) == 1


def _digests(folder: Path) -> dict[str, str]:
    """SHA-256 of every output file under ``folder`` but the manifest and the run-time records
    (a sample.json without its timings and the record's hash of itself, which covers them);
    temporary files of a killed writer left out."""
    out = {}
    for path in sorted(folder.rglob("*")):
        if not path.is_file() or path.name.startswith(".") or path.name == "manifest.json":
            continue
        data = path.read_bytes()
        if path.name == "sample.json":
            record = json.loads(data)
            record.pop("timing_s")
            record.pop("record_sha256")
            data = json.dumps(record, sort_keys=True).encode()
        out[str(path.relative_to(folder))] = hashlib.sha256(data).hexdigest()
    return out


def test_study_tables_are_the_same_bytes_on_every_executor(variant, tmp_path):
    runs = {}
    for executor, workers in (("inline", 1), ("pool", 2), ("dask", 2)):
        out = tmp_path / executor
        manifest = run_study(STUDY, out, variant, workers, progress=False, executor=executor)
        assert manifest["executor"] == executor and manifest["cells_computed"] == 2
        runs[executor] = {
            name: digest
            for name, digest in _digests(out).items()
            if name in STUDY_TABLES or name.startswith("cells/")
        }
    assert len(runs["inline"]) == len(STUDY_TABLES) + 4  # 2 cells: parquet and record each
    assert runs["pool"] == runs["inline"]
    assert runs["dask"] == runs["inline"]


@pytest.fixture(scope="module")
def four_samples(pair_config):
    """Four short samples: enough that each of two workers holds one when the first is done.
    Every 12th frame: 7 a sample, one of them a still frame of the lead-in that reuses the
    first's optical image, as every 8th did with 10."""
    import dataclasses

    return dataclasses.replace(
        pair_config, branches=((), (100.0,), (0.0,), (0.0, 100.0)), frames_step=12
    )


@pytest.fixture(scope="module")
def reference(tmp_path_factory, variant, four_samples) -> dict[str, str]:
    """The four samples made in this process: the digests every executor must reproduce."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    out = tmp_path_factory.mktemp("inline")
    run_dataset(four_samples, out, variant, progress=False, executor="inline")
    return _digests(out)


def test_dataset_on_a_pool_then_resumed_on_dask_is_the_same_bytes(
    variant, tmp_path, four_samples, reference
):
    out = tmp_path / "data"
    manifest = run_dataset(four_samples, out, variant, 2, progress=False, executor="pool")
    assert manifest["executor"] == "pool" and _digests(out) == reference
    last = four_samples.samples()[-1].sample_id
    for path in (out / last).iterdir():  # as if the run had been stopped before the last sample
        path.unlink()
    kept = {p: p.stat().st_mtime_ns for p in out.glob("*/video.mp4")}
    manifest = run_dataset(four_samples, out, variant, 2, progress=False, executor="dask")
    assert manifest["executor"] == "dask" and manifest["skipped"] == 3
    assert {p: p.stat().st_mtime_ns for p in kept} == kept  # the finished samples untouched
    assert _digests(out) == reference


def test_dask_run_survives_a_killed_worker(variant, tmp_path, four_samples, reference):
    from distributed import Client, LocalCluster

    out = tmp_path / "data"
    cluster = LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None, memory_limit=0,
    )  # fmt: skip
    client = Client(cluster)
    result: dict = {}

    def generate() -> None:
        try:
            result["manifest"] = run_dataset(
                four_samples, out, variant, 2, progress=False, scheduler=cluster.scheduler_address
            )
        except BaseException as exc:  # handed to the test's thread
            result["error"] = exc

    runner = threading.Thread(target=generate)
    try:
        runner.start()
        deadline = time.monotonic() + 300
        while not list(out.glob("*/sample.json")):
            assert runner.is_alive() and time.monotonic() < deadline, result
            time.sleep(0.05)
        pids = client.run(os.getpid)  # worker address -> pid
        busy = [address for address, keys in client.processing().items() if keys]
        assert busy, "no worker held a task mid-run"
        os.kill(pids[busy[0]], signal.SIGKILL)
        assert len(list(out.glob("*/sample.json"))) < 4, "killed after the run's end"
        runner.join(300)
        assert not runner.is_alive() and "error" not in result, result
    finally:
        client.close()
        cluster.close()
    assert result["manifest"]["executor"] == "dask"
    assert result["manifest"]["scheduler"] == cluster.scheduler_address
    assert _digests(out) == reference

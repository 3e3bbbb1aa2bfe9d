"""A local pool's workers split the cores between the samples still being made."""

from __future__ import annotations

import os
import time

from bench.dataset.core_share import CoreShare, core_share


def test_threads_follow_the_samples_still_in_progress(tmp_path) -> None:
    folders = tuple(tmp_path / name for name in ("a", "b", "c"))
    for folder in folders:
        folder.mkdir()
    stale = folders[2] / "sample.json"  # a damaged sample of an earlier run, being made again
    stale.write_text("{}")
    os.utime(stale, (time.time() - 3600,) * 2)
    share = CoreShare(folders, workers=2, cores=4, started=time.time() - 1)
    assert share.threads() == 2  # three to make, two at a time: two cores each
    (folders[0] / "sample.json").write_text("{}")
    assert share.threads() == 2  # two left, both in progress
    (folders[1] / "sample.json").write_text("{}")
    assert share.threads() == 4  # the last one alone takes every core
    stale.write_text("{}")
    assert share.threads() == 4  # all done: never below one thread, never above the cores
    assert CoreShare(folders, workers=8, cores=2, started=time.time() + 60).threads() == 1


def test_only_workers_on_this_machine_share_its_cores(tmp_path) -> None:
    folders = [tmp_path / "a", tmp_path / "b"]
    assert core_share("inline", None, folders, 1) is None  # this process keeps every core
    assert core_share("dask", "tcp://10.0.0.1:8786", folders, 2) is None  # other machines
    for executor in ("pool", "dask"):  # a process pool, a local Dask cluster
        share = core_share(executor, None, folders, 2)
        assert share is not None and share.folders == tuple(folders) and share.workers == 2
        assert share.cores == (os.cpu_count() or 1)

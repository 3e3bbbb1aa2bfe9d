"""``--scheduler`` is refused in one line, within its stated time, unless a Dask scheduler with
at least one worker answers: a port that accepts and stays silent, a scheduler without
workers and a port nothing listens on (all on 127.0.0.1) each give exit code 2, writing
nothing."""

from __future__ import annotations

import socket
import time

import pytest

import bench.cli.args
from bench.cli.main import main
from bench.common.executor import CONNECT_TIMEOUT_S


def _refused(argv: list[str], capsys, folder) -> tuple[str, float]:
    """The single stderr line of a refused run and its seconds; nothing under ``folder``."""
    start = time.monotonic()
    code = main(argv)
    elapsed = time.monotonic() - start
    err = capsys.readouterr().err.strip().split("\n")
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("whiskerbench ") and "--scheduler" in err[0], err
    assert not any(folder.iterdir()), "something was written"
    return err[0], elapsed


@pytest.mark.slow  # waits out the whole deadline
def test_a_silent_port_is_refused_within_the_deadline(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with socket.create_server(("127.0.0.1", 0)) as server:  # accepts (backlog), never answers
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        line, elapsed = _refused(["dataset", "--scheduler", address], capsys, tmp_path)
    assert "no Dask scheduler answers" in line
    assert elapsed < CONNECT_TIMEOUT_S + 2


@pytest.mark.slow  # starts a scheduler
def test_a_scheduler_without_workers_is_refused(tmp_path, capsys, monkeypatch):
    from distributed import LocalCluster

    monkeypatch.chdir(tmp_path)
    # its wait for a worker, shortened; long enough for a loaded machine's handshake
    monkeypatch.setattr(bench.cli.args, "CONNECT_TIMEOUT_S", 5)
    with LocalCluster(
        n_workers=0, processes=True, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        line, elapsed = _refused(
            ["detectability", "--scheduler", cluster.scheduler_address], capsys, tmp_path
        )
    assert "no workers" in line and "waited up to 5 s" in line
    assert elapsed < 5 + 2


def test_a_closed_port_is_refused_at_once(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]  # free once closed: nothing listens on it
    line, elapsed = _refused(
        ["dataset", "--scheduler", f"tcp://127.0.0.1:{port}"], capsys, tmp_path
    )
    assert "no scheduler answers" in line and elapsed < 2

"""``--scheduler`` is refused in one line, within its stated time, unless a Dask scheduler with
at least one worker answers: a port that accepts and stays silent, a scheduler without
workers and a port nothing listens on (all on 127.0.0.1) each give exit code 2, writing
nothing."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import bench.cli.args
from bench.cli.main import main
from bench.common.executor import CONNECT_TIMEOUT_S

ROOT = Path(__file__).resolve().parents[1]


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
    # the deadline, shortened as for the scheduler without workers: a silent peer is waited on
    # for all of it, whatever its length
    monkeypatch.setattr(bench.cli.args, "CONNECT_TIMEOUT_S", 3)
    with socket.create_server(("127.0.0.1", 0)) as server:  # accepts (backlog), never answers
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        line, elapsed = _refused(["dataset", "--scheduler", address], capsys, tmp_path)
    assert "no Dask scheduler answers" in line and "waited up to 3 s" in line
    assert elapsed < 3 + 2


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


@contextlib.contextmanager
def _peer(reply: bytes):
    """A port that accepts, sends ``reply`` (junk: not Dask's framing) and hangs up."""
    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = server.accept()
                with conn, contextlib.suppress(OSError):
                    conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        server.close()


#: Peers that are not Dask schedulers: what they send before hanging up.
PEERS = {
    "an HTTP server": b"HTTP/1.0 200 OK\r\nContent-Length: 0\r\n\r\n",
    "binary junk": bytes(range(256)) * 64,  # read as Dask's frame lengths: exabytes
    # Dask's connect may retry a handshake cut short until the deadline: slow
    "hangs up at once": pytest.param(b"", marks=pytest.mark.slow),
}


@pytest.mark.parametrize("reply", PEERS.values(), ids=PEERS.keys())
def test_a_peer_that_is_no_scheduler_is_refused(reply, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with _peer(reply) as address:
        line, elapsed = _refused(["dataset", "--scheduler", address], capsys, tmp_path)
    assert "no Dask scheduler answers" in line and elapsed < CONNECT_TIMEOUT_S + 2


@pytest.mark.slow
def test_nothing_follows_the_refusal_at_exit(tmp_path):
    """The whole stderr of the process is the one line: a half-made Dask client used to wait
    at exit to close and then print a traceback ("Exception ignored in Client.__del__")."""
    with _peer(PEERS["binary junk"]) as address:
        done = subprocess.run(
            [sys.executable, "-m", "bench.cli", "dataset", "--scheduler", address],
            cwd=tmp_path,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            capture_output=True,
            text=True,
            timeout=120,
        )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "--scheduler" in lines[0] and not any(tmp_path.iterdir())


@pytest.mark.slow  # starts a scheduler and a worker
def test_a_scheduler_with_a_worker_passes():
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=1, processes=True, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        assert bench.cli.args.check_executor(None, cluster.scheduler_address) == "dask"

"""Provenance: one ``manifest.json`` per output folder, written the same way by every command.

A manifest says what made the folder (``kind``: the command), with which config, seed, package
versions, machine (:func:`machine`) and Mitsuba variant, from which input files (path ->
SHA-256), what it wrote, and when and for how long. Its ``kind`` is also the folder's claim: a
command refuses a folder that holds another command's manifest
(:func:`bench.common.run_folder.claim`), before any work and before writing anything, so two
commands pointed at one folder never overwrite each other's results.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import os
import platform
import sys
import time
import tomllib
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

from bench.common.atomic import write_json
from scenes.bounded_read import read_json
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH

SCHEMA = 1
MANIFEST = "manifest.json"
#: SIMD levels a manifest names, widest first (x86 and Arm flag names of /proc/cpuinfo).
SIMD_LEVELS = ("avx512f", "avx2", "avx", "sse4_2", "sve", "asimd")
#: Lines read of /proc/cpuinfo at most: the first processor's block fits, and a machine with
#: hundreds of cores is not read whole.
CPUINFO_LINES = 200
#: This project's distribution name (pyproject.toml's ``[project] name``).
DISTRIBUTION = "whiskerbench"
PACKAGES = (
    "mitsuba",
    "drjit",
    "opencv-contrib-python-headless",
    "numpy",
    "pandas",
    "pyarrow",
    "matplotlib",
    "trimesh",
)


def whiskerbench_version() -> str:
    """This project's version: the installed distribution's, else (a source tree run without
    ``pip install``, e.g. ``PYTHONPATH=.``) the one its pyproject.toml declares."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
    try:
        return tomllib.loads(pyproject.read_text())["project"]["version"]
    except (OSError, KeyError, tomllib.TOMLDecodeError):  # package files copied on their own
        return "unknown"


def package_versions() -> dict[str, str]:
    """Python's and every package's version that shapes the results, this project's first."""
    return dict(_versions())


@functools.cache  # once per process: each lookup scans the installed distributions (~2 ms)
def _versions() -> tuple[tuple[str, str], ...]:
    versions = {"python": platform.python_version(), DISTRIBUTION: whiskerbench_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return tuple(versions.items())


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file, read in 1 MiB blocks (memory stays bounded for any video)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def json_sha256(obj: Any) -> str:
    """SHA-256 of a JSON value's canonical text: equal configs give equal hashes."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def cpu_summary(cpuinfo: Iterable[str]) -> tuple[str | None, str | None]:
    """(model, widest SIMD level of :data:`SIMD_LEVELS`) from the lines of ``/proc/cpuinfo``'s
    first processor; None for what it does not say."""
    model = simd = None
    for line in cpuinfo:
        key, sep, value = line.partition(":")
        key = key.strip().lower()
        if not sep:
            continue
        if key in ("model name", "hardware") and model is None:
            model = value.strip() or None
        elif key in ("flags", "features"):
            flags = set(value.split())
            simd = next((level for level in SIMD_LEVELS if level in flags), None)
    return model, simd


@functools.cache
def machine() -> dict[str, Any]:
    """The CPU of this process (a manifest's writer, a sample's worker): ``cpu`` (model),
    ``cores`` (logical) and ``simd`` (its widest level). A pool's workers share the machine; a
    remote Dask cluster's may not.

    NumPy's kernels and Dr.Jit's LLVM kernels (16 lanes with AVX-512F, 8 with AVX2) follow the
    SIMD level, and with it the last bits of labels, renders and tables: a byte comparison
    between runs holds on one kind of machine (docs/datasets.md, "Bytes across machines").
    """
    lines: list[str] = []
    try:
        with open("/proc/cpuinfo", errors="replace") as f:
            for line in itertools.islice(f, CPUINFO_LINES):
                if not line.strip():
                    break  # the first processor's block is enough
                lines.append(line)
    except OSError:  # not Linux, or no /proc
        pass
    model, simd = cpu_summary(lines)
    return {
        "cpu": model or platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "simd": simd,
    }


def current_variant() -> str | None:
    """The Mitsuba variant set in this process, or None when Mitsuba was never loaded."""
    mi = sys.modules.get("mitsuba")
    return mi.variant() if mi is not None else None


def read_manifest(folder: Path) -> dict | None:
    """``folder/manifest.json`` as a dict; None when there is none (or it is not a JSON object)."""
    path = Path(folder) / MANIFEST
    try:
        record = read_json(path, RECORD_BYTES, RECORD_DEPTH)
    except (OSError, ValueError):  # absent, unreadable, or not JSON: nobody's claim
        return None
    return record if isinstance(record, dict) else None


def kind_of(record: Mapping) -> str:
    """The command that wrote a manifest; manifests from before ``kind`` are recognized by keys."""
    if "kind" in record:
        return str(record["kind"])
    if record.get("study") == "detectability":
        return "detectability"
    if "settings_sha256" in record and "files" in record:
        return "dataset"
    return "unknown"


class RunClock:
    """When a command started (UTC) and how long it has run (monotonic)."""

    def __init__(self) -> None:
        self.started = datetime.now(UTC).isoformat(timespec="seconds")
        self._t0 = time.perf_counter()

    def elapsed_s(self) -> float:
        return time.perf_counter() - self._t0


def input_digests(paths: Iterable[Path]) -> dict[str, str]:
    """{path: SHA-256} of the files a command read (a manifest's ``inputs``); paths below the
    working folder (a shipped profile run from a clone) are written relative to it."""
    cwd = Path.cwd()
    return {
        str(Path(p).relative_to(cwd) if Path(p).is_relative_to(cwd) else p): sha256(p)
        for p in paths
    }


def hash_files(paths: Iterable[Path], root: Path) -> dict[str, str]:
    """{path relative to ``root``: SHA-256} of each file."""
    return {str(Path(p).relative_to(root)): sha256(p) for p in sorted(paths)}


def build_manifest(
    kind: str,
    clock: RunClock,
    config: Any,
    seed: int | None = None,
    variant: str | None = None,
    inputs: Mapping[str, str] | None = None,
    outputs: Mapping[str, str] | None = None,
    finished: bool = True,
    **extra: Any,
) -> dict:
    """The common fields (see the module docstring), then ``extra`` (a command's own figures).

    ``wall_s`` is the seconds since ``clock`` started unless ``extra`` gives it (the study
    gives its phases). An unfinished manifest (``finished: None``) marks a run under way.
    """
    record = {
        "kind": kind,
        "schema": SCHEMA,
        "config": config,
        "seed": seed,
        "versions": package_versions(),
        "machine": dict(machine()),  # a copy: the cached record stays as read
        "variant": variant if variant is not None else current_variant(),
        "inputs": dict(inputs or {}),
        "outputs": dict(outputs or {}),
        "started": clock.started,
        "finished": datetime.now(UTC).isoformat(timespec="seconds") if finished else None,
        "wall_s": round(clock.elapsed_s(), 3),
    }
    record.update(extra)
    return record


def write_manifest(folder: Path, record: Mapping) -> dict:
    """Write ``record`` as ``folder/manifest.json`` (atomically) and return it as a dict."""
    record = json.loads(json.dumps(record, default=str))  # what a reader will get back
    write_json(Path(folder) / MANIFEST, record)
    return record

"""A scored sample as a resumable unit: ``score`` (and ``compare``, which scores through it)
reuses a sample's detections and its row of ``samples.csv`` from an earlier run instead of
detecting again, so an interrupted ``score`` resumes and ``compare`` after ``score`` (the
README's quick start) or with one pipeline added reruns none of the finished work.

A sample is reused only when its record (``<sample id>/score.json``, :mod:`bench.common.units`)
is intact and was made by the same pipeline settings on the same dataset path, with the same
video (SHA-256), the same foliage threshold handed in from its twin, and the same code and
libraries: the hash of every Python file of the project (:func:`code_sha256`) and the versions
of the packages that shape the answer, so an edited pipeline or an upgraded library is never
answered from old detections; and when every file of its detection folder hashes as recorded.
Anything else is detected again. Another tool's detections (``--detections``) and a detector
plugin's (its code is the user's) are always scored anew.
"""

from __future__ import annotations

import functools
import hashlib
import json
from importlib import metadata
from pathlib import Path

from bench.common.manifest import json_sha256, package_versions, sha256
from bench.common.units import reusable, write_unit

RECORD = "score.json"  # in the sample's detection folder
_MARKS = (RECORD, "detections.parquet", "branches.json")  # a sample's detection folder
_PACKAGES = ("scenes", "renderers", "pipeline", "bench")  # the project's code


@functools.cache
def code_sha256() -> str:
    """SHA-256 over the project's Python files (their paths and bytes), once per process."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for package in _PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()


#: The peer detectors' distributions: their version is part of a peer pipeline's answer.
PEERS = ("locus-tag", "apriltag-python")


def unit_settings(settings_sha256: str) -> str:
    """The settings hash of a score run's units: its settings, the code and the versions of
    the libraries that shape the answer (OpenCV, NumPy, ..., the peers)."""
    versions = dict(package_versions())
    for peer in PEERS:
        try:
            versions[peer] = metadata.version(peer)
        except metadata.PackageNotFoundError:
            versions[peer] = None
    return json_sha256({"score": settings_sha256, "code": code_sha256(), "versions": versions})


def run_units(settings_sha256: str, config, external: bool) -> str | None:
    """The units' settings hash of a score run, or None where nothing may be reused: another
    tool's detections (their file is not in the settings) or a detector plugin's (its code is
    the user's, outside :func:`code_sha256`)."""
    if external or str(config.detector.backend).startswith("plugin:"):
        return None
    return unit_settings(settings_sha256)


def check_own_samples(out_dir: Path, sample_ids) -> None:
    """ValueError, before anything is written, when ``out_dir`` holds the detections of samples
    that are not the dataset's (``sample_ids``): another dataset's scores, which a run would
    leave mixed with its own."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        return
    foreign = sorted(
        p.name
        for p in out_dir.iterdir()
        if p.is_dir() and p.name not in sample_ids and any((p / n).exists() for n in _MARKS)
    )
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise ValueError(
            f"{out_dir}: holds the scores of {foreign[0]}{more}, not a sample of this dataset "
            "(another dataset's); choose another --out or delete them"
        )


def _unit(out_dir: Path, task) -> tuple[Path, dict]:
    """A sample task's folder of detections and the fields its record must hold to be reused:
    its id, the twin's threshold handed in and its video's SHA-256 (``task``: a
    :class:`bench.evaluate.score._SampleTask`)."""
    sample_id = task.record["sample_id"]
    expect = {"unit": sample_id, "threshold_in": task.threshold, "video_sha256": task.video_sha256}
    return Path(out_dir) / sample_id, expect


def reused_row(out_dir: Path, settings: str, task) -> tuple[dict, float | None] | None:
    """(row, foliage threshold) of ``task``'s sample scored before into ``out_dir`` with these
    settings, code, threshold and video, its files verified; None when it must be scored."""
    folder, expect = _unit(out_dir, task)
    record = reusable(folder / RECORD, settings, expect)
    try:
        return _row(record["row"]), record["threshold"]
    except (TypeError, KeyError, ValueError):  # none, or not one this module wrote
        return None


def seal_row(
    out_dir: Path, settings: str, task, row: dict, threshold: float | None
) -> tuple[dict, float | None]:
    """Record ``task``'s sample just scored (its detection folder's files by hash); return its
    row and threshold as a rerun reads them back (plain JSON values), so both runs' tables are
    alike."""
    folder, expect = _unit(out_dir, task)
    folder.mkdir(parents=True, exist_ok=True)
    files = {
        p.relative_to(folder).as_posix(): sha256(p)
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != RECORD
    }
    record = {
        **expect,
        "settings_sha256": settings,
        "files": files,
        "row": list(row.items()),  # pairs: the columns' order survives the sorted JSON
        "threshold": threshold,
    }
    sealed = write_unit(folder / RECORD, json.loads(json.dumps(record, default=_plain)))
    return _row(sealed["row"]), sealed["threshold"]


def _row(pairs: list) -> dict:
    """A row from its recorded (column, value) pairs; TypeError or ValueError if not pairs."""
    row = dict(pairs)
    if not all(isinstance(k, str) for k in row):
        raise TypeError("a column name that is not text")
    return row


def _plain(value):
    """A NumPy scalar as the Python number it holds (JSON cannot write NumPy's own)."""
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON")

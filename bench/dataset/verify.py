"""A dataset's integrity, checked before anything of it is scored.

The dataset manifest lists the SHA-256 of every sample's files, ``sample.json`` included, and
each ``sample.json`` lists those of its other files. :func:`verify_dataset` hashes every file
once and refuses, naming the file, a dataset where they disagree: a video swapped between
samples, edited labels or an edited ground truth (branch positions in ``sample.json``) must never
be scored. Files edited and re-sealed with their hashes must still fit the sample: the video
holds ``sample.json``'s frames and the labels one row per marker for each. Sample ids are plain
folder names equal to their folder's, so no id leads a reader or writer outside its folders.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from bench.common.manifest import MANIFEST, kind_of, read_manifest, sha256
from bench.dataset.config import SAMPLE_FILES
from bench.dataset.format import DatasetFormatError, check_format_version
from scenes.bounded_read import read_json
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH, VIDEO_FRAMES

#: A sample id: a plain folder name (no separator, no leading dot, so never ``..``).
SAMPLE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
#: What scoring reads from each sample.json.
RECORD_KEYS = (
    "sample_id",
    "files",
    "foliage",
    "distance",
    "branches_mm",
    "branch_gaps",
    "protocol",
    "lighting",
    "frames",
)


class DatasetIntegrityError(DatasetFormatError):
    """A dataset whose files do not match its recorded hashes, or that is not a dataset (a
    :class:`~bench.dataset.format.DatasetFormatError`, so a ValueError)."""


@dataclass(frozen=True)
class VerifiedDataset:
    """A dataset whose every file matched its recorded SHA-256 when it was verified."""

    folder: Path
    records: dict[str, dict]  # sample id -> its sample.json, in id order
    digests: dict[str, str]  # "<id>/<file name>" -> SHA-256 (sample.json included)
    manifest_sha256: str

    def inputs(self) -> dict[str, str]:
        """{path: SHA-256} of every file read, the manifest included: a manifest's ``inputs``."""
        files = {str(self.folder / rel): digest for rel, digest in self.digests.items()}
        return {str(self.folder / MANIFEST): self.manifest_sha256, **files}


def check_sample_id(sample_id: object, where: str) -> str:
    """``sample_id`` if it is a plain folder name; DatasetIntegrityError naming ``where``."""
    if not isinstance(sample_id, str) or not SAMPLE_ID.fullmatch(sample_id):
        raise DatasetIntegrityError(
            f"{where}: sample id {sample_id!r} is not a plain folder name "
            f"(letters, digits, '.', '_', '+', '-'; starting with a letter or digit)"
        )
    return sample_id


def verify_dataset(folder: Path, progress: bool = False) -> VerifiedDataset:
    """Hash every file of every sample and compare with the manifest and ``sample.json``.

    Raises DatasetIntegrityError (one line naming the file) on the first disagreement, a sample
    missing from the manifest or listed there but absent, or an unfinished dataset; a
    DatasetFormatError for a dataset of a newer major format version.
    """
    folder = Path(folder)
    manifest_path = folder / MANIFEST
    manifest = read_manifest(folder)
    if manifest is None or kind_of(manifest) != "dataset":
        raise DatasetIntegrityError(
            f"{manifest_path}: no dataset manifest (not a folder made by `whiskerbench dataset`)"
        )
    check_format_version(manifest, manifest_path)  # a newer major version: not read here
    if not isinstance(manifest.get("files"), dict) or not isinstance(manifest.get("samples"), list):
        raise DatasetIntegrityError(
            f"{manifest_path}: the dataset run did not finish; rerun `whiskerbench dataset`"
        )
    listed = [check_sample_id(s, str(manifest_path)) for s in manifest["samples"]]
    on_disk = {p.parent.name for p in folder.glob("*/sample.json")}
    unlisted = sorted(on_disk - set(listed))
    if unlisted:
        raise DatasetIntegrityError(
            f"{folder / unlisted[0] / 'sample.json'}: a sample not in the dataset manifest"
        )
    if not listed:
        raise DatasetIntegrityError(f"{manifest_path}: the dataset has no samples")
    expected = {f"{s}/{name}" for s in listed for name in (*SAMPLE_FILES, "sample.json")}
    if set(manifest["files"]) != expected:
        odd = sorted(set(manifest["files"]) ^ expected)[0]
        raise DatasetIntegrityError(f"{manifest_path}: lists {odd!r} wrongly (edited?)")
    records = {}
    digests: dict[str, str] = {}
    for sample_id in tqdm(
        sorted(listed), desc="verify samples", unit="sample", disable=not progress
    ):
        records[sample_id] = _verify_sample(folder, sample_id, manifest["files"], digests)
    return VerifiedDataset(folder, records, digests, sha256(manifest_path))


def _verify_sample(folder: Path, sample_id: str, files: dict, digests: dict[str, str]) -> dict:
    """One sample's sample.json, after checking it and every file it lists against ``files``."""
    record_path = folder / sample_id / "sample.json"
    for name in ("sample.json", *SAMPLE_FILES):
        path = folder / sample_id / name
        if not path.is_file():
            raise DatasetIntegrityError(f"{path}: listed in the dataset manifest but missing")
        digests[f"{sample_id}/{name}"] = digest = sha256(path)
        if digest != files[f"{sample_id}/{name}"]:
            raise DatasetIntegrityError(
                f"{path}: SHA-256 differs from the dataset manifest (swapped or edited?)"
            )
        if name == "sample.json":
            record = read_record(record_path, sample_id)
        elif record["files"].get(name) != digest:
            raise DatasetIntegrityError(
                f"{path}: SHA-256 differs from {record_path.name}'s (swapped or edited?)"
            )
    _check_fit(folder / sample_id, record)
    return record


def _check_fit(folder: Path, record: dict) -> None:
    """The video holds sample.json's frames and the labels one row per marker for each of them
    (:func:`scenes.tables.check_labels`): files edited and re-sealed with their hashes pass the
    check above. DatasetIntegrityError naming the file otherwise."""
    import pandas as pd  # here, not at import: `import whiskerbench` loads no pandas or OpenCV

    from bench.common.video import video_info
    from scenes.tables import check_labels

    video, labels = folder / "video.mp4", folder / "labels.parquet"
    n_frames = video_info(video).frame_count
    if n_frames != record["frames"]:
        raise DatasetIntegrityError(
            f"{video}: {n_frames} frames where sample.json says {record['frames']}"
        )
    try:
        table = pd.read_parquet(labels)
    except Exception as exc:  # pyarrow's errors have no common base but Exception
        reason = type(exc).__name__
        raise DatasetIntegrityError(f"{labels}: not a Parquet table ({reason})") from None
    try:
        check_labels(table, n_frames, labels)
    except ValueError as exc:
        raise DatasetIntegrityError(str(exc)) from None


def read_record(path: Path, sample_id: str) -> dict:
    """A ``sample.json`` (at ``path``, of ``sample_id``) with the keys scoring reads, checked;
    DatasetIntegrityError in one line naming the file otherwise. Its hashes are not checked."""
    try:
        record = read_json(path, RECORD_BYTES, RECORD_DEPTH)
    except (OSError, ValueError) as exc:
        raise DatasetIntegrityError(f"{path}: not readable JSON ({exc})") from None
    if not isinstance(record, dict) or not all(k in record for k in RECORD_KEYS):
        raise DatasetIntegrityError(f"{path}: needs the keys {', '.join(RECORD_KEYS)}")
    check_sample_id(record["sample_id"], str(path))
    if record["sample_id"] != sample_id:
        raise DatasetIntegrityError(
            f"{path}: sample id {record['sample_id']!r} is not its folder's name {sample_id!r}"
        )
    if not isinstance(record["files"], dict) or set(record["files"]) != set(SAMPLE_FILES):
        raise DatasetIntegrityError(f"{path}: 'files' must list {', '.join(SAMPLE_FILES)}")
    _check_truth(record, path)
    return record


def _check_truth(record: dict, path: Path) -> None:
    """The values scoring reads: names, finite branch positions, one gap (i, i + 1) each."""
    for key in ("foliage", "distance", "lighting"):
        if not isinstance(record[key], str):
            raise DatasetIntegrityError(f"{path}: '{key}' must be a name, got {record[key]!r}")
    protocol = record["protocol"]
    if not isinstance(protocol, dict) or not isinstance(protocol.get("name"), str):
        raise DatasetIntegrityError(f"{path}: 'protocol' must be an object with a 'name'")
    if not _is_number(protocol.get("fps")) or protocol["fps"] <= 0:
        raise DatasetIntegrityError(
            f"{path}: 'protocol.fps' must be a finite number > 0, got {protocol.get('fps')!r}"
        )
    frames = record["frames"]
    if not isinstance(frames, int) or isinstance(frames, bool) or not 1 <= frames <= VIDEO_FRAMES:
        raise DatasetIntegrityError(
            f"{path}: 'frames' must be an integer in 1..{VIDEO_FRAMES}, got {frames!r}"
        )
    branches, gaps = record["branches_mm"], record["branch_gaps"]
    if not isinstance(branches, list) or not all(map(_is_number, branches)):
        raise DatasetIntegrityError(f"{path}: 'branches_mm' must be a list of finite numbers (mm)")
    if not isinstance(gaps, list) or len(gaps) != len(branches) or not all(map(_is_gap, gaps)):
        raise DatasetIntegrityError(
            f"{path}: 'branch_gaps' must hold one [i, i + 1] pair of whisker indices per branch"
        )


def _is_number(value: object) -> bool:
    """A finite JSON number (not a boolean)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _is_gap(gap: object) -> bool:
    """A gap between two neighbouring whiskers: [i, i + 1], integers."""
    return (
        isinstance(gap, list)
        and len(gap) == 2
        and all(isinstance(i, int) and not isinstance(i, bool) for i in gap)
        and gap[1] == gap[0] + 1
    )

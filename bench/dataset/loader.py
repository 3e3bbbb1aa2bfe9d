"""Read a benchmark dataset (``docs/dataset_format.md``): samples, their frames and labels, lazily.

    ds = open_dataset("data/quick")          # whiskerbench.open_dataset
    for sample in ds:                        # .id, .meta (sample.json), .camera, .profile, .labels
        for frame in sample.frames():        # .index, .time_s, .image (H, W) uint8, .labels
            ...
    ds["soft-far-0-outdoor-sun"].frame(40)   # random access, by seeking

Opening reads ``manifest.json`` only, and checks that it is a finished dataset of a format
version this reader reads and that every file it lists is there; a sample reads its
``sample.json`` when it is taken from the dataset, ``camera.json`` and ``labels.parquet`` when
first asked for, and decodes a frame when it is asked for (:class:`~bench.common.grey_video.
GreyVideo`: the next frame is decoded, another is sought, exactly, for this project's videos).
Hashes are checked on request only: ``open_dataset(path, verify=True)`` or
:meth:`Dataset.verify` (:func:`bench.dataset.verify.verify_dataset`: every file's SHA-256
against ``sample.json`` and the manifest). Imports no Mitsuba or Dr.Jit.

Anything that is not such a dataset (no folder, no or another command's manifest, malformed
JSON, a missing file, a newer major format version, a video that does not match its labels or
camera) raises :class:`~bench.dataset.format.DatasetFormatError` (a ValueError), one line naming
the file.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common.grey_video import GreyVideo
from bench.common.manifest import MANIFEST, kind_of
from bench.dataset.config import SAMPLE_FILES
from bench.dataset.format import DatasetFormatError, check_format_version
from bench.dataset.verify import VerifiedDataset, check_sample_id, read_record, verify_dataset
from scenes.bounded_read import read_json
from scenes.camera import FisheyeCamera
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH
from scenes.profile import CameraProfile
from scenes.tables import check_labels


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame of a sample: its index in the video (from 0), time (s, the middle of its
    exposure), grey image ((H, W) uint8) and its rows of ``labels.parquet`` (one per marker)."""

    index: int
    time_s: float
    image: np.ndarray
    labels: pd.DataFrame


class Sample:
    """One sample of a dataset (its folder ``<dataset>/<id>/``); see the module docstring."""

    def __init__(self, folder: Path, sample_id: str, meta: dict | None = None) -> None:
        self.id = sample_id
        self.folder = Path(folder) / sample_id
        #: ``sample.json`` as a dict (checked for the keys scoring reads and ``frames``).
        self.meta = meta if meta is not None else read_record(self.folder / "sample.json", self.id)
        frames = self.meta.get("frames")
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 0:
            raise DatasetFormatError(
                f"{self.folder / 'sample.json'}: 'frames' must be a count, got {frames!r}"
            )
        self._frames = frames
        self._video: GreyVideo | None = None

    def __repr__(self) -> str:
        return f"Sample({self.id!r}, {len(self)} frames)"

    def __len__(self) -> int:
        return self._frames

    @property
    def video_path(self) -> Path:
        return self.folder / "video.mp4"

    @functools.cached_property
    def profile(self) -> CameraProfile:
        """The camera twin the sample was recorded through (``camera.json``)."""
        path = self.folder / "camera.json"
        try:
            data = read_json(path, RECORD_BYTES, RECORD_DEPTH)
        except (OSError, ValueError) as exc:
            raise DatasetFormatError(f"{path}: not readable JSON ({_line(exc)})") from None
        try:
            return CameraProfile.from_json(data)
        except (ValueError, TypeError) as exc:  # ProfileError names the field
            raise DatasetFormatError(f"{path}: not a camera profile: {_line(exc)}") from None

    @property
    def camera(self) -> FisheyeCamera:
        """The lens geometry the labels were projected with (``camera.json``'s ``lens``)."""
        return self.profile.lens

    @functools.cached_property
    def labels(self) -> pd.DataFrame:
        """``labels.parquet``: one row per frame and marker (:data:`scenes.tables.LABELS`)."""
        path = self.folder / "labels.parquet"
        try:
            table = pd.read_parquet(path)
        except Exception as exc:  # pyarrow's errors have no common base but Exception
            raise DatasetFormatError(f"{path}: not a Parquet table ({_line(exc)})") from None
        try:
            check_labels(table, len(self), path)
        except ValueError as exc:
            says = f"{self.folder / 'sample.json'} says {len(self)} frames"
            raise DatasetFormatError(f"{_line(exc)}, where {says}") from None
        return table

    @functools.cached_property
    def _rows(self) -> tuple[list[slice | np.ndarray], np.ndarray]:
        """(each frame's rows of :attr:`labels`: a slice where the table is in frame order, as
        written, else their positions; each frame's time_s, NaN for a frame without rows)."""
        table, n = self.labels, len(self)
        frames = table["frame"].to_numpy()
        if np.all(frames[1:] >= frames[:-1]):
            lo, hi = (np.searchsorted(frames, np.arange(n), side=s) for s in ("left", "right"))
            rows: list[slice | np.ndarray] = [slice(a, b) for a, b in zip(lo, hi, strict=True)]
        else:
            positions = table.groupby("frame").indices
            rows = [positions.get(f, np.zeros(0, int)) for f in range(n)]
        first = table.groupby("frame")["time_s"].first()
        times = np.full(n, np.nan)
        times[first.index.to_numpy()] = first.to_numpy()
        return rows, times

    # --- frames
    def frame(self, index: int) -> Frame:
        """Frame ``index`` (negative counts from the end), decoded now; IndexError if none."""
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise TypeError(f"a frame is taken by integer index, not {type(index).__name__}")
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"{self.id}: frame {index} out of range (the sample has {n})")
        if self._video is None:
            self._video = self._open_video()
        return self._make_frame(self._video, index % n)

    def frames(self) -> Iterator[Frame]:
        """Every frame in order, each decoded when the loop reaches it (its own video reader, so
        :meth:`frame` calls in between do not disturb it)."""
        video = self._open_video()
        try:
            for index in range(len(self)):
                yield self._make_frame(video, index)
        finally:
            video.close()

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def close(self) -> None:
        """Release the video :meth:`frame` keeps open (reopened if a frame is asked again)."""
        if self._video is not None:
            self._video.close()
            self._video = None

    def __enter__(self) -> Sample:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __getstate__(self) -> dict:
        """Picklable (for worker processes): the open video stays behind, reopened on use."""
        return {**self.__dict__, "_video": None}

    def _make_frame(self, video: GreyVideo, index: int) -> Frame:
        try:
            image = video.read(index)
        except ValueError as exc:
            raise DatasetFormatError(_line(exc)) from None
        rows, times = self._rows
        return Frame(index, float(times[index]), image, self.labels.iloc[rows[index]])

    def _open_video(self) -> GreyVideo:
        path = self.video_path
        try:
            video = GreyVideo(path)
        except (OSError, ValueError) as exc:
            raise DatasetFormatError(f"{path}: not a readable video ({_line(exc)})") from None
        camera = self.camera
        problem = None
        if (video.width, video.height) != (camera.width_px, camera.height_px):
            problem = (
                f"{video.width}x{video.height} px where camera.json's lens is "
                f"{camera.width_px}x{camera.height_px}"
            )
        elif video.frame_count != len(self):
            problem = f"{video.frame_count} frames where sample.json says {len(self)}"
        if problem:
            video.close()
            raise DatasetFormatError(f"{path}: {problem}")
        return video


class Dataset:
    """A dataset folder: its manifest and samples, in the manifest's order; see the module
    docstring. ``ds[i]`` and ``ds["sample id"]`` return a new :class:`Sample` each time."""

    def __init__(self, path: Path, manifest: dict, format_version: str) -> None:
        self.path = Path(path)
        self.manifest = manifest
        self.format_version = format_version
        self.sample_ids: tuple[str, ...] = tuple(manifest["samples"])
        #: Set by :meth:`verify`: the records and SHA-256 of every file, as checked.
        self.verified: VerifiedDataset | None = None

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r}, {len(self)} samples, format {self.format_version})"

    def __len__(self) -> int:
        return len(self.sample_ids)

    def __contains__(self, sample_id: object) -> bool:
        return sample_id in self.sample_ids

    def __iter__(self) -> Iterator[Sample]:
        for sample_id in self.sample_ids:
            yield self[sample_id]

    def __getitem__(self, key: int | str) -> Sample:
        if isinstance(key, str):
            if key not in self.sample_ids:
                raise KeyError(f"{key!r}: no such sample in {self.path}")
            sample_id = key
        elif isinstance(key, int | np.integer) and not isinstance(key, bool):
            if not -len(self) <= key < len(self):
                raise IndexError(f"sample {key} out of range (the dataset has {len(self)})")
            sample_id = self.sample_ids[key]
        else:
            raise TypeError(f"a sample is taken by index or id, not {type(key).__name__}")
        meta = self.verified.records[sample_id] if self.verified is not None else None
        return Sample(self.path, sample_id, meta)

    def verify(self, progress: bool = False) -> VerifiedDataset:
        """Check every file's SHA-256 against ``sample.json`` and the manifest, now
        (:class:`~bench.dataset.verify.DatasetIntegrityError`, a DatasetFormatError, naming
        the first file that differs); samples taken afterwards use the records checked."""
        self.verified = verify_dataset(self.path, progress=progress)
        return self.verified


def open_dataset(path: str | Path, verify: bool = False) -> Dataset:
    """The dataset in folder ``path`` (made by ``whiskerbench dataset``); ``verify``: check
    every file's SHA-256 first (:meth:`Dataset.verify`). DatasetFormatError, one line naming
    the file, for anything that is not a finished dataset of a format version read here."""
    folder = Path(path)
    if not folder.is_dir():
        why = "a file" if folder.exists() else "no such folder"
        raise DatasetFormatError(f"{folder}: not a dataset folder ({why})")
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise DatasetFormatError(
            f"{manifest_path}: missing: not a dataset folder (made by `whiskerbench dataset`)"
        )
    try:
        manifest = read_json(manifest_path, RECORD_BYTES, RECORD_DEPTH)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DatasetFormatError(f"{manifest_path}: not valid JSON ({_line(exc)})") from None
    if not isinstance(manifest, dict):
        raise DatasetFormatError(f"{manifest_path}: not a JSON object")
    if kind_of(manifest) != "dataset":
        raise DatasetFormatError(
            f"{manifest_path}: the output of `{kind_of(manifest)}`, not of `whiskerbench dataset`"
        )
    version = check_format_version(manifest, manifest_path)
    files, samples = manifest.get("files"), manifest.get("samples")
    if not isinstance(files, dict) or not isinstance(samples, list):
        raise DatasetFormatError(
            f"{manifest_path}: the dataset run did not finish; rerun `whiskerbench dataset`"
        )
    for sample_id in samples:
        check_sample_id(sample_id, str(manifest_path))
        for name in ("sample.json", *SAMPLE_FILES):
            file = folder / sample_id / name
            if not file.is_file():
                raise DatasetFormatError(f"{file}: missing (a file of a sample in {MANIFEST})")
    dataset = Dataset(folder, manifest, version)
    if verify:
        dataset.verify()
    return dataset


def _line(message: object) -> str:
    """``message`` on one line."""
    return " ".join(str(message).split())

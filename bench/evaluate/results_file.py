"""Results files from any tool: another method's detections, read and checked at the boundary.

A detections results file (``docs/results_format.md``) is a Parquet or CSV table: ``sample_id``
plus the detections table's own columns (:mod:`scenes.tables`): ``frame``, ``marker_id``, the
corners ``c{0..3}_{x,y}_px``; optionally the 12 pose columns of ``T_cam_marker``, the seconds the
method spent on each frame (:data:`TIME_COLUMN`) and the dataset manifest's SHA-256
(:data:`SHA_COLUMN`). A folder holds one such file per sample, named ``<sample id>.csv`` or
``.parquet``, not both (``sample_id`` may then be left out; a header only: nothing detected).

:func:`read_detections` reads it with bounded reads (:data:`MAX_FILE_BYTES` per file,
:data:`MAX_ROWS` in all) and refuses, in one line naming the file and the row or column and what
was expected (:class:`ResultsFileError`, a ValueError), anything the scorer could misread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common.manifest import sha256
from bench.dataset.verify import SAMPLE_ID, VerifiedDataset
from scenes.bounded_read import input_problem
from scenes.input_limits import RESULTS_FILE_BYTES
from scenes.tables import CORNER_COLUMNS, ROTATION_COLUMNS, TRANSLATION_COLUMNS

#: Largest results file read (bytes), and most rows in all files together.
MAX_FILE_BYTES = RESULTS_FILE_BYTES
MAX_ROWS = 10_000_000
SUFFIXES = (".csv", ".parquet")
#: How far (px) past the image's edge ([-0.5, W - 0.5] x [-0.5, H - 0.5]) a corner may lie.
OUTSIDE_PX = 8.0
TIME_COLUMN = "frame_time_s"
#: A frame's time (s), and ``--fps`` as their inverse: 1 us a frame is 1e6 frames/s, beyond any
#: detector (OpenCV's ArUco takes 66 us on a blank 64 x 64 image here); an hour a frame is no
#: detector either. A time of 0 is a timer too coarse or a time left out, not a speed. Within
#: these the total time of MAX_ROWS frames (3.6e10 s) and the frames/s stay finite: no overflow
#: warning, no inf or 0 frames/s in samples.csv.
MIN_FRAME_TIME_S = 1e-6
MAX_FRAME_TIME_S = 3600.0
SHA_COLUMN = "dataset_sha256"
CORNERS = [name for pair in CORNER_COLUMNS for name in pair]
POSE = [*ROTATION_COLUMNS, *TRANSLATION_COLUMNS]
REQUIRED = ["sample_id", "frame", "marker_id", *CORNERS]
OPTIONAL = [*POSE, TIME_COLUMN, SHA_COLUMN]


class ResultsFileError(ValueError):
    """A results file the scorer refuses: one line naming the file, row or column."""


@dataclass(frozen=True)
class SampleFacts:
    """What a sample's detections are checked against."""

    frames: int
    width_px: int
    height_px: int
    family_size: int  # marker ids of the family: 0 .. family_size - 1


@dataclass(frozen=True)
class ExternalDetections:
    """Validated detections of one method: per sample, rows sorted by frame and marker id."""

    source: Path
    files: dict[str, str]  # path -> SHA-256
    tables: dict[str, pd.DataFrame]  # sample id -> sample_id-less rows
    has_pose: bool
    has_time: bool


def read_detections(
    path: Path, verified: VerifiedDataset, facts: dict[str, SampleFacts]
) -> ExternalDetections:
    """Read a results file or folder of them (see the module docstring) for the dataset
    ``verified``; ResultsFileError on anything malformed."""
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if not p.name.startswith("."))
        if not files:
            raise ResultsFileError(f"{path}: an empty folder; expected <sample id>.csv/.parquet")
        _one_file_each(path, files)
        per_sample = True
    elif path.is_file():
        files, per_sample = [path], False
    else:
        raise ResultsFileError(f"{path}: {input_problem(path) or 'no such file or folder'}")
    tables: dict[str, pd.DataFrame] = {}
    columns: set[frozenset[str]] = set()
    rows = 0
    for file in files:
        expected = _sample_of(file, facts) if per_sample else None
        table = _read(file, MAX_ROWS - rows)
        rows += len(table)
        table = _check(file, table, expected, verified.manifest_sha256, facts)
        columns.add(frozenset(table.columns))
        for sample_id, part in table.groupby("sample_id", sort=True):
            tables[sample_id] = part.drop(columns="sample_id").reset_index(drop=True)
        if expected is not None:
            tables.setdefault(expected, table.drop(columns="sample_id").iloc[:0])
    if len(columns) > 1:
        raise ResultsFileError(f"{path}: the files have different columns; expected the same")
    missing = [s for s in facts if s not in tables]
    if missing:
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        raise ResultsFileError(
            f"{path}: no detections of sample {missing[0]}{more}; expected every sample of the "
            f"dataset ({'a file each' if per_sample else 'rows'}; a header-only file: none found)"
        )
    names = next(iter(columns))
    return ExternalDetections(
        path,
        {str(f): sha256(f) for f in files},
        dict(sorted(tables.items())),
        has_pose=POSE[0] in names,
        has_time=TIME_COLUMN in names,
    )


def _one_file_each(folder: Path, files: list[Path]) -> None:
    """Refuse a sample with both a .csv and a .parquet file: reading one would drop the other's
    rows unseen (a recall made up from half the results)."""
    seen: dict[str, Path] = {}
    for file in files:
        if file.suffix not in SUFFIXES or not file.is_file():
            continue  # refused as it is read (_sample_of)
        if file.stem in seen:
            raise ResultsFileError(
                f"{folder}: two files for sample {file.stem}: {seen[file.stem].name} and "
                f"{file.name}; expected one <sample id>.csv or .parquet per sample"
            )
        seen[file.stem] = file


def _sample_of(file: Path, facts: dict[str, SampleFacts]) -> str:
    if file.suffix not in SUFFIXES or not file.is_file():
        raise ResultsFileError(f"{file}: expected a <sample id>.csv or .parquet file")
    if file.stem not in facts:
        raise ResultsFileError(f"{file}: {file.stem!r} is not a sample of this dataset")
    return file.stem


def _read(file: Path, rows_left: int) -> pd.DataFrame:
    """The file's table, read no further than the caps allow."""
    size = file.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ResultsFileError(f"{file}: {size} bytes; expected at most {MAX_FILE_BYTES}")
    try:
        if file.suffix == ".parquet":
            import pyarrow.parquet as pq

            n = pq.ParquetFile(file).metadata.num_rows
            if n > rows_left:
                raise ResultsFileError(f"{file}: {n} rows; expected at most {MAX_ROWS} in all")
            return pd.read_parquet(file)
        if file.suffix != ".csv":
            raise ResultsFileError(f"{file}: expected a .csv or .parquet file")
        table = pd.read_csv(  # only an empty cell is empty: "nan", "NA" are text, refused
            file,
            nrows=rows_left + 1,
            dtype={"sample_id": str, SHA_COLUMN: str},
            comment=None,
            keep_default_na=False,
            na_values=[""],
        )
    except ResultsFileError:
        raise
    except Exception as exc:  # noqa: BLE001  (pandas and pyarrow raise many kinds)
        detail = " ".join(str(exc).split())[:200]
        kind = file.suffix[1:]
        raise ResultsFileError(f"{file}: not a readable {kind} table ({detail})") from None
    if len(table) > rows_left:
        raise ResultsFileError(f"{file}: more than {MAX_ROWS} rows in all; expected fewer")
    return table


def _check(
    file: Path,
    table: pd.DataFrame,
    expected: str | None,
    dataset_sha256: str,
    facts: dict[str, SampleFacts],
) -> pd.DataFrame:
    """The table with checked columns and values (sample_id filled in from the file name in a
    folder), sorted; ResultsFileError on the first thing wrong."""
    given = [str(c) for c in table.columns]
    if len(set(given)) != len(given):
        raise ResultsFileError(f"{file}: a column name repeats; expected each once")
    if expected is not None and "sample_id" not in given:
        table = table.assign(sample_id=expected)
    for name in REQUIRED:
        if name not in table.columns:
            raise ResultsFileError(f"{file}: column {name!r} is missing; expected {_listing()}")
    for name in given:
        if name not in REQUIRED + OPTIONAL:
            raise ResultsFileError(
                f"{file}: column {name!r} is not in the format; expected {_listing()}"
            )
    pose = [c for c in POSE if c in table.columns]
    if pose and len(pose) != len(POSE):
        gone = next(c for c in POSE if c not in table.columns)
        raise ResultsFileError(
            f"{file}: column {gone!r} is missing; the pose columns come all 12 or none"
        )
    out = pd.DataFrame({"sample_id": _text(file, table, "sample_id")})
    for name in ("frame", "marker_id"):
        out[name] = _integers(file, table, name)
    for name in CORNERS + pose + ([TIME_COLUMN] if TIME_COLUMN in table else []):
        out[name] = _finite(file, table, name)
    if SHA_COLUMN in table:
        sha = _text(file, table, SHA_COLUMN)
        wrong = np.flatnonzero(sha.str.lower() != dataset_sha256)
        if len(wrong):
            raise ResultsFileError(
                f"{file}: row {wrong[0] + 1}: {SHA_COLUMN} {sha.iloc[wrong[0]]!r} is not this "
                f"dataset's manifest.json (SHA-256 {dataset_sha256}): results of another dataset"
            )
    _check_values(file, out, expected, facts)
    return out.sort_values(["sample_id", "frame", "marker_id"], kind="stable")


def _listing() -> str:
    return (
        f"{', '.join(REQUIRED[:3])}, {CORNERS[0]} .. {CORNERS[-1]}; optional: the 12 pose "
        f"columns ({POSE[0]} .. {POSE[-1]}), {TIME_COLUMN}, {SHA_COLUMN}"
    )


def _first(file: Path, bad: np.ndarray, table: pd.DataFrame, name: str, want: str) -> None:
    """Refuse the first row where ``bad`` holds."""
    hit = np.flatnonzero(bad)
    if len(hit):
        value = table[name].iloc[hit[0]]
        value = value.item() if isinstance(value, np.generic) else value  # 1e-320, not np.float64
        raise ResultsFileError(
            f"{file}: row {hit[0] + 1}: column {name!r} is {value!r}; expected {want}"
        )


def _text(file: Path, table: pd.DataFrame, name: str) -> pd.Series:
    column = table[name]
    bad = ~column.map(lambda v: isinstance(v, str) and v != "").to_numpy(bool)
    _first(file, bad, table, name, "text")
    return column.astype(str).reset_index(drop=True)


def _numbers(file: Path, table: pd.DataFrame, name: str, want: str) -> np.ndarray:
    column = table[name]
    if column.dtype.kind == "b":  # text is read below, row by row
        raise ResultsFileError(f"{file}: column {name!r} is {column.dtype}; expected {want}")
    numbers = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)
    _first(file, np.isnan(numbers) & column.notna().to_numpy(), table, name, want)
    return numbers


def _integers(file: Path, table: pd.DataFrame, name: str) -> np.ndarray:
    numbers = _numbers(file, table, name, "an integer")
    bad = ~np.isfinite(numbers) | (numbers != np.round(numbers)) | (np.abs(numbers) > 2**53)
    _first(file, bad, table, name, "an integer")
    return numbers.astype(np.int64)


def _finite(file: Path, table: pd.DataFrame, name: str) -> np.ndarray:
    numbers = _numbers(file, table, name, "a finite number")
    _first(file, ~np.isfinite(numbers), table, name, "a finite number")
    return numbers


def _check_values(
    file: Path, out: pd.DataFrame, expected: str | None, facts: dict[str, SampleFacts]
) -> None:
    """Sample ids, frames, marker ids, corners within the image, duplicates, frame times."""
    ids = out["sample_id"]
    if expected is not None:
        bad = (ids != expected).to_numpy()
        _first(file, bad, out, "sample_id", f"{expected!r} (the file's name)")
    for k, sid in enumerate(ids):
        if sid not in facts:
            plain = "" if SAMPLE_ID.fullmatch(sid) else " (not even a sample id)"
            raise ResultsFileError(
                f"{file}: row {k + 1}: sample_id {sid!r} is not a sample of "
                f"this dataset{plain}; expected results of this dataset"
            )
    fact = [facts[s] for s in ids]
    frames = np.array([f.frames for f in fact], dtype=np.int64)
    frame = out["frame"].to_numpy()
    _first(
        file,
        (frame < 0) | (frame >= frames),
        out,
        "frame",
        "a frame of the sample's video (0 .. its frame count - 1)",
    )
    family = np.array([f.family_size for f in fact], dtype=np.int64)
    mid = out["marker_id"].to_numpy()
    _first(
        file,
        (mid < 0) | (mid >= family),
        out,
        "marker_id",
        "an id of the dataset's marker family (0 .. its size - 1)",
    )
    width = np.array([f.width_px for f in fact], dtype=float)
    height = np.array([f.height_px for f in fact], dtype=float)
    for k, (x, y) in enumerate(CORNER_COLUMNS):
        for name, size in ((x, width), (y, height)):
            v = out[name].to_numpy()
            _first(
                file,
                (v < -0.5 - OUTSIDE_PX) | (v > size - 0.5 + OUTSIDE_PX),
                out,
                name,
                f"a pixel position in the image (-0.5 .. size - 0.5, {OUTSIDE_PX:g} px "
                f"of slack; corner {k})",
            )
    dup = out.duplicated(["sample_id", "frame", "marker_id"]).to_numpy()
    hit = np.flatnonzero(dup)
    if len(hit):
        r = out.iloc[hit[0]]
        raise ResultsFileError(
            f"{file}: row {hit[0] + 1}: a second row of sample "
            f"{r['sample_id']}, frame {r['frame']}, marker {r['marker_id']}; "
            "expected one row per sample, frame and marker"
        )
    if TIME_COLUMN in out:
        times = out[TIME_COLUMN].to_numpy()
        _first(
            file,
            (times < MIN_FRAME_TIME_S) | (times > MAX_FRAME_TIME_S),
            out,
            TIME_COLUMN,
            f"seconds in {MIN_FRAME_TIME_S:g} .. {MAX_FRAME_TIME_S:g} (a frame's time; 0 is no "
            "timing: leave the column out or use --fps)",
        )
        spread = out.groupby(["sample_id", "frame"])[TIME_COLUMN].transform("nunique")
        _first(
            file, spread.to_numpy() > 1, out, TIME_COLUMN, "the same time on every row of a frame"
        )


def fps_problem(fps: float) -> str | None:
    """Why ``--fps`` is refused (None: accepted): the frame-time bounds as frames/s, so that no
    made-up speed (0, inf) reaches samples.csv."""
    lo, hi = 1 / MAX_FRAME_TIME_S, 1 / MIN_FRAME_TIME_S
    if math.isfinite(fps) and lo <= fps <= hi:
        return None
    return f"{fps:g}: expected a finite number of frames/s in 1/{MAX_FRAME_TIME_S:g} .. {hi:g}"


def frames_per_s(table: pd.DataFrame, fps: float | None) -> float | None:
    """``fps`` if given, else the frames timed over their total time; None: accuracy only."""
    if fps is not None:
        return fps
    if TIME_COLUMN not in table or table.empty:
        return None
    per_frame = table.groupby("frame")[TIME_COLUMN].first()
    total = float(per_frame.sum())
    return len(per_frame) / total if total > 0 and math.isfinite(total) else None


def sample_facts(verified: VerifiedDataset) -> dict[str, SampleFacts]:
    """What each sample's detections are checked against: frames, image size, family size."""
    from bench.evaluate.score import _array
    from scenes.array import ArraySpec
    from scenes.marker import get_dictionary
    from scenes.profile import load_profile

    facts = {}
    for sample_id, record in verified.records.items():
        lens = load_profile(verified.folder / sample_id / "camera.json").lens
        array = _array(record) or ArraySpec()
        family = len(get_dictionary(array.dictionary).bytesList)
        facts[sample_id] = SampleFacts(int(record["frames"]), lens.width_px, lens.height_px, family)
    return facts

"""Hostile files made by systematic mutation (issue 24, part 9): each accepted input format,
taken from a good file, is damaged whole (emptied, cut short, binary junk, not UTF-8, nested
past the bound, the wrong kind of document) and field by field (each leaf or column in turn
given a value of each hostile kind: not a number, an infinity, a huge or negative number, the
wrong type, nothing; an unknown field added), and handed to the command that reads it.

Every variant must be answered as input: refused in one line naming the file or option, exit
code 2, nothing written; or accepted, where the damage left a valid file (a name changed to
another name); never an internal error or a traceback, and a value that is not a finite number
is never accepted where a number stands. The suite grows by a line in :data:`FORMATS` for a new
format, by a value in ``document_mutations.HOSTILE_VALUES`` or by a line in :data:`DAMAGE` for a
new kind of damage.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from document_mutations import HOSTILE_VALUES, paths, replaced, wrong_answer
from fake_dataset import SAMPLES, make_dataset
from test_calibration_import import basalt_calib, basalt_entry, kalibr_camchain
from test_lens_models import TUM_KB4

from bench.cli.main import main
from bench.common.manifest import sha256
from bench.dataset.loader import open_dataset
from scenes.tables import CORNER_COLUMNS

pytestmark = pytest.mark.usefixtures("figures_not_drawn")  # answers, not figures

LONG, SHORT = SAMPLES
#: Whole-file damage: (name, new bytes from the good file's bytes).
DAMAGE: tuple[tuple[str, Callable[[bytes], bytes]], ...] = (
    ("emptied", lambda data: b""),
    ("cut short", lambda data: data[: len(data) // 2]),
    ("binary junk", lambda data: bytes(range(256)) * 64),
    ("not UTF-8", lambda data: b"\xff\xfe" + data[2:]),
    ("nested past the bound", lambda data: b"[" * 50_000 + b"]" * 50_000),
    ("another document kind", lambda data: b"[1, 2, 3]\n"),
    ("doubled", lambda data: data + data),
)


@dataclass(frozen=True)
class Format:
    """An input format: its good file, made in a folder; how a command reads it."""

    name: str
    #: (folder, dataset) -> (the good file, the command line, the folder that must stay as it is)
    make: Callable[[Path, Path], tuple[Path, list[str], Path]]
    #: "json", "yaml", "csv" or "parquet": how the file is mutated field by field
    kind: str
    #: after a mutation, make the dataset's hashes agree again (a record the manifest lists)
    rehash: Callable[[Path, Path], None] | None = None
    #: leaves the command does not read (another camera of the file, a pose it ignores): any
    #: value there may be accepted
    unread: tuple[tuple, ...] = ()
    #: whole-file damage that may leave a valid file (YAML cut at a line end, a key given twice)
    may_survive: tuple[str, ...] = ()


def _copy_dataset(folder: Path, dataset: Path) -> Path:
    import shutil

    shutil.copytree(dataset, folder / "data")
    return folder / "data"


def _branches_csv(folder: Path) -> Path:
    path = folder / "branches.csv"
    path.write_text(f"sample_id,whisker_left,whisker_right\n{LONG},,\n{SHORT},5,6\n")
    return path


def _score_branches(data: Path, branches: Path, folder: Path) -> list[str]:
    return [
        "score",
        str(data),
        "--branches",
        str(branches),
        "--name",
        "m",
        "--out",
        str(folder / "out"),
    ]


def _sample_json(folder: Path, dataset: Path):
    data = _copy_dataset(folder, dataset)
    argv = _score_branches(data, _branches_csv(folder), folder)
    return data / SHORT / "sample.json", argv, data


def _manifest(folder: Path, dataset: Path):
    data = _copy_dataset(folder, dataset)
    argv = _score_branches(data, _branches_csv(folder), folder)
    return data / "manifest.json", argv, data


def _rehash_sample(path: Path, data: Path) -> None:
    manifest = json.loads((data / "manifest.json").read_text())
    for key in ("files", "outputs"):
        manifest[key][f"{SHORT}/sample.json"] = sha256(path)
    (data / "manifest.json").write_text(json.dumps(manifest))


def _branches(folder: Path, dataset: Path):
    path = _branches_csv(folder)
    return path, _score_branches(dataset, path, folder), folder


def _detections(suffix: str):
    def make(folder: Path, dataset: Path):
        corners = [name for pair in CORNER_COLUMNS for name in pair]
        parts = []
        for sample in open_dataset(dataset):  # a few markers of each sample: an exact method
            labels = sample.labels[sample.labels["visible"]].head(3)
            parts.append(labels[["frame", "marker_id", *corners]].assign(sample_id=sample.id))
        table = pd.concat(parts, ignore_index=True)
        path = folder / f"detections{suffix}"
        if suffix == ".csv":
            table.to_csv(path, index=False)
        else:
            table.to_parquet(path, index=False)
        argv = ["score", str(dataset), "--detections", str(path), "--name", "m"]
        return path, [*argv, "--out", str(folder / "out")], folder

    return make


def _calibration(fmt: str):
    def make(folder: Path, dataset: Path):
        if fmt == "kalibr":
            path, _ = kalibr_camchain(folder)
        else:
            path = basalt_calib(folder, [basalt_entry("kb4", TUM_KB4, ("k1", "k2", "k3", "k4"))])
        argv = ["camera", "import", str(path), "--format", fmt, "--theta-max-deg", "100"]
        return path, [*argv, "--out", str(folder / "out.json")], folder

    return make


def _truth_csv(folder: Path, dataset: Path):
    """A still image of one marker on white and its corners, for ``detect-images --truth``."""
    import cv2

    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(0), 3, 40)
    image = np.full((80, 80), 255, np.uint8)
    image[20:60, 20:60] = marker
    cv2.imwrite(str(folder / "still.png"), image)
    path = folder / "truth.csv"
    corners = "19.5,19.5,59.5,19.5,59.5,59.5,19.5,59.5"
    path.write_text(f"image,marker_id,x0,y0,x1,y1,x2,y2,x3,y3\nstill.png,3,{corners}\n")
    argv = ["detect-images", str(folder / "still.png"), "--pipelines", "naive"]
    return (
        path,
        [*argv, "--family", "4x4_50", "--truth", str(path), "--out", str(folder / "out")],
        folder,
    )


#: Camera profiles and observations files are generated the same way in test_hostile_files.py.
FORMATS = (
    Format(
        "calibration YAML (kalibr)",
        _calibration("kalibr"),
        "yaml",
        unread=(("cam1",), ("cam2",)),
        may_survive=("cut short", "doubled"),  # cam0 whole; a key twice: the last one holds
    ),
    Format(
        "calibration JSON (basalt)",
        _calibration("basalt"),
        "json",
        unread=(("value0", "T_imu_cam"), ("value0", "vignette")),
    ),
    Format("detections CSV", _detections(".csv"), "csv"),
    Format(  # pyarrow reads from the footer: the data whole, the leading bytes unread
        "detections Parquet",
        _detections(".parquet"),
        "parquet",
        may_survive=("not UTF-8", "doubled"),
    ),
    Format("branches file CSV", _branches, "csv"),
    Format("ground truth CSV (detect-images)", _truth_csv, "csv"),
    Format("dataset manifest", _manifest, "json", unread=(("schema",),)),
    Format("sample.json", _sample_json, "json", rehash=_rehash_sample),
)


# --- mutations ------------------------------------------------------------------------------


#: Members of one object or list mutated in turn; the rest are alike (a manifest's file hashes).
MEMBERS = 4


def _document_variants(
    path: Path, kind: str, unread: tuple[tuple, ...]
) -> Iterator[tuple[str, bytes, bool]]:
    """(what, bytes, whether a number that is read turned non-finite) for every leaf and
    value, and an unknown member in every object."""
    text = path.read_text()
    document = yaml.safe_load(text) if kind == "yaml" else json.loads(text)

    def dump(doc) -> bytes:
        if kind == "yaml":
            return yaml.safe_dump(doc).encode()
        return json.dumps(doc).encode()  # NaN and Infinity as Python writes them

    for where in paths(document, MEMBERS):
        old = _get(document, where)
        for value in HOSTILE_VALUES:
            nonfinite = isinstance(value, float) and not math.isfinite(value)
            numeric = isinstance(old, int | float) and not isinstance(old, bool)
            numeric = numeric and not any(where[: len(u)] == u for u in unread)
            variant = dump(replaced(document, where, value))
            yield f"{where} = {value!r}", variant, nonfinite and numeric
        if isinstance(old, dict):
            yield f"{where} + unknown", dump(replaced(document, (*where, "zz_unknown"), 1)), False
    if isinstance(document, dict):
        yield "unknown top-level member", dump({**document, "zz_unknown": 1}), False


def _get(document, path: tuple):
    for key in path:
        document = document[key]
    return document


def _table_variants(path: Path, kind: str) -> Iterator[tuple[str, bytes, bool]]:
    """Each column's first value given each hostile value; each column dropped; an unknown
    column added; the header alone."""
    table = pd.read_csv(path) if kind == "csv" else pd.read_parquet(path)

    def dump(t: pd.DataFrame) -> bytes:
        out = path.with_name("variant" + path.suffix)
        if kind == "csv":
            t.to_csv(out, index=False)
        else:
            t.to_parquet(out, index=False)
        return out.read_bytes()

    for column in table.columns:
        numeric = pd.api.types.is_numeric_dtype(table[column])
        for value in HOSTILE_VALUES:
            if isinstance(value, list | dict):
                continue  # a cell of a table holds no list
            t = table.astype({column: object})
            t.at[t.index[0], column] = value
            if kind == "parquet" and (
                value == 10**30 or not all(type(v) is type(value) for v in t[column])
            ):
                t[column] = t[column].astype(str)  # Parquet holds one type a column, 64 bits
            # NaN is a table's empty cell, which some columns allow: infinities only
            nonfinite = isinstance(value, float) and math.isinf(value) and numeric
            yield f"{column}[0] = {value!r}", dump(t), nonfinite
        yield f"{column} dropped", dump(table.drop(columns=column)), False
    yield "unknown column", dump(table.assign(zz_unknown=1.0)), False
    yield "header only", dump(table.head(0)), False


def _variants(path: Path, fmt: Format, fields: bool) -> Iterator[tuple[str, bytes, bool]]:
    """The whole-file damage, or (``fields``) every field's."""
    good = path.read_bytes()
    if not fields:
        for what, damage in DAMAGE:
            yield what, damage(good), False
    elif fmt.kind in ("json", "yaml"):
        yield from _document_variants(path, fmt.kind, fmt.unread)
    else:
        yield from _table_variants(path, fmt.kind)


# --- the answer -----------------------------------------------------------------------------


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    short = dict(zip(SAMPLES, (12, 5), strict=True))  # fewer frames: an accepted file scores fast
    return make_dataset(tmp_path_factory.mktemp("generated") / "data", short)


#: A format whose good file runs a whole scoring (seconds) is left to the slow tests.
DAMAGED = [
    pytest.param(f, id=f.name, marks=[pytest.mark.slow] if f.name.startswith("detections") else [])
    for f in FORMATS
]


@pytest.mark.parametrize("fmt", DAMAGED)
def test_a_damaged_file_of_every_format_is_refused(fmt, dataset, tmp_path, capsys):
    tried, accepted = _answer_every_variant(fmt, False, dataset, tmp_path, capsys)
    assert tried == len(DAMAGE) and set(accepted) <= set(fmt.may_survive), accepted


@pytest.mark.slow  # about 6 min on a busy 2-core machine: a few thousand runs of the commands
@pytest.mark.parametrize("fmt", FORMATS, ids=[f.name for f in FORMATS])
def test_every_field_of_every_format_meets_every_hostile_value(fmt, dataset, tmp_path, capsys):
    tried, accepted = _answer_every_variant(fmt, True, dataset, tmp_path, capsys)
    assert tried >= 30 and len(accepted) <= tried * 3 // 4, (tried, accepted)


def _answer_every_variant(
    fmt: Format, fields: bool, dataset: Path, tmp_path: Path, capsys
) -> tuple[int, int]:
    """Run the command on each variant of ``fmt``'s good file; (variants, those accepted)."""
    folder = tmp_path / "case"
    folder.mkdir()
    good, argv, watched = fmt.make(folder, dataset)
    original = good.read_bytes()
    assert main(argv) == 0, capsys.readouterr().err  # the good file itself is accepted
    capsys.readouterr()
    out = Path(argv[-1]) if "--out" in argv else None
    wrong, tried, accepted = [], 0, []
    for what, data, nonfinite in list(_variants(good, fmt, fields)):
        if out is not None and out.exists():  # an accepted variant's output: not this one's
            _remove(out)
        good.write_bytes(data)
        if fmt.rehash is not None:
            fmt.rehash(good, watched)
        before = _files(watched)
        code = main(argv)
        err = capsys.readouterr().err
        written = (out is not None and out.exists()) or _files(watched) != before
        tried += 1
        if code == 0:
            accepted.append(what)
        why = wrong_answer(code, err, nonfinite, written, prefix="whiskerbench ")
        if why:
            wrong.append(f"{what}: {why}: exit {code}: {err.strip()[:300]}")
        good.write_bytes(original)
    assert not wrong, f"{fmt.name}: {len(wrong)} of {tried} wrong:\n" + "\n".join(wrong[:25])
    return tried, accepted


def _remove(path: Path) -> None:
    import shutil

    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()


def test_the_suite_covers_every_format_the_brief_names():
    names = " ".join(f.name for f in FORMATS)
    for needed in ("YAML", "detections CSV", "Parquet", "branches", "manifest", "sample.json"):
        assert needed in names, needed


#: Variants the field tier found answered wrongly, kept fast: (format, leaf, value, the one
#: line's pattern). A new finding is a new line.
FOUND = [
    ("sample.json", ("frames",), math.inf, r"sample\.json: 'frames' must be an integer in 1\.\."),
    ("sample.json", ("frames",), "x", r"'frames' must be an integer"),
    ("sample.json", ("protocol", "fps"), math.nan, r"'protocol\.fps' must be a finite number"),
    ("sample.json", ("protocol", "fps"), -1, r"'protocol\.fps' must be a finite number > 0"),
    (
        "calibration JSON (basalt)",
        ("value0", "intrinsics", 0, "camera_type"),
        [],
        r"calib\.json.*camera_type.*\[\] is not supported",
    ),
]


@pytest.mark.parametrize(
    ("name", "where", "value", "pattern"), FOUND, ids=[str(f[:3]) for f in FOUND]
)
def test_what_the_field_tier_found_stays_refused(
    name, where, value, pattern, dataset, tmp_path, capsys
):
    import re

    fmt = next(f for f in FORMATS if f.name == name)
    folder = tmp_path / "case"
    folder.mkdir()
    good, argv, watched = fmt.make(folder, dataset)
    text = good.read_text()
    document = yaml.safe_load(text) if fmt.kind == "yaml" else json.loads(text)
    good.write_text(json.dumps(replaced(document, where, value)))
    if fmt.rehash is not None:
        fmt.rehash(good, watched)
    before = _files(watched)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(pattern, err[0]), err
    assert _files(watched) == before


def test_a_sample_in_which_no_marker_is_ever_seen_is_refused_not_the_run(tmp_path, capsys):
    """A dataset of noise frames: a sample with no marker seen is ``refused`` with its reason
    and named in a warning; it used to end the whole run in one line naming no sample."""
    data = make_dataset(tmp_path / "data", dict(zip(SAMPLES, (12, 5), strict=True)))
    out = tmp_path / "out"
    assert main(["score", str(data), "--out", str(out)]) == 0, capsys.readouterr().err
    err = capsys.readouterr().err
    table = pd.read_csv(out / "samples.csv").set_index("sample_id")
    blind = table[table["markers_found"].fillna(0) == 0].index
    assert len(blind) >= 1
    for sample_id in blind:
        assert table.loc[sample_id, "outcome"] == "refused"
        assert "no marker seen in any frame" in table.loc[sample_id, "refused_reason"]
        assert f"warning: {sample_id} refused: no marker seen" in err

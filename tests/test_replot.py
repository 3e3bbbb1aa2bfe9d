"""``whiskerbench replot``: committed result folders' figures drawn again from their own tables,
the tables untouched and the manifest still verifying; a fresh score folder's figure drawn
again exactly as its run drew it; a folder whose tables are not its manifest's, are damaged, or
of a kind it does not know, refused in one line with no folder named touched."""

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from fake_dataset import SAMPLES, make_dataset
from PIL import Image

from bench.cli.main import main
from bench.common.run_folder import LOCK

RESULTS = Path(__file__).resolve().parents[1] / "results"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _copy(name: str, tmp_path: Path) -> Path:
    """A committed result folder as git has it (its ignored bulk files left out)."""
    out = tmp_path / name.replace("/", "-")
    shutil.copytree(RESULTS / name, out, ignore=shutil.ignore_patterns("cells", "images.parquet"))
    return out


def _files(folder: Path) -> dict[str, str]:
    """Every file's hash by its path in the folder; the lock file is no result."""
    paths = sorted(p for p in folder.rglob("*") if p.is_file() and p.name != LOCK)
    return {p.relative_to(folder).as_posix(): _digest(p) for p in paths}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "manifest", "figures", "title_says"),
    [
        ("detectability/cell8", "manifest.json", ["max_phi.png", "heatmap.png", "pose_error.png"],
         "options: --cell-px 8"),
        ("indoor", "score-manifest.json", ["grid-indoor-sun.png"], "paper: indoor, sun"),
        ("ladder", "manifest.json", ["ladder.png"], "ladder"),
        ("compare/default", "manifest.json", ["pareto.png", "sweeps.png"],
         "Accuracy against speed on compare"),
    ],
)  # fmt: skip
def test_figures_are_redrawn_from_the_tables_and_the_manifest_verifies(
    name, manifest, figures, title_says, tmp_path, capsys
):
    folder = _copy(name, tmp_path)
    before = _files(folder)
    assert main(["replot", str(folder)]) == 0
    after = _files(folder)
    record = json.loads((folder / manifest).read_text())
    for table in set(before) - {*figures, manifest}:
        assert after[table] == before[table], table  # tables and settings untouched
    for figure in figures:
        assert record["outputs"][figure] == after[figure]
        with Image.open(folder / figure) as image:
            assert image.text.get("Title") is not None  # drawn by today's figures.save
    assert any(title_says in Image.open(folder / f).text["Title"] for f in figures)
    listed = {k: v for k, v in record["outputs"].items() if (folder / k).exists()}
    assert all(after[k] == v for k, v in listed.items())  # the folder verifies
    assert record["replotted"]["figures"] == figures
    assert capsys.readouterr().out.count("redrew") == len(figures)


def _refused(argv: list[str], capsys, says: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1, err


def test_a_table_that_is_not_the_manifests_is_refused_and_nothing_is_written(tmp_path, capsys):
    good, bad = _copy("ladder", tmp_path), _copy("indoor", tmp_path)
    with (bad / "samples.csv").open("a") as f:
        f.write("\n")
    before = {**_files(good), **{f"bad/{k}": v for k, v in _files(bad).items()}}
    _refused(["replot", str(good), str(bad)], capsys, "differs from the manifest's hash")
    assert {**_files(good), **{f"bad/{k}": v for k, v in _files(bad).items()}} == before
    (bad / "samples.csv").unlink()
    _refused(["replot", str(bad)], capsys, "samples.csv is missing")


def test_folders_replot_does_not_know_are_refused(tmp_path, capsys):
    _refused(["replot", str(tmp_path / "nowhere")], capsys, "not a folder")
    _refused(["replot", str(tmp_path)], capsys, "not a result folder")
    other = tmp_path / "other"
    other.mkdir()
    (other / "manifest.json").write_text(json.dumps({"kind": "dataset", "outputs": {}}))
    _refused(["replot", str(other)], capsys, "a run of kind 'dataset'")
    (other / "manifest.json").write_text("{" * 10_000)
    _refused(["replot", str(other)], capsys, "manifest.json")


def test_a_score_folder_is_redrawn_exactly_as_its_run_drew_it(tmp_path):
    """Another tool's branch estimates scored by the project's own writer: the same table and
    recorded name give the same figure, title ("branches only") included, byte for byte."""
    long, short = SAMPLES
    dataset, branches, out = make_dataset(tmp_path / "data"), tmp_path / "b.csv", tmp_path / "out"
    branches.write_text(f"sample_id,whisker_left,whisker_right\n{long},,\n{short},0,1\n")
    argv = ["score", str(dataset), "--branches", str(branches), "--name", "mine", "--out"]
    assert main([*argv, str(out)]) == 0
    before = _files(out)
    (figure,) = [name for name in before if name.endswith(".png")]
    (out / figure).write_bytes(b"stale")
    assert main(["replot", str(out)]) == 0
    record = json.loads((out / "manifest.json").read_text())
    assert _files(out) == {**before, "manifest.json": _digest(out / "manifest.json")}
    assert record["outputs"][figure] == before[figure]
    assert "branches only" in Image.open(out / figure).text["Title"]


def _damage(folder: Path, name: str, text: str) -> None:
    """``name`` rewritten and its new hash recorded: the manifest vouches for a damaged table."""
    (folder / name).write_text(text)
    record = json.loads((folder / "manifest.json").read_text())
    record["outputs"][name] = _digest(folder / name)
    (folder / "manifest.json").write_text(json.dumps(record))


@pytest.mark.slow
def test_a_damaged_table_is_refused_and_no_folder_named_is_touched(tmp_path, capsys):
    """The good folder's figure is drawn (staged) before the bad one's fails: a score grid,
    drawn in about a second (the ladder's takes ten times that; its config damaged below)."""
    good, bad = _copy("indoor", tmp_path), _copy("compare/default", tmp_path)
    (good / "grid-indoor-sun.png").write_bytes(b"stale")  # would be redrawn, were bad not refused
    summary = (bad / "summary.csv").read_text().splitlines()
    _damage(bad, "summary.csv", "\n".join(line.split(",", 1)[1] for line in summary) + "\n")
    before = {**_files(good), **{f"bad/{k}": v for k, v in _files(bad).items()}}
    _refused(["replot", str(good), str(bad)], capsys, "is damaged or from another version")
    assert {**_files(good), **{f"bad/{k}": v for k, v in _files(bad).items()}} == before
    assert not [p for p in [*good.iterdir(), *bad.iterdir()] if ".tmp-" in p.name]
    ladder = _copy("ladder", tmp_path)
    _damage(ladder, "config.json", "[1]")
    _refused(["replot", str(ladder)], capsys, "ladder: a table or its config is damaged")

"""``whiskerbench replot``: committed result folders' figures drawn again from their own tables,
the tables untouched and the manifest still verifying; a folder whose tables are not its
manifest's, or of a kind it does not know, refused in one line with nothing written."""

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from PIL import Image

from bench.cli.main import main

RESULTS = Path(__file__).resolve().parents[1] / "results"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _copy(name: str, tmp_path: Path) -> Path:
    """A committed result folder as git has it (its ignored bulk files left out)."""
    out = tmp_path / Path(name).name
    shutil.copytree(RESULTS / name, out, ignore=shutil.ignore_patterns("cells", "images.parquet"))
    return out


def _files(folder: Path) -> dict[str, str]:
    return {p.name: _digest(p) for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.parametrize(
    ("name", "manifest", "figures", "title_says"),
    [
        ("detectability/cell8", "manifest.json", ["max_phi.png", "heatmap.png", "pose_error.png"],
         "options: --cell-px 8"),
        ("indoor", "score-manifest.json", ["grid-indoor-sun.png"], "paper: indoor, sun"),
        ("ladder", "manifest.json", ["ladder.png"], "ladder"),
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
    assert all(after[Path(k).name] == v for k, v in listed.items())  # the folder verifies
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
    compare = tmp_path / "compare"
    compare.mkdir()
    (compare / "manifest.json").write_text(json.dumps({"kind": "compare", "outputs": {}}))
    _refused(["replot", str(compare)], capsys, "a run of kind 'compare'")
    (compare / "manifest.json").write_text("{" * 10_000)
    _refused(["replot", str(compare)], capsys, "manifest.json")

"""docs/dataset_format.md against the code: its column table is scenes.tables.LABELS (names,
order, dtypes, units), its file table the sample's files, its key tables the keys a rendered
dataset writes, and it states the format version the generator writes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from bench.dataset.config import SAMPLE_FILES
from bench.dataset.format import FORMAT_VERSION
from scenes.tables import LABELS

DOC = Path(__file__).resolve().parents[1] / "docs" / "dataset_format.md"


def doc_tables(text: str) -> dict[str, list[dict[str, str]]]:
    """{marker: rows} of every table right after a ``<!-- kind: name -->`` marker line; a row is
    {header: cell}, backticks stripped."""
    tables = {}
    lines = text.splitlines()
    for k, line in enumerate(lines):
        marker = re.fullmatch(r"<!-- (\w+: [\w.]+) -->", line.strip())
        if not marker:
            continue
        block = []
        for row in lines[k + 1 :]:
            if not row.startswith("|"):
                break
            block.append([c.strip().strip("`") for c in row.strip().strip("|").split("|")])
        header, rule, *body = block
        assert set("".join(rule)) <= set("-: "), f"{marker[1]}: no table after the marker"
        tables[marker[1]] = [dict(zip(header, cells, strict=True)) for cells in body]
    return tables


TABLES = doc_tables(DOC.read_text())


def test_the_parser_finds_every_table() -> None:
    assert set(TABLES) == {
        "columns: scenes.tables.LABELS",
        "files: sample",
        "keys: sample.json",
        "keys: manifest.json",
    }


def test_labels_columns_are_the_schema() -> None:
    """Every column of scenes.tables.LABELS, in order, with its dtype and unit ("-": none)."""
    rows = TABLES["columns: scenes.tables.LABELS"]
    assert [r["column"] for r in rows] == [c.name for c in LABELS]
    for row, column in zip(rows, LABELS, strict=True):
        assert row["dtype"] == column.dtype, column.name
        assert row["unit"] == (column.unit or "-"), column.name
        assert row["meaning"], column.name


def test_sample_files_are_the_formats() -> None:
    assert {r["file"] for r in TABLES["files: sample"]} == {*SAMPLE_FILES, "sample.json"}


def test_the_doc_states_the_version_written() -> None:
    assert f"**Format version {FORMAT_VERSION}.**" in DOC.read_text()


@pytest.mark.slow
def test_key_tables_are_what_a_rendered_dataset_holds(rendered_pair) -> None:
    manifest = json.loads((rendered_pair / "manifest.json").read_text())
    assert {r["key"] for r in TABLES["keys: manifest.json"]} == set(manifest)
    sample_id = manifest["samples"][0]
    record = json.loads((rendered_pair / sample_id / "sample.json").read_text())
    assert {r["key"] for r in TABLES["keys: sample.json"]} == set(record)

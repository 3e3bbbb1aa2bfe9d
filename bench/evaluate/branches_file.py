"""``score --branches``: another tool's final branch estimates, scored alone.

A branches results file (``docs/results_format.md``) is a Parquet or CSV table, one row per
sample and estimated branch: ``sample_id``, ``whisker_left`` and ``whisker_right`` (the gap
between whiskers i and i + 1, as ``branches.json``'s ``gap``); a sample where the method found
no branch has one row with both empty (an empty cell or null: ``nan`` or ``NA`` text is refused,
not read as empty); optionally ``dataset_sha256``. Each sample is scored
with :func:`bench.evaluate.score.branch_outcome` against its ``sample.json``'s gaps.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common.atomic import atomic_path
from bench.common.manifest import (
    RunClock,
    build_manifest,
    hash_files,
    sha256,
    write_manifest,
)
from bench.common.run_folder import claim, open_folder
from bench.dataset.verify import VerifiedDataset
from bench.evaluate.results_file import (
    MAX_ROWS,
    SHA_COLUMN,
    ResultsFileError,
    _first,
    _read,
    _text,
)
from scenes.bounded_read import input_problem

GAP_COLUMNS = ("whisker_left", "whisker_right")
COLUMNS = ("sample_id", *GAP_COLUMNS)


def read_branches(
    path: Path, verified: VerifiedDataset, n_whiskers: dict[str, int]
) -> dict[str, list[list[int]]]:
    """Sample id -> estimated gaps [[i, i + 1], ...] of every sample; ResultsFileError on a
    malformed file (one line naming the file, row or column)."""
    path = Path(path)
    if not path.is_file():
        problem = input_problem(path) or "no such file"
        raise ResultsFileError(f"{path}: {problem}; expected a .csv or .parquet file")
    table = _read(path, MAX_ROWS)
    for name in COLUMNS:
        if name not in table.columns:
            raise ResultsFileError(f"{path}: column {name!r} is missing; expected {_listing()}")
    for name in table.columns:
        if str(name) not in (*COLUMNS, SHA_COLUMN):
            raise ResultsFileError(
                f"{path}: column {name!r} is not in the format; expected {_listing()}"
            )
    ids = _text(path, table, "sample_id")
    if SHA_COLUMN in table:
        bad = (_text(path, table, SHA_COLUMN).str.lower() != verified.manifest_sha256).to_numpy()
        _first(
            path,
            bad,
            table,
            SHA_COLUMN,
            f"this dataset's manifest.json SHA-256 "
            f"({verified.manifest_sha256}): results of another dataset",
        )
    _first(
        path, ~ids.isin(list(n_whiskers)).to_numpy(), table, "sample_id", "a sample of this dataset"
    )
    gaps = {}
    nans = _parquet_nans(path, GAP_COLUMNS) if path.suffix == ".parquet" else {}
    for name in GAP_COLUMNS:
        column = table[name]
        numbers = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)
        bad = np.isnan(numbers) & column.notna().to_numpy() | np.isinf(numbers)
        bad |= nans.get(name, False)
        bad |= np.isfinite(numbers) & (numbers != np.round(numbers))
        _first(path, bad, table, name, "an integer (a whisker index), or an empty cell")
        gaps[name] = numbers
    left, right = gaps["whisker_left"], gaps["whisker_right"]
    n = ids.map(n_whiskers).to_numpy(dtype=float)
    _first(
        path,
        np.isnan(left) != np.isnan(right),
        table,
        "whisker_right",
        "empty exactly where whisker_left is (a sample without branches)",
    )
    _first(
        path,
        (left < 0) | (left > n - 2),
        table,
        "whisker_left",
        "a whisker index 0 .. n - 2 (the gap's left whisker)",
    )
    _first(path, ~np.isnan(left) & (right != left + 1), table, "whisker_right", "whisker_left + 1")
    out: dict[str, list[list[int]]] = {}
    for k, (sample_id, lo) in enumerate(zip(ids, left, strict=True)):
        estimates = out.setdefault(sample_id, [])
        gap = [] if np.isnan(lo) else [int(lo), int(lo) + 1]
        if (estimates == [[]] or (estimates and not gap)) or gap in estimates:
            raise ResultsFileError(
                f"{path}: row {k + 1}: sample {sample_id} is listed again; "
                "expected each gap once, or one empty row"
            )
        estimates.append(gap)
    missing = [s for s in n_whiskers if s not in out]
    if missing:
        raise ResultsFileError(
            f"{path}: no row of sample {missing[0]}; expected every sample "
            "of the dataset (one empty row: no branch found)"
        )
    return {s: sorted(g for g in out[s] if g) for s in sorted(out)}


def _parquet_nans(path: Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per floating column of a Parquet file, its cells holding a NaN value: pandas reads NaN
    and null alike, but only null is an empty cell (a NaN is refused, as ``nan`` text in CSV)."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq
    import pyarrow.types as pat

    columns = pq.read_table(path, columns=list(names))
    return {
        name: pc.fill_null(pc.is_nan(columns[name]), False).to_numpy(zero_copy_only=False)
        for name in names
        if pat.is_floating(columns[name].type)
    }


def _listing() -> str:
    return f"{', '.join(COLUMNS)}; optional: {SHA_COLUMN}"


def score_branches(
    path: Path,
    verified: VerifiedDataset,
    estimates: dict[str, list[list[int]]],
    name: str,
    out_dir: Path,
    refused: dict[str, str] | None = None,
    plugin: str | None = None,
) -> pd.DataFrame:
    """Score the estimates; write ``samples.csv``, the grids and ``manifest.json`` (last).

    ``refused``: why each sample without estimates has none (a branch plugin that crashed on
    it, :mod:`bench.evaluate.branch_plugin`); ``plugin``: that plugin's name, where the
    estimates come from it and not from the file ``path``."""
    from bench.evaluate.grid_plot import plot_grid
    from bench.evaluate.score import SCORED_COLUMNS, branch_outcome, sample_columns

    out_dir = Path(out_dir)
    clock = RunClock()
    claim(out_dir, "score")
    rows = []
    for sample_id, record in verified.records.items():
        if sample_id in (refused or {}):
            reason = {"outcome": "refused", "refused_reason": refused[sample_id]}
            rows.append({**sample_columns(record), **reason})
            continue
        estimated = estimates[sample_id]
        rows.append(
            {
                **sample_columns(record),
                "estimated_gaps": json.dumps(estimated),
                **branch_outcome(estimated, record["branch_gaps"]),
            }
        )
    with open_folder(out_dir, "score"):  # locked while it is written
        table = pd.DataFrame(rows).sort_values("sample_id").reset_index(drop=True)
        table = table.reindex(columns=[*table, *(c for c in SCORED_COLUMNS if c not in table)])
        with atomic_path(out_dir / "samples.csv") as tmp:
            table.to_csv(tmp, index=False)
        for (protocol, lighting), part in table.groupby(["protocol", "lighting"]):
            title = f"{name}: {protocol}, {lighting} (branches only, accuracy only)"
            plot_grid(part, out_dir / f"grid-{protocol}-{lighting}.png", title)
        written = [out_dir / "samples.csv", *out_dir.glob("grid-*.png")]
        source = {"branches": str(path)} if plugin is None else {"branch_plugin": plugin}
        settings = {**source, "name": name, "dataset": str(verified.folder)}
        inputs = verified.inputs()
        if plugin is None:
            inputs[str(path)] = sha256(path)
        record = build_manifest(
            "score", clock, settings, inputs=inputs, outputs=hash_files(written, out_dir)
        )
        write_manifest(out_dir, record)
    return table

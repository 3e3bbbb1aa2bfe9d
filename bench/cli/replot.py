"""``whiskerbench replot FOLDER...``: a result folder's figures drawn again from its own tables.

A figure is derived data: when the figure style changes (``bench.common.figures``), the
committed studies, ladders and score grids need not be rerun, which takes hours, to be read in
it. Each figure is drawn by the function the run itself uses, from the tables the run wrote,
and only after their SHA-256 match the folder's manifest (a figure that is not its table's would
be a silent wrong answer). The manifest then lists the new figures' hashes and a ``replotted``
entry (when, by which version); tables and settings are untouched. Bad input: one line naming
the folder, exit code 2, nothing written.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from bench.common.atomic import write_json
from bench.common.manifest import MANIFEST, sha256, whiskerbench_version, write_manifest
from bench.common.run_folder import open_folder
from scenes.bounded_read import BoundedReadError, read_json
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH
from scenes.validation import FieldError

#: A score folder's manifest where ``make indoor`` copies it beside the table it describes.
COPIED_SCORE_MANIFEST = "score-manifest.json"


def _study(folder: Path, record: dict) -> list[str]:
    from bench.study import plots as report_plots
    from bench.study import report
    from bench.study.config import StudyConfig, nondefault_options
    from pipeline.detect import DetectorConfig
    from scenes.profile import CameraProfile

    fields = read_json(_table(folder, record, "config.json"), RECORD_BYTES, RECORD_DEPTH)
    known = StudyConfig.__dataclass_fields__
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items() if k in known}
    fields["camera"] = CameraProfile.from_json(fields["camera"])
    detector = DetectorConfig.__dataclass_fields__
    fields["detector"] = DetectorConfig(
        **{k: v for k, v in fields["detector"].items() if k in detector}
    )
    config = StudyConfig(**fields)
    summary = pd.read_csv(_table(folder, record, "summary.csv"))
    max_phi = pd.read_csv(_table(folder, record, "max_phi_by_scale.csv"))
    options = {"detector": config.detector_label, "options": nondefault_options(config)}
    refinements = report.refinements_of(config.detector.backend)
    report_plots.plot_max_phi(max_phi, folder / "max_phi.png", **options)
    report_plots.plot_heatmap(summary, folder / "heatmap.png", **options)
    report_plots.plot_pose_error(
        summary, folder / "pose_error.png", **options, refinements=refinements
    )
    return ["max_phi.png", "heatmap.png", "pose_error.png"]


def _ladder(folder: Path, record: dict) -> list[str]:
    from bench.ladder import report
    from bench.ladder.config import LadderConfig, ladder_options
    from bench.study.config import Cell

    fields = read_json(_table(folder, record, "config.json"), RECORD_BYTES, RECORD_DEPTH)
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}
    fields["cells"] = tuple(Cell(**c) for c in fields["cells"])
    config = LadderConfig(**fields)
    cells = pd.read_csv(_table(folder, record, "rungs.csv")).drop(columns="matches_reference")
    per_rung = report.per_rung(cells)
    defaults = report.defaults_table(per_rung)
    report.plot(per_rung, defaults, folder / "ladder.png", ladder_options(config))
    return ["ladder.png"]


def _score(folder: Path, record: dict) -> list[str]:
    from bench.evaluate.grid_plot import plot_grid

    table = pd.read_csv(_table(folder, record, "samples.csv"))
    name = record["config"]["pipeline"]["name"]
    untimed = bool(record["config"].get("results", {}).get("timed") is False)
    drawn = []
    for (protocol, lighting), part in table.groupby(["protocol", "lighting"]):
        drawn.append(f"grid-{protocol}-{lighting}.png")
        title = f"{name}: {protocol}, {lighting}" + (" (accuracy only)" if untimed else "")
        plot_grid(part, folder / drawn[-1], title)
    return drawn


#: A run's kind -> the tables its figures are drawn from (each checked against the manifest).
TABLES = {
    "detectability": ("config.json", "summary.csv", "max_phi_by_scale.csv"),
    "ladder": ("config.json", "rungs.csv"),
    "score": ("samples.csv",),
}
#: A run's kind (its manifest's ``kind``) -> what draws its figures.
REPLOTTERS: dict[str, Callable[[Path, dict], list[str]]] = {
    "detectability": _study,
    "ladder": _ladder,
    "score": _score,
}


def _table(folder: Path, record: dict, name: str) -> Path:
    """``folder/name``, once its SHA-256 matches the manifest's; FieldError otherwise."""
    path = folder / name
    listed = record.get("outputs", {}).get(name)
    if listed is None or not path.is_file():
        raise FieldError("folder", f"{folder}: {name} is missing or not in its manifest")
    if sha256(path) != listed:
        raise FieldError(
            "folder", f"{path}: differs from the manifest's hash; its figures would not be its own"
        )
    return path


def manifest_path(folder: Path) -> Path:
    """The folder's manifest: its own, or the score manifest ``make indoor`` copies beside."""
    own = folder / MANIFEST
    return own if own.exists() or not (folder / COPIED_SCORE_MANIFEST).exists() else (
        folder / COPIED_SCORE_MANIFEST
    )  # fmt: skip


def check_folder(folder: Path | str) -> tuple[Path, dict]:
    """``folder``'s manifest path and record, once it is a run replot knows whose tables match
    their hashes; FieldError (field ``folder``) naming the folder or file otherwise."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FieldError("folder", f"{folder}: not a folder")
    path = manifest_path(folder)
    if not path.is_file():
        raise FieldError("folder", f"{folder}: not a result folder (no {MANIFEST})")
    try:
        record = read_json(path, RECORD_BYTES, RECORD_DEPTH)
    except BoundedReadError as exc:
        raise FieldError("folder", f"{path}: {exc}") from None
    kind = record.get("kind") if isinstance(record, dict) else None
    if kind not in REPLOTTERS:
        raise FieldError(
            "folder", f"{path}: a run of kind {kind!r}; replot knows {', '.join(REPLOTTERS)}"
        )
    if not isinstance(record.get("outputs"), dict):
        raise FieldError("folder", f"{path}: lists no outputs")
    for name in TABLES[kind]:
        _table(folder, record, name)
    return path, record


def replot(folder: Path | str) -> list[Path]:
    """Draw ``folder``'s figures again from its tables (the module docstring); the figures.
    FieldError (field ``folder``) for a folder it cannot replot, before anything is written."""
    folder = Path(folder)
    path, record = check_folder(folder)
    kind = record["kind"]
    try:
        lock = open_folder(folder, kind, record=False)
    except ValueError as exc:
        raise FieldError("folder", str(exc)) from None
    with lock:
        drawn = REPLOTTERS[kind](folder, record)
        record["outputs"].update({name: sha256(folder / name) for name in drawn})
        stamp = datetime.now(UTC).isoformat(timespec="seconds")
        record["replotted"] = {"at": stamp, "version": whiskerbench_version(), "figures": drawn}
        if path.name == MANIFEST:
            write_manifest(folder, record)
        else:  # the copied score manifest keeps its name
            write_json(path, record)
    return [folder / name for name in drawn]


def add_replot_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``replot`` on the top-level subparsers."""
    p = subparsers.add_parser(
        "replot", help="draw a result folder's figures again from its own tables"
    )
    p.add_argument("folders", nargs="+", type=Path, metavar="FOLDER", help="result folders")
    p.set_defaults(func=cmd_replot)


def cmd_replot(args: argparse.Namespace) -> int:
    """Check every folder first, so that a bad one leaves all of them as they were."""
    for folder in args.folders:
        check_folder(folder)
    for folder in args.folders:
        for figure in replot(folder):
            print(f"redrew {figure}")
    return 0

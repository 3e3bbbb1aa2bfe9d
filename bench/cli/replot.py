"""``whiskerbench replot FOLDER...``: a result folder's figures drawn again from its own tables.

A figure is derived data: when the figure style changes (``bench.common.figures``), the
committed studies, comparisons, ladders and score grids need not be rerun, which takes hours,
to be read in it. Each figure is drawn by the function the run itself uses, with the titles its
recorded config gives, from the tables the run wrote, and only after their SHA-256 match the
folder's manifest (a figure that is not its table's would be a silent wrong answer). The
manifest then lists the new figures' hashes and a ``replotted`` entry (when, by which version);
tables and settings are untouched. Every folder named is checked, locked and drawn before any
figure replaces an old one, so a folder refused (unknown, a table missing, changed or damaged:
one line naming it, exit code 2) leaves all of them as they were. A comparison's ``grids/`` are
copies of the dataset's score folders' figures, whose tables are not in it: replot those
folders themselves.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.common.atomic import atomic_path, write_json
from bench.common.manifest import MANIFEST, sha256, whiskerbench_version, write_manifest
from bench.common.run_folder import open_folder
from scenes.bounded_read import BoundedReadError, read_json
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH
from scenes.validation import FieldError

if TYPE_CHECKING:
    import pandas as pd

#: A score folder's manifest where ``make indoor`` copies it beside the table it describes.
COPIED_SCORE_MANIFEST = "score-manifest.json"
#: What a table or config that parses but is not what its run wrote raises while it is read or
#: drawn (a column or key missing, a wrong type or value): the folder is refused in one line.
DAMAGED = (KeyError, IndexError, TypeError, ValueError, AttributeError, FieldError)

#: One figure: its file name in the folder, and what draws it at a given path.
Figure = tuple[str, Callable[[Path], None]]


@dataclasses.dataclass
class Folder:
    """A folder replot accepted: its manifest (path and record) and the figures it draws."""

    path: Path
    manifest: Path
    record: dict
    figures: list[Figure]


def _config(cls: type, fields: Any, **nested: Callable[[Any], Any]) -> Any:
    """``cls`` from its JSON record: lists back to tuples, keys it does not know (another
    version's) dropped, the ``nested`` fields converted by their functions."""
    known = {f.name for f in dataclasses.fields(cls)}
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items() if k in known}
    return cls(**{**fields, **{k: convert(fields[k]) for k, convert in nested.items()}})


def _study(folder: Path, record: dict) -> list[Figure]:
    from bench.study import plots, report
    from bench.study.config import StudyConfig, nondefault_options
    from pipeline.detect import DetectorConfig
    from scenes.profile import CameraProfile

    config = _config(
        StudyConfig,
        _json(folder, record, "config.json"),
        camera=CameraProfile.from_json,
        detector=lambda fields: _config(DetectorConfig, fields),
    )
    summary = _csv(folder, record, "summary.csv")
    max_phi = _csv(folder, record, "max_phi_by_scale.csv")
    options = {"detector": config.detector_label, "options": nondefault_options(config)}
    refinements = report.refinements_of(config.detector.backend)
    return [
        ("max_phi.png", lambda p: plots.plot_max_phi(max_phi, p, **options)),
        ("heatmap.png", lambda p: plots.plot_heatmap(summary, p, **options)),
        ("pose_error.png",
         lambda p: plots.plot_pose_error(summary, p, **options, refinements=refinements)),
    ]  # fmt: skip


def _compare(folder: Path, record: dict) -> list[Figure]:
    from bench.evaluate.pareto import plot_pareto
    from bench.evaluate.sweep_config import SweepConfig, sweep_options
    from bench.evaluate.sweep_report import plot_sweeps
    from scenes.profile import CameraProfile

    settings = record.get("config", {})
    sweep = _config(SweepConfig, settings["sweep"], camera=CameraProfile.from_json)
    options, dataset = sweep_options(sweep), Path(settings["dataset"]).name
    summary = _csv(folder, record, "summary.csv")
    figures = [("pareto.png", lambda p: plot_pareto(summary, p, dataset, options))]
    if "sweeps.png" in record["outputs"]:  # a comparison of outside methods alone has none
        sweeps = _csv(folder, record, "sweeps.csv")
        figures.append(("sweeps.png", lambda p: plot_sweeps(sweeps, p, options)))
    return figures


def _ladder(folder: Path, record: dict) -> list[Figure]:
    from bench.ladder import report
    from bench.ladder.config import LadderConfig, ladder_options
    from bench.study.config import Cell

    config = _config(
        LadderConfig,
        _json(folder, record, "config.json"),
        cells=lambda cells: tuple(Cell(**c) for c in cells),
    )
    cells = _csv(folder, record, "rungs.csv").drop(columns="matches_reference")
    per_rung = report.per_rung(cells)
    defaults = report.defaults_table(per_rung)
    return [("ladder.png", lambda p: report.plot(per_rung, defaults, p, ladder_options(config)))]


def _score(folder: Path, record: dict) -> list[Figure]:
    from bench.evaluate.grid_plot import plot_grid

    table = _csv(folder, record, "samples.csv")
    settings = record.get("config", {})
    if "pipeline" in settings:  # a built-in pipeline, or another tool's detections
        name = settings["pipeline"]["name"]
        untimed = settings.get("results", {}).get("timed") is False
        suffix = " (accuracy only)" if untimed else ""
    else:  # another tool's branch estimates (bench.evaluate.branches_file)
        name, suffix = settings["name"], " (branches only, accuracy only)"
    figures = []
    for (protocol, lighting), part in table.groupby(["protocol", "lighting"]):
        title = f"{name}: {protocol}, {lighting}{suffix}"
        figures.append(
            (f"grid-{protocol}-{lighting}.png", lambda p, t=part, s=title: plot_grid(t, p, s))
        )
    return figures


#: A run's kind (its manifest's ``kind``) -> what reads its tables into the figures to draw.
REPLOTTERS: dict[str, Callable[[Path, dict], list[Figure]]] = {
    "detectability": _study,
    "compare": _compare,
    "ladder": _ladder,
    "score": _score,
}


def _table(folder: Path, record: dict, name: str) -> Path:
    """``folder/name``, once its SHA-256 matches the manifest's; FieldError otherwise."""
    path = folder / name
    listed = record["outputs"].get(name)
    if listed is None or not path.is_file():
        raise FieldError("folder", f"{folder}: {name} is missing or not in its manifest")
    if sha256(path) != listed:
        raise FieldError(
            "folder", f"{path}: differs from the manifest's hash; its figures would not be its own"
        )
    return path


def _csv(folder: Path, record: dict, name: str) -> pd.DataFrame:
    import pandas as pd

    return pd.read_csv(_table(folder, record, name))


def _json(folder: Path, record: dict, name: str) -> Any:
    return read_json(_table(folder, record, name), RECORD_BYTES, RECORD_DEPTH)


def manifest_path(folder: Path) -> Path:
    """The folder's manifest: its own, or the score manifest ``make indoor`` copies beside."""
    own = folder / MANIFEST
    return own if own.exists() or not (folder / COPIED_SCORE_MANIFEST).exists() else (
        folder / COPIED_SCORE_MANIFEST
    )  # fmt: skip


def _damaged(folder: Path, exc: BaseException) -> FieldError:
    detail = exc.detail if isinstance(exc, FieldError) else str(exc)
    return FieldError(
        "folder",
        f"{folder}: a table or its config is damaged or from another version, so its figures "
        f"cannot be drawn ({type(exc).__name__}: {detail})",
    )


def check_folder(folder: Path | str) -> Folder:
    """``folder``'s manifest and the figures to draw, once it is a run replot knows whose
    tables match their hashes and read as the run wrote them; FieldError (field ``folder``)
    naming the folder or file otherwise. Writes nothing."""
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
    try:
        figures = REPLOTTERS[kind](folder, record)
    except BoundedReadError as exc:
        raise FieldError("folder", f"{folder}: {exc}") from None
    except DAMAGED as exc:
        if isinstance(exc, FieldError) and exc.field == "folder":
            raise  # already names the folder's file
        raise _damaged(folder, exc) from None
    return Folder(folder, path, record, figures)


def replot(folders: Sequence[Path | str]) -> list[Path]:
    """Draw the ``folders``' figures again from their tables (the module docstring); the
    figures. FieldError (field ``folder``) for a folder it cannot replot, nothing replaced."""
    folders = list({Path(f).resolve(): Path(f) for f in folders}.values())  # each once
    # all checked before a lock file is made in a folder that is no run's
    kinds = [check_folder(folder).record["kind"] for folder in folders]
    with contextlib.ExitStack() as locks:
        for folder, kind in zip(folders, kinds, strict=True):
            try:
                locks.enter_context(open_folder(folder, kind, record=False))
            except ValueError as exc:
                raise FieldError("folder", str(exc)) from None
        accepted = [check_folder(folder) for folder in folders]  # again, nobody writing now
        with contextlib.ExitStack() as staged:  # every figure replaces its old one at the end
            for run in accepted:
                for name, draw in run.figures:
                    try:
                        draw(staged.enter_context(atomic_path(run.path / name)))
                    except DAMAGED as exc:
                        raise _damaged(run.path, exc) from None
        stamp = datetime.now(UTC).isoformat(timespec="seconds")
        for run in accepted:
            drawn = [name for name, _ in run.figures]
            run.record["outputs"].update({name: sha256(run.path / name) for name in drawn})
            run.record["replotted"] = {
                "at": stamp,
                "version": whiskerbench_version(),
                "figures": drawn,
            }
            if run.manifest.name == MANIFEST:
                write_manifest(run.path, run.record)
            else:  # the copied score manifest keeps its name
                write_json(run.manifest, run.record)
    return [run.path / name for run in accepted for name, _ in run.figures]


def add_replot_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``replot`` on the top-level subparsers."""
    p = subparsers.add_parser(
        "replot", help="draw a result folder's figures again from its own tables"
    )
    p.add_argument("folders", nargs="+", type=Path, metavar="FOLDER", help="result folders")
    p.set_defaults(func=cmd_replot)


def cmd_replot(args: argparse.Namespace) -> int:
    for figure in replot(args.folders):
        print(f"redrew {figure}")
    return 0

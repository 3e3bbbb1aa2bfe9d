"""``whiskerbench score DATASET --detections FILE_OR_DIR --name NAME``: another tool's results
scored as a built-in pipeline's (``docs/results_format.md``), and ``score DATASET --pipeline
branch-plugin:SPEC``: a branch finder's (``docs/plugins.md``); bad input: one line, exit code 2,
nothing written."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from bench.cli.args import check_out_folder
from bench.cli.hints import CSV, summary_hints
from bench.dataset.verify import SAMPLE_ID
from pipeline.presets import PRESETS
from scenes.validation import FieldError


def add_results_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--detections",
        type=Path,
        metavar="FILE_OR_DIR",
        help="score another tool's detections (docs/results_format.md: Parquet or CSV, or a "
        "folder of <sample id>.csv/.parquet) instead of running a detector; --pipeline then "
        "names the stages after detection (pose method, aggregation, threshold)",
    )
    p.add_argument(
        "--branches",
        type=Path,
        metavar="FILE",
        help="score another tool's final branch estimates alone (docs/results_format.md: "
        "sample_id, whisker_left, whisker_right; Parquet or CSV)",
    )
    p.add_argument(
        "--name",
        help="the method's name with --detections or --branches: letters, digits, '.', '_', "
        "'+', '-' (output <dataset>/scores/<name>)",
    )
    p.add_argument(
        "--fps",
        type=float,
        help="the method's frames/s with --detections, 1/3600 .. 1e6 (default: from the file's "
        "frame_time_s; without either the method is scored for accuracy only)",
    )


def wants_results(args: argparse.Namespace) -> bool:
    given = (args.detections, args.branches, args.name, args.fps)
    return any(v is not None for v in given)


def cmd_score_results(args: argparse.Namespace, fail: Callable[[str], int], executor: str) -> int:
    """Score ``--detections`` (see the module docstring) on ``executor``."""
    import dataclasses

    from bench.dataset.verify import verify_dataset
    from bench.evaluate.results_file import fps_problem, read_detections, sample_facts
    from bench.evaluate.score import score_dataset

    if args.detections is None and args.branches is None:
        return fail("--name and --fps go with --detections FILE_OR_DIR or --branches FILE")
    if args.detections is not None and args.branches is not None:
        return fail("--branches: give --detections or --branches, not both")
    if args.branches is not None and args.fps is not None:
        return fail("--fps: goes with --detections (branch estimates alone have no speed)")
    option = "--detections" if args.branches is None else "--branches"
    name = args.name
    if name is None:
        return fail(f"{option}: needs --name, the method's name")
    if not SAMPLE_ID.fullmatch(name):
        return fail(
            f"--name: {name!r}: expected letters, digits, '.', '_', '+', '-', starting "
            "with a letter or digit"
        )
    if name in {p.folder_name for p in PRESETS.values()}:
        return fail(f"--name: {name!r} is a built-in pipeline's name; choose another")
    fps = args.fps
    if fps is not None and (problem := fps_problem(fps)) is not None:
        return fail(f"--fps: {problem}")
    if not args.dataset.is_dir():
        return fail(f"{args.dataset}: not a dataset folder")
    out = args.out or args.dataset / "scores" / name
    try:
        check_out_folder(out)
    except FieldError as exc:
        return fail(f"--{exc.field}: {exc.detail}")
    if args.branches is not None:
        return _score_branches(args, name, out, fail)
    try:
        verified = verify_dataset(args.dataset)
        external = read_detections(args.detections, verified, sample_facts(verified))
    except (ValueError, FileNotFoundError) as exc:  # nothing written yet
        return fail(str(exc))
    config = dataclasses.replace(args.pipeline, name=name)  # its stages after detection
    args.kept = f"samples scored so far are kept in {out}/<sample id>/; rerun the same command"
    try:
        table = score_dataset(
            args.dataset,
            config,
            out,
            verified,
            args.workers,
            executor,
            args.scheduler,
            external=external,
            fps=fps,
        )
    except (ValueError, FileNotFoundError) as exc:
        return fail(str(exc))
    refused = table[table["outcome"] == "refused"]
    scored = table[table["outcome"] != "refused"]
    speed = (
        f"{scored['frames_per_s'].mean():.1f} frames/s"
        if scored["frames_per_s"].notna().any()
        else "accuracy only (no timing: --fps or frame_time_s)"
    )
    accuracy = "no rates"
    if len(scored):
        accuracy = (
            f"branch outcome correct in {(table['outcome'] == 'correct').mean():.0%}, "
            f"marker recall {scored['recall'].mean():.3f}"
        )
    print(
        f"{name}: {len(table)} samples, {len(refused)} refused: {accuracy}; {speed}; wrote "
        f"{out}/samples.csv and grid-*.png"
    )
    recall = scored["recall"].mean() if len(scored) else float("nan")
    for line in summary_hints(name, recall, len(refused), len(table), out / CSV):
        print(line)
    for row in refused.itertuples():
        print(f"warning: {row.sample_id} refused: {row.refused_reason}", file=sys.stderr)
    return 0


def _score_branches(
    args: argparse.Namespace, name: str, out: Path, fail: Callable[[str], int]
) -> int:
    from bench.dataset.verify import verify_dataset
    from bench.evaluate.branches_file import read_branches, score_branches
    from bench.evaluate.score import _array
    from scenes.array import ArraySpec

    try:
        verified = verify_dataset(args.dataset)
        n = {s: (_array(r) or ArraySpec()).n_whiskers for s, r in verified.records.items()}
        estimates = read_branches(args.branches, verified, n)
    except (ValueError, FileNotFoundError) as exc:  # nothing written yet
        return fail(str(exc))
    table = score_branches(args.branches, verified, estimates, name, out)
    correct = (table["outcome"] == "correct").mean()
    print(
        f"{name}: {len(table)} samples: branch outcome correct in {correct:.0%} (branch "
        f"estimates alone: accuracy only); wrote {out}/samples.csv and grid-*.png"
    )
    return 0


def cmd_score_branch_plugin(args: argparse.Namespace, fail: Callable[[str], int]) -> int:
    """Score the branch finder ``args.pipeline`` (an outside method) on every sample."""
    from bench.dataset.verify import verify_dataset
    from bench.evaluate.branch_plugin import run_branch_plugin
    from bench.evaluate.branches_file import score_branches

    method = args.pipeline
    out = args.out or args.dataset / "scores" / method.folder_name
    try:
        check_out_folder(out)
        verified = verify_dataset(args.dataset)
    except FieldError as exc:
        return fail(f"--{exc.field}: {exc.detail}")
    except (ValueError, FileNotFoundError) as exc:  # nothing written yet
        return fail(str(exc))
    args.kept = "nothing was written: the scores are written once every sample has run"
    estimates, refused = run_branch_plugin(method.name, verified)  # BackendError: one line
    table = score_branches(
        method.name, verified, estimates, method.name, out, refused, plugin=method.name
    )
    correct = (table["outcome"] == "correct").mean()
    print(
        f"{method.name}: {len(table)} samples, {len(refused)} refused: branch outcome correct "
        f"in {correct:.0%} (a branch finder: accuracy only); wrote {out}/samples.csv and grid-*.png"
    )
    for sample_id, why in refused.items():
        print(f"warning: {sample_id} refused: {why}", file=sys.stderr)
    return 0

"""``whiskerbench detect`` and ``score``: options and commands, and the option types and
helpers ``compare`` shares (:mod:`bench.cli.compare`; bad input: one line, exit code 2)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bench.cli import limits
from bench.cli.args import (
    add_executor_options,
    check_executor,
    check_out_folder,
    integer,
    name_list,
)
from bench.cli.hints import CSV, summary_hints
from bench.cli.results import (
    add_results_options,
    cmd_score_branch_plugin,
    cmd_score_results,
    wants_results,
)
from pipeline.presets import CHOICES, PRESETS, PipelineConfig, get_pipeline
from scenes.bounded_read import input_problem
from scenes.validation import FieldError

VARIANT_HELP = (
    f"a preset ({', '.join(PRESETS)}) or a detector plugin plugin:SPEC (docs/plugins.md), "
    "optionally changed by /CHOICE=VALUE parts, e.g. "
    f"paper/refine=contour/aruco3=on; choices: {', '.join(CHOICES)}"
)
OUTSIDE_HELP = (
    "; or results:FILE_OR_DIR (another tool's detections, docs/results_format.md) or "
    "branch-plugin:SPEC (a branch finder, docs/plugins.md), scored on the dataset only"
)


def _pipeline(text: str) -> PipelineConfig:
    try:
        return get_pipeline(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def pipelines(text: str) -> list[PipelineConfig]:
    names = name_list("--pipelines")(text)
    return [_pipeline(n) for n in names]


def _method(text: str):
    """A pipeline, ``results:PATH`` or ``branch-plugin:SPEC`` (:mod:`bench.evaluate.outside`)."""
    from bench.evaluate.outside import parse_method

    try:
        return parse_method(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def methods(text: str) -> list:
    """compare's ``--pipelines``: pipelines and outside methods."""
    return [_method(n) for n in name_list("--pipelines")(text)]


def _score_pipeline(text: str):
    """score's ``--pipeline``: a pipeline, or a branch finder ``branch-plugin:SPEC``."""
    from bench.evaluate.outside import RESULTS

    if text.startswith(RESULTS):
        raise argparse.ArgumentTypeError(f"{text!r}: give a results file as --detections")
    return _method(text)


def add_detect_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", type=Path, help="video file (synthetic or recorded)")
    p.add_argument(
        "--camera",
        required=True,
        help="camera profile JSON (a dataset's camera.json; a bare camera file too) or a shipped "
        "profile name; its lens is used",
    )
    p.add_argument(
        "--pipeline",
        default=PRESETS["paper"],
        type=_pipeline,
        help=VARIANT_HELP + " (default paper)",
    )
    p.add_argument(
        "--foliage-threshold",
        type=float,
        metavar="MM",
        help="maximum foliage deflection (from a no-branch sample), 0 .. 1000 mm; default: "
        "inferred online",
    )
    p.add_argument("--out", type=Path, help="output folder (default: <video>.<pipeline>/)")


#: A deflection is a marker's displacement from its no-contact pose: no whisker bends a metre
#: (the prototype's are 140 mm). Beyond it a threshold only overflows the plot's scale.
MAX_FOLIAGE_THRESHOLD_MM = 1000.0


def cmd_detect(args: argparse.Namespace) -> int:
    from bench.common.video import check_video
    from bench.evaluate.detect import run_detect
    from scenes.profile import ProfileError, load_profile

    def fail(message: str) -> int:
        print(f"whiskerbench detect: error: {message}", file=sys.stderr)
        return 2

    threshold = args.foliage_threshold
    if threshold is not None and not (0 <= threshold <= MAX_FOLIAGE_THRESHOLD_MM):
        return fail(
            f"--foliage-threshold: {threshold:g}: must be 0 .. {MAX_FOLIAGE_THRESHOLD_MM:g} mm"
        )
    missing = _missing_detector(args.pipeline)
    if missing:
        return fail(missing)
    try:
        camera = load_profile(args.camera).lens
    except ProfileError as exc:
        return fail(f"--camera: {exc.option_detail}")
    if args.video.is_dir():
        return fail(f"{args.video}: is a folder, not a video file")
    if not args.video.is_file():
        return fail(f"{args.video}: {input_problem(args.video) or 'no such file'}")
    try:
        check_video(args.video)  # bounded before the output is claimed or a frame decoded
    except ValueError as exc:
        return fail(f"{args.video}: {exc}")
    out = args.out or args.video.with_name(f"{args.video.stem}.{args.pipeline.folder_name}")
    try:
        check_out_folder(out)
    except FieldError as exc:
        return fail(f"--out: {exc.detail}")
    args.kept = f"files finished in {out} are complete; rerun the same command to redo the rest"
    try:
        record = run_detect(args.video, camera, args.pipeline, out, args.foliage_threshold)
    except ValueError as exc:  # unreadable or truncated video, no no-contact frames, ...
        return fail(f"{args.video}: {exc}")
    gaps = ", ".join(f"{b['gap'][0]}-{b['gap'][1]}" for b in record["branches"]) or "none"
    print(
        f"{record['frames']} frames at {record['frames_per_s']:.1f} frames/s; branches between "
        f"whiskers: {gaps} (threshold {record['threshold_mm']:.2f} mm, "
        f"{record['threshold_source']}); wrote {out}/"
    )
    if record["unseen_markers"]:
        print(
            f"warning: markers of whiskers {record['unseen_markers']} never seen", file=sys.stderr
        )
    if record["failed_frames"]:
        print(
            crash_warning(args.video, record["detector"], record["failed_frames"]), file=sys.stderr
        )
    fell_back = sum(record["refine_failures"].values())
    if fell_back:
        print(
            f"warning: corner refinement 'lines' kept the detector's corners of {fell_back} "
            f"detections (why: {out}/branches.json, refine_failures)",
            file=sys.stderr,
        )
    return 0


def _missing_detector(pipeline: PipelineConfig) -> str | None:
    """Why the pipeline's detector backend cannot run here (not installed: how to get it)."""
    from pipeline.backends import BackendUnavailableError, require

    try:
        for backend in pipeline.backends:
            require(backend)
    except BackendUnavailableError as exc:
        return f"--pipeline {pipeline.name}: {exc}"
    return None


def crash_warning(where: object, backend: str, frames: list[int]) -> str:
    """The stderr line for the frames a detector backend crashed on (10 of them named)."""
    named = ", ".join(map(str, frames[:10])) + (", ..." if len(frames) > 10 else "")
    return (
        f"warning: {where}: detector {backend} crashed on {len(frames)} frames ({named}); "
        "they have no detections"
    )


def add_score_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="dataset folder (made by whiskerbench dataset)")
    p.add_argument(
        "--pipeline",
        default=PRESETS["paper"],
        type=_score_pipeline,
        help=VARIANT_HELP + "; or a branch finder branch-plugin:SPEC (default paper)",
    )
    p.add_argument("--out", type=Path, help="output folder (default <dataset>/scores/<pipeline>)")
    add_results_options(p)
    add_workers_options(p, "one sample each")


def add_workers_options(p: argparse.ArgumentParser, task: str) -> None:
    p.add_argument(
        "--workers", type=integer, default=1, help=f"worker processes, {task} (default 1)"
    )
    add_executor_options(p)


def check_workers_option(args: argparse.Namespace) -> str:
    """The executor; FieldError on --workers, --executor or --scheduler."""
    limits.check_workers("workers", args.workers)
    return check_executor(args.executor, args.scheduler, args.workers)


def cmd_score(args: argparse.Namespace) -> int:
    def fail(message: str) -> int:
        print(f"whiskerbench score: error: {' '.join(message.split())}", file=sys.stderr)
        return 2

    if wants_results(args):  # another tool's detections: no detector runs
        try:
            executor = check_workers_option(args)
        except FieldError as exc:
            return fail(f"--{exc.field}: {exc.detail}")
        return cmd_score_results(args, fail, executor)
    if not args.dataset.is_dir():
        return fail(f"{args.dataset}: not a dataset folder")
    if not isinstance(args.pipeline, PipelineConfig):  # a branch finder
        return cmd_score_branch_plugin(args, fail)
    missing = _missing_detector(args.pipeline)
    if missing:
        return fail(missing)
    out = args.out or args.dataset / "scores" / args.pipeline.folder_name
    try:
        check_out_folder(out)
        executor = check_workers_option(args)
    except FieldError as exc:
        return fail(f"--{exc.field}: {exc.detail}")
    args.kept = (
        f"samples scored so far are kept in {out}/<sample id>/; samples.csv is written at the "
        "end: rerun the same command"
    )
    from bench.evaluate.score import score_dataset  # after the checks: a refusal stays quick

    try:
        table = score_dataset(
            args.dataset, args.pipeline, out, None, args.workers, executor, args.scheduler
        )
    except (ValueError, FileNotFoundError) as exc:
        return fail(str(exc))
    refused = table[table["outcome"] == "refused"]
    if len(refused) == len(table):  # no answer to rate: the counts say why
        accuracy = "no rates"
    else:
        correct = (table["outcome"] == "correct").mean()
        accuracy = f"branch outcome correct in {correct:.0%}, marker recall "
        accuracy += f"{table['recall'].mean():.3f}"
    reused = len(table.attrs.get("reused", ()))
    again = f" ({reused} scored by an earlier run of the same code and settings)" if reused else ""
    print(
        f"{len(table)} samples{again}, {len(refused)} refused: {accuracy}; wrote {out}/samples.csv "
        "and grid-*.png"
    )
    name = args.pipeline.name
    for line in summary_hints(name, table["recall"].mean(), len(refused), len(table), out / CSV):
        print(line)
    for row in refused.itertuples():
        print(f"warning: {row.sample_id} refused: {row.refused_reason}", file=sys.stderr)
    for row in table.itertuples():
        if getattr(row, "failed_frames", 0) > 0:  # NaN (refused) is not
            frames = json.loads(row.failed_frame_ids)
            print(
                crash_warning(row.sample_id, args.pipeline.detector.backend, frames),
                file=sys.stderr,
            )
    return 0

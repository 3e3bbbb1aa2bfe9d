"""``whiskerbench compare`` and ``bench pipeline``: options and commands (bad input: one line,
exit code 2); the pipelines' option types are :mod:`bench.cli.evaluate`'s."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from bench.cli import limits
from bench.cli.args import check_out_folder, integer
from bench.cli.evaluate import (
    OUTSIDE_HELP,
    VARIANT_HELP,
    add_workers_options,
    check_workers_option,
    methods,
    pipelines,
)
from bench.cli.hints import CSV, summary_hints
from pipeline.backends import PEERS_INSTALL
from pipeline.presets import PRESETS, PipelineConfig
from renderers.variant import VARIANTS
from scenes.validation import FieldError

#: What --pipelines of compare and bench pipeline default to.
DEFAULT_PIPELINES_HELP = (
    f"every preset whose detector is installed ({','.join(PRESETS)}; the peers need "
    f"{PEERS_INSTALL})"
)


def _installed_presets() -> list[PipelineConfig]:
    """Every preset whose detector can run here: a peer asked for by name and missing is
    refused, but a default without the optional peers still runs."""
    from pipeline.backends import available

    return [p for p in PRESETS.values() if all(map(available, p.backends))]


def add_compare_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="dataset folder (made by whiskerbench dataset)")
    p.add_argument(
        "--pipelines",
        type=methods,
        metavar="NAME,...",
        help="variants to compare, comma-separated; each "
        + VARIANT_HELP
        + OUTSIDE_HELP
        + f" (default {DEFAULT_PIPELINES_HELP})",
    )
    p.add_argument("--out", type=Path, help="report folder (default <dataset>/compare)")
    p.add_argument(
        "--seeds",
        type=integer,
        help="seeds per sweep level (default 5, at least 5; with --quick default 2, at least 1)",
    )
    p.add_argument(
        "--quick", action="store_true", help="a small sweep (2 seeds unless --seeds, few levels)"
    )
    p.add_argument(
        "--camera",
        metavar="PROFILE",
        help="camera profile of the failure-boundary sweeps: a shipped name or a JSON file "
        "(default: the dataset's own, from its samples' camera.json)",
    )
    p.add_argument(
        "--speed-frames",
        type=integer,
        default=40,
        metavar="N",
        help="frames of the dataset to time each pipeline on, in runs of 10 consecutive frames "
        f"spread evenly over its samples (default 40, 1..{limits.MAX_SPEED_FRAMES})",
    )
    _add_rounds_option(p, "--speed-rounds")
    p.add_argument(
        "--variant", choices=VARIANTS, help="Mitsuba variant (default: the fastest available)"
    )
    add_workers_options(p, "one sample or sweep render each")


def _add_rounds_option(p: argparse.ArgumentParser, name: str) -> None:
    low, high = limits.SPEED_ROUNDS_RANGE
    p.add_argument(
        name,
        type=integer,
        default=5,
        metavar="R",
        help="timing rounds, the pipelines alternating in each; frames/s is the median, the "
        f"slowest and fastest round its spread (default 5, {low}..{high})",
    )


def _sweep_camera(option: str | None, dataset: Path):
    """The sweeps' camera profile: the option's, else the one the dataset was rendered with."""
    from bench.study.config import StudyConfigError, profile_from_option

    if option is None:
        cameras = sorted(dataset.glob("*/camera.json"))[:1]
        if not cameras:
            return None  # run_compare refuses a folder without samples in its own words
        option = str(cameras[0])
    try:
        return profile_from_option(option)
    except StudyConfigError as exc:
        raise ValueError(f"--camera: {exc.detail}") from None


def _dataset_lens(dataset: Path):
    """The lens of the dataset's first sample (its frames' size), None where there is no
    readable one (run_compare then refuses the folder in its own words)."""
    try:
        return _sweep_camera(None, dataset).lens
    except (ValueError, AttributeError):  # None: no sample
        return None


def _on_camera(sweep, camera, option: str | None):
    """The sweep on ``camera``: its built-in alphas end at the lens's edge, as the study's do;
    its base angle is not fitted, since every other axis is read there: a lens that does not
    see it is refused, naming --camera, or the dataset whose camera it is."""
    from bench.study.config import alphas_within

    theta_max, base = camera.lens.theta_max_deg, sweep.base_alpha_deg
    if base > theta_max:
        culprit = f"--camera {option}" if option is not None else "DATASET: its camera.json"
        raise ValueError(
            f"{culprit}: its lens sees 0..{theta_max:g} deg off axis; the sweep's base angle is "
            f"{base:g} deg (every axis but alpha is read there): a lens that sees at least "
            f"{base:g} deg is needed"
        )
    alphas = alphas_within(sweep.alphas_deg, camera)
    return dataclasses.replace(sweep, camera=camera, alphas_deg=alphas)


def cmd_compare(args: argparse.Namespace) -> int:
    import pandas as pd

    from bench.evaluate.compare import run_compare
    from bench.evaluate.leaders import band_lines, spread_verdict
    from bench.evaluate.score import dataset_family
    from bench.evaluate.sweep_config import QUICK_SWEEP, SweepConfig
    from pipeline.backends import BackendUnavailableError

    def fail(message: str) -> int:
        print(f"whiskerbench compare: error: {' '.join(message.split())}", file=sys.stderr)
        return 2

    args.pipelines = args.pipelines or _installed_presets()
    least = 1 if args.quick else 5  # --quick fills in what was not given, as in every command
    base = QUICK_SWEEP if args.quick else SweepConfig()
    seeds = base.seeds if args.seeds is None else args.seeds
    if seeds < least:
        hint = "with --quick" if args.quick else "use --quick for a smoke run"
        return fail(f"--seeds: {seeds}: must be >= {least} ({hint})")
    sweep = dataclasses.replace(base, seeds=seeds)
    if not args.dataset.is_dir():
        return fail(f"{args.dataset}: not a dataset folder")
    out = args.out or args.dataset / "compare"
    try:
        check_out_folder(args.dataset / "scores", "dataset")  # each variant's scores go there
        check_out_folder(out)
        limits.check_sweep(sweep, len(args.pipelines))
        limits.check_speed_rounds("speed-rounds", args.speed_rounds)
        limits.check_speed_frames("speed-frames", args.speed_frames, _dataset_lens(args.dataset))
        executor = check_workers_option(args)
    except FieldError as exc:
        return fail(f"{'DATASET' if exc.field == 'dataset' else '--' + exc.field}: {exc.detail}")
    args.kept = (
        f"scores of the variants finished so far are kept in {args.dataset / 'scores'}; the "
        f"report in {out} is written at the end: rerun the same command"
    )
    try:
        camera = _sweep_camera(args.camera, args.dataset)
        if camera is not None:
            sweep = _on_camera(sweep, camera, args.camera)
        family = dataset_family(args.dataset)
        if family is not None:  # the sweeps render the dataset's marker family
            sweep = dataclasses.replace(sweep, dictionary=family)
        summary = run_compare(
            args.dataset,
            args.pipelines,
            out,
            sweep,
            speed_frames=args.speed_frames,
            speed_rounds=args.speed_rounds,
            variant=args.variant,
            workers=args.workers,
            executor=executor,
            scheduler=args.scheduler,
        )
    except (ValueError, FileNotFoundError, BackendUnavailableError) as exc:
        return fail(str(exc))
    for row in summary.itertuples():
        if row.failed:  # its backend failed, timed or scored: why, and the others went on
            print(f"{row.pipeline:>24}: failed: {row.failed}")
            continue
        if row.refused_samples == row.samples:  # no answer to rate: the counts say why
            accuracy = f"refused all {row.samples} samples, no rates"
        else:
            accuracy = (
                f"correct {row.correct_rate:.0%}, recall {row.recall:.3f}, deflection error "
                f"{row.deflection_err_mm:.2f} mm"
            )
        if math.isfinite(row.fps_min):  # timed in the rounds
            speed = f"{row.fps:7.1f} frames/s ({row.fps_min:.1f}-{row.fps_max:.1f})"
        elif math.isfinite(row.fps):  # a results file's own times
            speed = f"{row.fps:7.1f} frames/s (the file's own times)"
        else:
            speed = "accuracy only"
        print(f"{row.pipeline:>24}: {speed}, {accuracy}")
    folders = {p.name: p.folder_name for p in args.pipelines}
    for row in summary.itertuples():
        if row.failed:  # said above
            continue
        csv = args.dataset / "scores" / folders.get(row.pipeline, row.pipeline) / CSV
        for line in summary_hints(row.pipeline, row.recall, row.refused_samples, row.samples, csv):
            print(line)
    leads = pd.read_csv(out / "leaders.csv")
    for row in leads[leads["measure"] == "fps"].itertuples(index=False):
        if isinstance(row.lead_within_spread, bool):
            print(f"speed lead of {row.leader}: {spread_verdict(row)}")
    for line in band_lines(leads):
        print(line)
    print(f"wrote {out}/report.md")
    return 0


def add_bench_pipeline_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--pipelines",
        type=pipelines,
        metavar="NAME,...",
        help=f"variants to time; ratios are against the first (default {DEFAULT_PIPELINES_HELP})",
    )
    p.add_argument("--frames", type=integer, default=30, help="full frames to time (default 30)")
    _add_rounds_option(p, "--rounds")
    p.add_argument("--out", type=Path, help="also write bench.json into this folder")
    p.add_argument(
        "--variant", choices=VARIANTS, help="Mitsuba variant (default: the fastest available)"
    )


def cmd_bench_pipeline(args: argparse.Namespace) -> int:
    from bench.benchmarks.pipeline import band_scales, bench_pipeline
    from bench.dataset.config import DatasetConfigError
    from bench.evaluate.speed import SPEED_SAMPLE
    from pipeline.backends import BackendUnavailableError

    if args.frames < 2:
        raise DatasetConfigError("frames", f"{args.frames}: must be >= 2")
    try:
        limits.check_speed_rounds("rounds", args.rounds)
    except FieldError as exc:
        print(f"whiskerbench bench pipeline: error: --rounds: {exc.detail}", file=sys.stderr)
        return 2
    lens = SPEED_SAMPLE.camera.lens
    scales = 1 + len(band_scales(SPEED_SAMPLE))  # the frames at 1 and at the band's ends
    size = f"{lens.width_px}x{lens.height_px}"
    what = f"{args.frames} full frames of {size} at {scales} PSF scales"
    limits.check_memory("frames", args.frames, scales * lens.width_px * lens.height_px, what)
    if args.out is not None:
        check_out_folder(args.out)
    pipelines = args.pipelines or _installed_presets()
    try:
        bench_pipeline(
            pipelines, frames=args.frames, rounds=args.rounds, variant=args.variant, out=args.out
        )
    except BackendUnavailableError as exc:  # refused before any work
        print(f"whiskerbench bench pipeline: error: --pipelines: {exc}", file=sys.stderr)
        return 2
    return 0

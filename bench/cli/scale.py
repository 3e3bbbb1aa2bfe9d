"""Options of ``whiskerbench bench scale`` and its command, validated before any work."""

from __future__ import annotations

import argparse

from bench.cli import limits
from bench.cli.args import check_out_folder, integer, name_list
from bench.common.executor import EXECUTORS
from bench.study.config import StudyConfig
from scenes.validation import FieldError


def add_scale_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--executors",
        type=name_list("--executors"),
        metavar="NAME,...",
        help="executors to time, of inline, pool, dask; inline with 1 worker always runs (the "
        "baseline of the ratios) (default inline,pool,dask)",
    )
    p.add_argument(
        "--workers-max",
        type=integer,
        default=2,
        help="pool and Dask rows with 2..N workers (default 2; 1 times the baseline alone)",
    )
    p.add_argument("--out", help="also write bench.json and manifest.json into this folder")
    p.add_argument(
        "--variant",
        choices=("cuda_ad_rgb", "llvm_ad_rgb"),
        help="Mitsuba variant (default: the fastest that works here)",
    )


def check_executors(names: tuple[str, ...] | None) -> tuple[str, ...]:
    """The executors asked for (default: all three); FieldError on ``executors``."""
    if names is None:
        return EXECUTORS
    unknown = [n for n in names if n not in EXECUTORS]
    if unknown:
        raise FieldError(
            "executors",
            f"unknown {', '.join(map(repr, unknown))}; choose from {', '.join(EXECUTORS)}",
        )
    return names


def cmd_bench_scale(args: argparse.Namespace, study: StudyConfig) -> int:
    """Validate, then time ``study`` (the quick study) and the benchmark's fixed dataset."""
    from bench.benchmarks.scale import SCALE_DATASET, bench_scale
    from bench.dataset.config import DatasetConfig

    executors = check_executors(args.executors)
    limits.check_workers("workers_max", args.workers_max)
    out = check_out_folder(args.out) if args.out is not None else None
    dataset = DatasetConfig(**SCALE_DATASET)
    bench_scale(study, dataset, executors, args.workers_max, args.variant, out)
    return 0

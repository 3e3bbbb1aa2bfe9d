"""``whiskerbench bench targets``: its options, validated, and the call to the benchmark."""

from __future__ import annotations

import argparse

from bench.cli import limits
from bench.cli.args import RUNS, check_out_folder
from bench.cli.dataset import add_dataset_options, dataset_config
from bench.dataset.config import DatasetConfig

#: The default run folder.
TARGETS_OUT = RUNS / "bench-targets"


def dataset_of(argv: list[str]) -> DatasetConfig:
    """The DatasetConfig ``whiskerbench dataset <argv>`` makes (its own options, its defaults)."""
    p = argparse.ArgumentParser()
    add_dataset_options(p)
    return dataset_config(p.parse_args(argv))


def cmd_bench_targets(args: argparse.Namespace) -> int:
    from bench.benchmarks.targets import bench_targets

    out = check_out_folder(args.out)
    quick = dataset_of(["--quick"])  # the targets' own commands: dataset --quick, make indoor
    indoor = dataset_of(["--protocol", "indoor"])
    limits.check_dataset(quick, 2)
    bench_targets(quick, indoor, out, args.quick, args.time_tests)
    return 0


def add_bench_targets_parser(bench_sub) -> None:
    """The ``targets`` parser under ``bench``."""
    p = bench_sub.add_parser(
        "targets", help="issue 25's targets: each figure, its threshold and whether it is met"
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="every 10th frame of the datasets and no Cycles renders: a first look",
    )
    p.add_argument(
        "--time-tests",
        action="store_true",
        help="also time make test and make test-fast in this folder (minutes)",
    )
    p.add_argument(
        "--out",
        default=TARGETS_OUT,
        help=f"write targets.csv and manifest.json here (default {TARGETS_OUT})",
    )
    p.set_defaults(func=cmd_bench_targets)

"""``whiskerbench bench loader``: its options and the call to the benchmark."""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.cli.args import integer
from scenes.validation import FieldError


def cmd_bench_loader(args: argparse.Namespace) -> int:
    from bench.benchmarks.loader import bench_loader
    from bench.dataset.format import DatasetFormatError

    if args.repeats < 1:
        raise FieldError("--repeats", f"{args.repeats}: must be >= 1")
    if args.random_frames < 0:
        raise FieldError("--random-frames", f"{args.random_frames}: must be >= 0")
    try:
        bench_loader(args.dataset, args.sample, args.repeats, args.random_frames)
    except DatasetFormatError as exc:
        raise FieldError("DATASET", str(exc)) from None
    except KeyError as exc:  # an unknown --sample
        raise FieldError("--sample", str(exc.args[0])) from None
    return 0


def add_bench_loader_parser(bench_sub) -> None:
    """The ``loader`` parser under ``bench``."""
    p = bench_sub.add_parser(
        "loader", help="frames/s of the dataset loader against decoding the video with OpenCV"
    )
    p.add_argument("dataset", type=Path, metavar="DATASET", help="a dataset folder")
    p.add_argument("--sample", help="the sample id to read (default: the dataset's first)")
    p.add_argument("--repeats", type=integer, default=3, help="timed runs per reader (default 3)")
    p.add_argument(
        "--random-frames",
        type=integer,
        default=20,
        help="frames read in random order for the random-access figure (default 20)",
    )
    p.set_defaults(func=cmd_bench_loader)

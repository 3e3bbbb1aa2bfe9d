"""``whiskerbench ladder``: the fidelity ladder's options, their checks, and the command."""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.cli import limits
from bench.cli.args import check_out_folder, integer, name_list, seed
from bench.ladder.config import OPTION_OF_FIELD, LadderConfig, LadderConfigError


#: LadderConfig field -> the option that sets it (for one-line errors).
def _spps(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in name_list("--spp")(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--spp: {text!r}: integers, comma-separated") from None


def add_ladder_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``ladder`` on the top-level subparsers."""
    p = subparsers.add_parser(
        "ladder", help="one rendering choice at a time against a high-quality reference"
    )
    p.add_argument("--out", required=True, help="output folder (resumable)")
    p.add_argument("--quick", action="store_true", help="a tiny ladder for tests (seconds)")
    p.add_argument("--parts", type=name_list("--parts"), help="study,video (default both)")
    p.add_argument("--images", type=integer, help="images per study cell and rung (1..800)")
    p.add_argument("--frames-step", type=integer, help="render every n-th video frame (1..30)")
    p.add_argument("--profile", help="the video's camera profile (default prototype)")
    p.add_argument(
        "--video-axes", type=name_list("--video-axes"), help="the video's axes (default all)"
    )
    p.add_argument("--spp", type=_spps, help="spp rungs, e.g. 1,2,4,8,16")
    p.add_argument("--reference-spp", type=integer, help="the reference's spp (1..1024)")
    p.add_argument("--path-depth", type=integer, help="the reference's path depth (1..8)")
    p.add_argument("--pipeline", help="pipeline run on the clip (default paper)")
    p.add_argument("--seed", type=seed, help="seed of every render and noise draw")
    p.add_argument("--workers", type=integer, default=1, help="worker processes (default 1)")
    p.add_argument("--variant", help="Mitsuba variant (default: the fastest available)")
    p.set_defaults(func=cmd_ladder)


def ladder_config(args: argparse.Namespace) -> LadderConfig:
    """The config of the options; LadderConfigError names the field on a bad value."""
    fields = {
        "parts": args.parts,
        "images": args.images,
        "frames_step": args.frames_step,
        "profile": args.profile,
        "video_axes": args.video_axes,
        "spps": args.spp,
        "reference_spp": args.reference_spp,
        "path_depth": args.path_depth,
        "pipeline": args.pipeline,
        "seed": args.seed,
    }
    given = {k: v for k, v in fields.items() if v is not None}
    if "pipeline" in given:
        from pipeline.presets import get_pipeline

        try:
            get_pipeline(given["pipeline"])
        except ValueError as exc:
            raise LadderConfigError("--pipeline", str(exc)) from None
    return LadderConfig.quick(**given) if args.quick else LadderConfig(**given)


def cmd_ladder(args: argparse.Namespace) -> int:
    from bench.ladder.run import open_ladder, run_ladder

    try:
        config = ladder_config(args)
    except LadderConfigError as exc:
        raise LadderConfigError(OPTION_OF_FIELD.get(exc.field, exc.field), exc.detail) from None
    limits.check_workers("--workers", args.workers)
    out = check_out_folder(Path(args.out), "--out")
    try:
        run = open_ladder(config, out)
    except ValueError as exc:  # the folder is another command's, or another ladder's
        raise LadderConfigError("--out", str(exc)) from None
    with run:  # the folder stays locked until the manifest is written
        manifest = run_ladder(config, out, args.workers, variant=args.variant, run=run)
    print(f"ladder: {out} in {manifest['wall_s']['total_s']:.0f} s; see {out / 'table.md'}")
    return 0

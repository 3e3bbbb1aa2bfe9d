"""The ``whiskerbench`` command line: parse, call an importable function, report.

Bad input gets one line naming the option and the allowed range, exit code 2, nothing written;
an internal error a short bug report and exit code 1; Ctrl-C exit code 130 and what is kept;
stdout closed early (``| head``) a quiet exit code 141, as a shell reports SIGPIPE.
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import functools
import re
import sys
from pathlib import Path

from bench.cli import limits
from bench.cli.args import (
    BAND,
    RUNS,
    add_executor_options,
    check_executor,
    check_out_folder,
    check_variant,
    float_list,
    integer,
    psf_scales_option,
    seed,
)
from bench.cli.camera import add_camera_parser
from bench.cli.compare import (
    add_bench_pipeline_options,
    add_compare_options,
    cmd_bench_pipeline,
    cmd_compare,
)
from bench.cli.dataset import OPTION_OF_FIELD as DATASET_OPTION_OF_FIELD
from bench.cli.dataset import add_bench_dataset_parser, add_dataset_options, cmd_dataset
from bench.cli.evaluate import add_detect_options, add_score_options, cmd_detect, cmd_score
from bench.cli.exits import (
    bug_report,
    end_quietly,
    environment_failure,
    prepare_streams,
    stdout_closed,
    undecodable_argument,
)
from bench.cli.images import add_images_parser
from bench.cli.ladder import add_ladder_parser
from bench.cli.lens import add_lens_parser
from bench.cli.loader import add_bench_loader_parser
from bench.cli.render import add_bench_render_parser
from bench.cli.replot import add_replot_parser
from bench.cli.scale import add_scale_options, cmd_bench_scale
from bench.cli.targets import add_bench_targets_parser
from bench.common.manifest import input_digests, whiskerbench_version
from bench.common.run_folder import FolderBusyError, set_command_line
from bench.study.config import (
    DEFAULT_ALPHAS_DEG,
    DEFAULT_PHIS_DEG,
    DEFAULT_SIZES_MM,
    StudyConfig,
    alphas_within,
    detector_from_option,
    profile_from_option,
)
from pipeline.backends import BACKENDS, backend_name
from scenes.profile import profile_path
from scenes.validation import FieldError

QUICK = {"sizes": (8.8, 13.2), "alphas": (0.0, 60.0, 85.0), "phis": (0.0, 30.0, 60.0), "images": 30}
OPTION_OF_FIELD = {
    "sizes_mm": "--sizes",
    "alphas_deg": "--alphas",
    "phis_deg": "--phis",
    "images": "--images",
    "distance_mm": "--distance",
    "lightings": "--lighting",
    "dictionary": "--family/--dictionary",
    "spp": "--spp",
    "out": "--out",
    "variant": "--variant",
    "workers": "--workers",
    "executor": "--executor",
    "scheduler": "--scheduler",
    "camera": "--camera",
    "psf_scales": "--psf-scale",
    "exposure": "--exposure",
    "detector": "--detector",
    "cell_px": "--cell-px",
    "seed": "--seed",
    "study_grid": "--sizes x --alphas x --phis x --lighting",
    "full_frame_cells": "--full-frame-cells",
    "executors": "--executors",
    "workers_max": "--workers-max",
    "threads": "--threads",
    "scene": "--scene",
}


class _Parser(argparse.ArgumentParser):
    """argparse, but an error is one line (no usage block): option, problem, exit code 2."""

    def error(self, message: str):
        message = re.sub(r"^argument (\S+): \1: ", r"\1: ", message)  # the option named once
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _add_study_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sizes",
        type=float_list("--sizes"),
        metavar="MM,...",
        help=f"marker sizes in mm (default {','.join(f'{s:g}' for s in DEFAULT_SIZES_MM)})",
    )
    p.add_argument(
        "--alphas",
        type=float_list("--alphas"),
        metavar="DEG,...",
        help="angular positions in degrees, 0..theta_max (default "
        f"{','.join(f'{a:g}' for a in DEFAULT_ALPHAS_DEG)}, each past the camera's theta_max "
        "replaced by theta_max)",
    )
    p.add_argument(
        "--phis",
        type=float_list("--phis"),
        metavar="DEG,...",
        help="tilts about both in-plane axes, 0..89 degrees (default "
        f"{','.join(f'{a:g}' for a in DEFAULT_PHIS_DEG)})",
    )
    p.add_argument(
        "--images",
        type=integer,
        metavar="N",
        help="cap on images per cell: each cell draws images (10, 30, 80, 160, 240, ...) until "
        "the 95%% Wilson interval of its detection rate excludes 0.95 or N is reached "
        "(default 240)",
    )
    p.add_argument(
        "--camera",
        metavar="PROFILE",
        default="prototype",
        help="camera profile: a shipped name (prototype, ideal) or a profile JSON file "
        "(default prototype, the seed system's ELP/MT9P001 fisheye camera)",
    )
    p.add_argument(
        "--psf-scale",
        type=psf_scales_option,
        metavar="F,...|band",
        default=(1.0,),
        help="factors on the profile's PSF widths; several draw the sensitivity band; 'band': "
        "the profile's own band, its ends, midpoints and 1 (make study; default 1)",
    )
    p.add_argument(
        "--cell-px",
        type=integer,
        default=4,
        help="pixels per code cell when OpenCV reads the bits (perspectiveRemovePixelPerCell), "
        "2..32 (default 4, OpenCV's and the original system's)",
    )
    p.add_argument(
        "--exposure",
        type=float,
        default=1.0,
        help="linear radiance to sensor full scale, times the lighting preset's own (default 1)",
    )
    p.add_argument(
        "--distance",
        type=float,
        metavar="MM",
        default=200.0,
        help="camera-marker distance in mm (default 200)",
    )
    p.add_argument(
        "--lighting",
        nargs="+",
        metavar="PRESET",
        default=["sun"],
        help="one or more of lab, sun, canopy, backlit (default sun)",
    )
    p.add_argument(
        "--detector",
        type=backend_name,
        default="opencv",
        help=f"which library finds the markers: {', '.join(BACKENDS)} (the peers: pip install "
        "-e '.[peers]'), or a plugin: module:function, path/file.py:function or an entry "
        "point's name (docs/plugins.md) (default opencv, its subpix corners)",
    )
    p.add_argument(
        "--family",
        "--dictionary",
        dest="dictionary",
        default="4x4_50",
        help="marker family, one the detector decodes: 4x4_50, apriltag_36h11, apriltag_16h5, "
        "... (OpenCV's dictionary names; default 4x4_50)",
    )
    p.add_argument("--seed", type=seed, default=0, help="random seed, 0..2**32-1 (default 0)")
    p.add_argument("--spp", type=integer, default=16, help="samples per pixel of the clean render")
    p.add_argument(
        "--variant",
        choices=("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb"),
        help="Mitsuba variant (default: the fastest that works here)",
    )
    p.add_argument(
        "--workers",
        type=integer,
        help="worker processes, one cell at a time each (default: one per core, as many as "
        "memory allows; 1 runs in this process)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="a small grid for a first look (2 sizes x 3 alphas x 3 phis, at most 30 images)",
    )


def study_config(args: argparse.Namespace) -> StudyConfig:
    """The StudyConfig the options describe (--quick fills what was not given; alphas_within)."""
    quick = QUICK if args.quick else {}
    lightings = tuple(name for item in args.lighting for name in item.split(",") if name)
    camera = profile_from_option(args.camera)
    return StudyConfig(
        sizes_mm=args.sizes or quick.get("sizes", DEFAULT_SIZES_MM),
        alphas_deg=args.alphas or alphas_within(quick.get("alphas", DEFAULT_ALPHAS_DEG), camera),
        phis_deg=args.phis or quick.get("phis", DEFAULT_PHIS_DEG),
        images=args.images if args.images is not None else quick.get("images", 240),
        distance_mm=args.distance,
        lightings=lightings,
        dictionary=args.dictionary,
        seed=args.seed,
        spp=args.spp,
        camera=camera,
        psf_scales=camera.band.psf_levels() if args.psf_scale == BAND else args.psf_scale,
        exposure=args.exposure,
        detector=detector_from_option(args.cell_px, args.detector, args.dictionary),
    )


def default_out(config: StudyConfig, quick: bool) -> Path:
    """``runs/detectability/<name>``: ``default``, ``quick`` or ``custom-<hash>`` of the grid,
    then the detector and the family where they are not the defaults (``quick-locus``)."""
    default = StudyConfig()
    plain = dataclasses.replace(
        config,
        dictionary=default.dictionary,
        detector=dataclasses.replace(
            config.detector, dictionary=default.dictionary, backend="opencv",
            corner_refinement=default.detector.corner_refinement,
        ),
    )  # fmt: skip
    if plain == default or plain == StudyConfig(psf_scales=default.camera.band.psf_levels()):
        name = "default"
    elif quick and plain == study_config(_parser().parse_args(["detectability", "--quick"])):
        name = "quick"
    else:
        import hashlib
        import json

        digest = hashlib.sha256(
            json.dumps(plain.to_json(), default=str, sort_keys=True).encode()
        ).hexdigest()[:8]
        name = f"custom-{digest}"
    backend = config.detector.backend.replace("/", "~")  # a plugin's file: no subfolder
    extra = [backend] if backend != "opencv" else []
    extra += [config.dictionary] if config.dictionary != default.dictionary else []
    return RUNS / "detectability" / "-".join([name, *extra])


def _cmd_detectability(args: argparse.Namespace) -> int:
    config = study_config(args)
    out = check_out_folder(args.out if args.out is not None else default_out(config, args.quick))
    workers = limits.default_workers() if args.workers is None else args.workers
    limits.check_study(config, workers)
    executor = check_executor(args.executor, args.scheduler, args.workers)
    args.kept = f"finished cells are kept in {out / 'cells'}; rerun the same command to resume"
    from bench.study.run import run_study  # after the checks: a refusal stays quick

    manifest = run_study(
        config,
        out,
        variant=args.variant,
        workers=workers,
        save_images=args.save_images,
        inputs=input_digests([profile_path(args.camera)]),
        executor=executor,
        scheduler=args.scheduler,
    )
    print(
        f"wrote {out}/ ({manifest['cells_total']} cells, {manifest['cells_resumed']} resumed; "
        f"{manifest['images_total']} images in {manifest['wall_s']['cells_s']:.1f} s, "
        f"{manifest['images_per_s'] or 0:.0f} images/s, variant {manifest['variant']})"
    )
    print(f"max phi with detection >= 95%: {out / 'max_phi.csv'}, plot {out / 'max_phi.png'}")
    failures = manifest["backend_failures"]
    if failures:
        print(
            f"detector {config.detector.backend} crashed on {sum(failures.values())} images "
            f"(not counted as detected or missed) in {len(failures)} cells: "
            + ", ".join(f"{cell} ({n})" for cell, n in failures.items())
        )
    if len(config.psf_scales) > 1:
        print(f"band over PSF scales {', '.join(f'{s:g}' for s in config.psf_scales)} included")
    return 0


def _cmd_bench_detectability(args: argparse.Namespace) -> int:
    from bench.benchmarks.study import bench_detectability

    config = study_config(args)
    workers = limits.default_workers() if args.workers is None else args.workers
    limits.check_study(config, workers)
    limits.check_full_frame_cells(args.full_frame_cells, config)
    bench_detectability(
        config, variant=args.variant, full_frame_cells=args.full_frame_cells, workers=workers
    )
    return 0


def _cmd_bench_scale(args: argparse.Namespace) -> int:
    """``bench scale`` on the quick study (and the benchmark's own small dataset)."""
    return cmd_bench_scale(args, study_config(_parser().parse_args(["detectability", "--quick"])))


@functools.cache  # once per process: parsing keeps no state (tests call main thousands of times)
def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="whiskerbench", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {whiskerbench_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    study = sub.add_parser("detectability", help="rerun the marker-size detectability study")
    _add_study_options(study)
    study.add_argument("--out", help=f"run folder (default {RUNS}/detectability/<name>)")
    study.add_argument(
        "--save-images",
        action="store_true",
        help="also write every 8-bit image detected on (PNG) for inspection",
    )
    add_executor_options(study)
    study.set_defaults(func=_cmd_detectability)
    bench = sub.add_parser("bench", help="speed benchmarks (print their figures)")
    bench_sub = bench.add_subparsers(dest="benchmark", required=True, parser_class=_Parser)
    bdet = bench_sub.add_parser(
        "detectability", help="time the full default study, crops vs full frames"
    )
    _add_study_options(bdet)
    bdet.add_argument(
        "--full-frame-cells",
        type=integer,
        default=2,
        help="cells rendered as full 2592x1944 frames for the ratio (default 2)",
    )
    bdet.set_defaults(func=_cmd_bench_detectability)
    det = sub.add_parser("detect", help="find branches in one video with a pipeline variant")
    add_detect_options(det)
    det.set_defaults(func=cmd_detect)
    score = sub.add_parser("score", help="score a pipeline variant on a labeled dataset")
    add_score_options(score)
    score.set_defaults(func=cmd_score)
    compare = sub.add_parser(
        "compare", help="compare pipeline variants by accuracy and speed; writes a report"
    )
    add_compare_options(compare)
    compare.set_defaults(func=cmd_compare)
    bpipe = bench_sub.add_parser(
        "pipeline", help="frames/s of each pipeline on full frames, one core"
    )
    add_bench_pipeline_options(bpipe)
    bpipe.set_defaults(func=cmd_bench_pipeline)
    data = sub.add_parser("dataset", help="generate labeled videos of the array in vegetation")
    add_dataset_options(data)
    data.add_argument("--out", help="dataset folder (default data/default, data/quick)")
    data.add_argument(
        "--workers",
        type=integer,
        default=1,
        help="worker processes, one sample each (default 1: one sample uses every core)",
    )
    add_executor_options(data)
    data.set_defaults(func=cmd_dataset)
    add_bench_dataset_parser(bench_sub)
    bscale = bench_sub.add_parser(
        "scale", help="images/s and frames/s against executor and workers, default grids' time"
    )
    add_scale_options(bscale)
    bscale.set_defaults(func=_cmd_bench_scale)
    add_bench_render_parser(bench_sub)
    add_bench_loader_parser(bench_sub)
    add_bench_targets_parser(bench_sub)
    add_camera_parser(sub, _Parser)
    add_lens_parser(sub, _Parser)
    add_images_parser(sub)
    add_ladder_parser(sub)
    add_replot_parser(sub)
    return parser


def command_name(args: argparse.Namespace) -> str:
    """``detectability``, ``bench pipeline``, ``camera import``, ...: the command as typed."""
    subcommands = ("benchmark", "camera_command", "lens_command")
    return " ".join([args.command, *(getattr(args, k) for k in subcommands if hasattr(args, k))])


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit code. A reader that closes stdout early (``| head -1``)
    wanted no more output: the command ends quietly, with SIGPIPE's shell exit code."""
    prepare_streams()
    try:
        try:
            return _main(argv)
        finally:
            if sys.stdout is not None:  # None: started with stdout closed (>&-)
                sys.stdout.flush()  # a reader gone shows here, not at interpreter exit
    except BrokenPipeError:
        return end_quietly()


def _main(argv: list[str] | None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    command = command_name(args)
    set_command_line(sys.argv[1:] if argv is None else argv)
    args.kept = "nothing was written"
    odd = undecodable_argument(sys.argv[1:] if argv is None else [str(a) for a in argv])
    if odd is not None:
        print(f"whiskerbench {command}: error: {odd}", file=sys.stderr)
        return 2
    try:
        check_variant(getattr(args, "variant", None))
        return args.func(args)
    except (FieldError, FolderBusyError) as exc:  # busy: another run holds the output folder
        field = getattr(exc, "field", "out")
        option = {**OPTION_OF_FIELD, **DATASET_OPTION_OF_FIELD}.get(field, field)
        detail = " ".join(getattr(exc, "detail", str(exc)).split())  # one line, whatever it held
        print(f"whiskerbench {command}: error: {option}: {detail}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"whiskerbench {command}: interrupted: {args.kept}", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, not the input: say so, briefly
        if isinstance(exc, BrokenPipeError) and stdout_closed():
            raise  # not a bug: main ends quietly
        line = environment_failure(command, exc, args.kept)  # the system's, not a bug
        print(line or bug_report(command, exc), file=sys.stderr)
        too_long = isinstance(exc, OSError) and exc.errno == errno.ENAMETOOLONG  # a name given
        return 2 if line and too_long else 1


if __name__ == "__main__":
    sys.exit(main())

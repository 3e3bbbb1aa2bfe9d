"""Options of ``whiskerbench dataset`` and ``whiskerbench bench dataset``, and their commands."""

from __future__ import annotations

import argparse
import sys

from bench.cli import limits
from bench.cli.args import (
    check_executor,
    check_out_folder,
    distinct,
    integer,
    name_list,
    seed,
)
from bench.common.manifest import input_digests
from bench.dataset.config import (
    DEFAULT_BRANCHES,
    DEFAULT_DISTANCES,
    DEFAULT_FOLIAGE,
    DEFAULT_PROFILE,
    DEFAULT_PROTOCOLS,
    DatasetConfig,
    DatasetConfigError,
    array_of_family,
    branches_name,
)
from bench.study.config import profile_from_option
from renderers.frame_sampling import FrameSampling
from scenes.profile import profile_path

#: A few short samples: one foliage, one distance, no / one / two branches, one outdoor pass.
QUICK = {
    "foliage": ("soft",),
    "distances": ("intermediate",),
    "branches": ((), (0.0,), (0.0, 100.0)),
    "protocols": ("outdoor",),
    "passes": 1,
}
OPTION_OF_FIELD = {
    "foliage": "--foliage",
    "distances": "--distance",
    "branches": "--branches",
    "protocols": "--protocol",
    "lightings": "--lighting",
    "frames_step": "--frames-step",
    "speed_mm_s": "--speed",
    "amplitude_mm": "--amplitude",
    "passes": "--passes",
    "fps": "--fps",
    "exposure_ms": "--exposure-ms",
    "exposure": "--exposure",
    "camera": "--camera",
    "psf_scale": "--psf-scale",
    "marker_spp": "--spp",
    "subframes": "--subframes",
    "integrator": "--integrator",
    "path_depth": "--path-depth",
    "adaptive": "--adaptive",
    "workers": "--workers",
    "executor": "--executor",
    "scheduler": "--scheduler",
    "out": "--out",
    "seed": "--seed",
    "mechanics": "--mechanics",
    "foliage_detail": "--foliage-detail",
    "dataset_grid": "--foliage x --distance x --branches x --protocol x --lighting",
    "frames": "--frames",
    "family": "--family",
}


def _branch_sets(text: str) -> tuple[tuple[float, ...], ...]:
    """'none,0,50,0+100' -> ((), (0,), (50,), (0, 100)); each configuration once."""
    out = []
    for item in name_list("--branches")(text):
        if item == "none":
            out.append(())
            continue
        try:
            branches = distinct("--branches", [float(v) for v in item.split("+")], item)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--branches: {item!r} is not 'none' or mm positions joined by '+'"
            ) from None
        out.append(branches)
    keys = ["+".join(f"{x:g}" for x in sorted(b)) or "none" for b in out]  # 0+50 is 50+0
    distinct("--branches", keys, text)
    return tuple(out)


def add_dataset_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--foliage",
        type=name_list("--foliage"),
        help=f"foliage kinds (default {','.join(DEFAULT_FOLIAGE)}; also none)",
    )
    p.add_argument(
        "--distance",
        type=name_list("--distance"),
        help=f"sampling distances (default {','.join(DEFAULT_DISTANCES)})",
    )
    p.add_argument(
        "--branches",
        type=_branch_sets,
        help="branch configurations, mm along the array, '+' for pairs (default "
        f"{','.join(branches_name(b) for b in DEFAULT_BRANCHES)})",
    )
    p.add_argument(
        "--protocol",
        type=name_list("--protocol"),
        help=f"protocols (default {','.join(DEFAULT_PROTOCOLS)})",
    )
    p.add_argument(
        "--lighting",
        type=name_list("--lighting"),
        default=("sun",),
        help="lighting presets (default sun)",
    )
    p.add_argument(
        "--frames-step",
        type=integer,
        default=1,
        help="keep every k-th frame (the slow indoor protocol has ~1000 frames per sample)",
    )
    p.add_argument("--speed", type=float, help="whisking speed mm/s (default: the protocol's)")
    p.add_argument("--amplitude", type=float, help="whisking amplitude mm (default 50)")
    p.add_argument("--passes", type=integer, help="translations (default: the protocol's)")
    p.add_argument("--fps", type=float, help="frame rate (default 15)")
    p.add_argument(
        "--exposure-ms",
        type=float,
        help=f"exposure time: motion blur (default {DatasetConfig.exposure_ms:g})",
    )
    p.add_argument(
        "--camera",
        metavar="PROFILE",
        help=f"camera twin: a shipped profile name or a profile JSON file (default "
        f"{DEFAULT_PROFILE})",
    )
    p.add_argument(
        "--psf-scale",
        type=float,
        default=1.0,
        metavar="F",
        help="factor on the camera profile's PSF widths, in (0, 10]: one point of the profile's "
        "band per dataset (default 1, the table as calibrated)",
    )
    p.add_argument(
        "--exposure",
        type=float,
        default=1.0,
        help="radiance to sensor full scale, times the lighting preset's own (default 1)",
    )
    p.add_argument(
        "--spp", type=integer, default=4, help="samples per pixel where markers can be (default 4)"
    )
    p.add_argument(
        "--subframes", type=integer, default=4, help="time samples per exposure (default 4)"
    )
    p.add_argument(
        "--full-frame", action="store_true", help="render whole frames, not just the band"
    )
    p.add_argument(
        "--integrator",
        default="direct",
        help="light paths: direct (sun with shadows, unoccluded sky; default) or path (bounces "
        "with occluded sky)",
    )
    p.add_argument(
        "--path-depth",
        type=integer,
        default=3,
        help="bounces of --integrator path, 1..8 (default 3)",
    )
    p.add_argument(
        "--adaptive",
        action="store_true",
        help="each pixel's first sample, its others only near an edge (about 11%% less render "
        "time; within the reference's seed spread: docs/video_speed.md)",
    )
    p.add_argument(
        "--family",
        help="marker family of the array, one a detector decodes: 4x4_50, apriltag_36h11, "
        "apriltag_16h5, ... (OpenCV's dictionary names; default 4x4_50)",
    )
    p.add_argument("--seed", type=seed, default=0, help="random seed, 0..2**32-1 (default 0)")
    p.add_argument(
        "--foliage-detail",
        default="default",
        help="foliage mesh detail: coarse, default or fine (the shapes drawn; contacts stay)",
    )
    p.add_argument(
        "--mechanics",
        default="dynamic",
        help="whisker mechanics: dynamic (rings after a release; default) or quasi-static",
    )
    p.add_argument(
        "--variant",
        choices=("cuda_ad_rgb", "llvm_ad_rgb"),
        help="Mitsuba variant (default: the fastest that works here)",
    )
    p.add_argument("--quick", action="store_true", help="three short outdoor samples")


def dataset_config(args: argparse.Namespace) -> DatasetConfig:
    """The DatasetConfig the options describe (--quick fills what was not given); an exposure
    longer than a frame blames --fps when --exposure-ms was left at its default."""
    try:
        return _dataset_config(args)
    except DatasetConfigError as exc:
        if exc.field != "exposure_ms" or args.exposure_ms is not None or args.fps is None:
            raise
        default_ms = DatasetConfig.exposure_ms
        raise DatasetConfigError(
            "fps",
            f"{args.fps:g}: one frame lasts {1000.0 / args.fps:g} ms, shorter than the default "
            f"exposure of {default_ms:g} ms; allowed up to {1000.0 / default_ms:g} fps with it, "
            "or give a shorter --exposure-ms as well",
        ) from None


def _dataset_config(args: argparse.Namespace) -> DatasetConfig:
    quick = QUICK if args.quick else {}
    camera = {} if args.camera is None else {"camera": profile_from_option(args.camera)}
    array = {} if args.family is None else {"array": array_of_family(args.family)}
    sampling = FrameSampling(
        marker_spp=args.spp,
        subframes=args.subframes,
        full_frame=args.full_frame,
        integrator=args.integrator,
        path_depth=args.path_depth,
        adaptive=args.adaptive,
    )
    return DatasetConfig(
        foliage=args.foliage or quick.get("foliage", DEFAULT_FOLIAGE),
        distances=args.distance or quick.get("distances", DEFAULT_DISTANCES),
        branches=args.branches or quick.get("branches", DEFAULT_BRANCHES),
        protocols=args.protocol or quick.get("protocols", DEFAULT_PROTOCOLS),
        lightings=args.lighting,
        frames_step=args.frames_step,
        seed=args.seed,
        mechanics=args.mechanics,
        foliage_detail=args.foliage_detail,
        speed_mm_s=args.speed,
        amplitude_mm=args.amplitude,
        passes=args.passes if args.passes is not None else quick.get("passes"),
        fps=args.fps,
        **({} if args.exposure_ms is None else {"exposure_ms": args.exposure_ms}),
        exposure=args.exposure,
        psf_scale=args.psf_scale,
        sampling=sampling,
        **camera,
        **array,
    )


def cmd_dataset(args: argparse.Namespace) -> int:
    config = dataset_config(args)
    out = check_out_folder(args.out or ("data/quick" if args.quick else "data/default"))
    limits.check_dataset(config, args.workers)
    executor = check_executor(args.executor, args.scheduler, args.workers)
    args.kept = (
        f"finished samples are kept in {out}/<sample id>/ (each verified by its sample.json); "
        "rerun the same command to resume"
    )
    camera_file = profile_path(args.camera or DEFAULT_PROFILE)
    from bench.dataset.generate import run_dataset  # after the checks: a refusal stays quick

    manifest = run_dataset(
        config,
        out,
        args.variant,
        args.workers,
        inputs=input_digests([camera_file]),
        executor=executor,
        scheduler=args.scheduler,
    )
    rate = manifest["frames_per_s"]
    print(
        f"wrote {out}/ ({len(manifest['samples'])} samples, {manifest['skipped']} already done; "
        f"{manifest['frames_rendered']} frames in {manifest['wall_s']:.1f} s"
        + (f", {rate:.1f} frames/s" if rate else "")
        + f", variant {manifest['variant']}, camera {manifest['camera_profile']}"
        + ("" if config.psf_scale == 1 else f" at PSF scale {config.psf_scale:g}")
        + ")"
    )
    if manifest["units_redone"]:
        redone = manifest["units_redone"]
        print(f"damaged samples made again: {', '.join(redone)}", file=sys.stderr)
    groups = manifest["foliage_groups"]
    print(
        "samples sharing foliage (one layout each): "
        + ", ".join(f"{g} ({len(ids)})" for g, ids in groups.items())
    )
    if manifest["frames_rendered"]:
        per_frame = {
            k.removesuffix("_s"): f"{v / manifest['frames_rendered']:.3f} s"
            for k, v in manifest["stage_s"].items()
        }
        beside = {k: per_frame.pop(k) for k in ("optics", "sensor")}
        print(
            "per frame: "
            + ", ".join(f"{k} {v}" for k, v in per_frame.items())
            + "; in the twin's thread, beside the render: "
            + ", ".join(f"{k} {v}" for k, v in beside.items())
        )
    return 0


def add_bench_dataset_parser(bench_sub: argparse._SubParsersAction) -> None:
    """Register ``bench dataset`` on the ``bench`` subparsers."""
    bdata = bench_sub.add_parser(
        "dataset", help="frames/s of band and full-frame rendering, and their detections"
    )
    add_dataset_options(bdata)
    bdata.add_argument(
        "--frames", type=integer, default=30, help="frames timed per mode (default 30)"
    )
    bdata.add_argument(
        "--out", help="also write bench.json and a still frame (still.png) into this folder"
    )
    bdata.set_defaults(func=cmd_bench_dataset)


def cmd_bench_dataset(args: argparse.Namespace) -> int:
    from bench.benchmarks.dataset import bench_dataset

    config = dataset_config(args)
    if args.out is not None:
        check_out_folder(args.out)
    if args.frames < 1:
        raise DatasetConfigError("frames", f"{args.frames}: must be >= 1")
    lens = config.camera.lens
    limits.check_frames("frames", args.frames, lens.width_px, lens.height_px, "frames")
    limits.check_dataset(config)
    bench_dataset(config, frames=args.frames, variant=args.variant, out_dir=args.out)
    return 0

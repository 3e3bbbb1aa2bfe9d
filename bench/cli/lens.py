"""``whiskerbench lens measure``: options and command (bad input: one line, exit code 2)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.cli.args import integer
from bench.lens.measure import DEFAULT_BIN_DEG, DEFAULT_MAX_FRAMES

OPTION_OF_FIELD = {
    "dictionary": "--dictionary",
    "bin_deg": "--bin-deg",
    "max_frames": "--max-frames",
}


def add_lens_parser(subparsers: argparse._SubParsersAction, parser_class: type) -> None:
    """Register ``lens measure`` on the top-level subparsers."""
    lens = subparsers.add_parser("lens", help="measure a camera's optics from footage")
    lens_sub = lens.add_subparsers(dest="lens_command", required=True, parser_class=parser_class)
    p = lens_sub.add_parser(
        "measure",
        help="fit PSF widths (from ArUco marker edges), noise (still frames) and JPEG quality "
        "from footage; write a camera profile",
    )
    p.add_argument("footage", type=Path, help="video file, folder of images, or one image")
    p.add_argument(
        "--camera", required=True, help="camera profile to start from (shipped name or JSON file)"
    )
    p.add_argument("--out", type=Path, required=True, help="profile JSON to write")
    p.add_argument(
        "--report",
        type=Path,
        help="report JSON with per-bin numbers (default: <out stem>.report.json beside --out)",
    )
    p.add_argument("--dictionary", default="4x4_50", help="ArUco dictionary (default 4x4_50)")
    p.add_argument(
        "--bin-deg",
        type=float,
        default=DEFAULT_BIN_DEG,
        help=f"field-angle bin width in degrees (default {DEFAULT_BIN_DEG:g})",
    )
    p.add_argument(
        "--max-frames",
        type=integer,
        default=DEFAULT_MAX_FRAMES,
        help=f"read at most this many frames (default {DEFAULT_MAX_FRAMES})",
    )
    p.add_argument(
        "--still",
        action="store_true",
        help="every frame shows the same static scene (photon transfer over all of them); "
        "default: detect runs of still frames",
    )
    p.set_defaults(func=cmd_lens_measure)


def cmd_lens_measure(args: argparse.Namespace) -> int:
    from bench.cli.args import check_out_file
    from bench.common.atomic import write_json
    from bench.lens.measure import FootageError, measure_lens
    from scenes.profile import ProfileError, load_profile, profile_path
    from scenes.validation import FieldError

    def fail(message: str) -> int:
        print(f"whiskerbench lens measure: error: {message}", file=sys.stderr)
        return 2

    report_path = args.report or args.out.with_name(f"{args.out.stem}.report.json")
    if report_path.resolve() == args.out.resolve():
        return fail("--report: must differ from --out")
    try:
        profile = load_profile(args.camera)
    except ProfileError as exc:
        return fail(f"--camera: {exc.option_detail}")
    inputs = (args.footage, profile_path(args.camera))
    try:
        check_out_file(args.out, inputs=inputs)
        check_out_file(report_path, "report", inputs)
    except FieldError as exc:
        return fail(f"--{exc.field}: {exc.detail}")
    args.kept = "nothing was written (the profile and report are written at the end)"
    try:
        new_profile, report = measure_lens(
            args.footage,
            profile,
            dictionary=args.dictionary,
            bin_deg=args.bin_deg,
            max_frames=args.max_frames,
            still=args.still,
            progress=sys.stderr.isatty(),
        )
    except FieldError as exc:
        return fail(f"{OPTION_OF_FIELD.get(exc.field, exc.field)}: {exc.detail}")
    except FootageError as exc:
        return fail(str(exc))
    write_json(report_path, report)
    write_json(args.out, new_profile.to_json())
    print(_summary(args.out, report_path, report))
    return 0


def _summary(out: Path, report_path: Path, report: dict) -> str:
    bins = [b for b in report["psf_bins"] if "sigma_radial_px" in b]
    psf = ", ".join(
        f"{b['theta_mean_deg']:.0f} deg {b['sigma_radial_px']:.2f}/{b['sigma_tangential_px']:.2f}"
        for b in bins
    )
    noise = report["noise"]
    noise_text = (
        f"full well {noise['full_well_e']:.0f} e-, read noise {noise['read_noise_e']:.1f} e-"
        if "full_well_e" in noise
        else f"noise not measured ({noise.get('skipped', 'no fit')})"
    )
    if "not_applied" in noise:
        noise_text += f" (reported, not written to the profile: {noise['not_applied']})"
    stream = report["stream"]
    stream_text = (
        f"MJPEG quality {stream['quality']} ({stream['chroma_subsampling']})"
        if stream.get("codec") == "mjpeg"
        else "no JPEG frames: stream unchanged"
    )
    return (
        f"wrote {out} and {report_path}: {report['edges_used']} edges from "
        f"{report['frames_read']} frames; PSF radial/tangential px: {psf}; {noise_text}; "
        f"{stream_text}"
    )

"""``whiskerbench camera``: show a camera profile, project rays through it, import a calibration.

Bad input gets one line on stderr naming the option (or CAMERA / FILE) and the allowed range,
exit code 2, and nothing written.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from bench.cli.args import check_out_file, float_list, integer
from bench.cli.calibrate import add_calibrate_parser
from bench.cli.limits import check_memory
from bench.common.atomic import write_json
from scenes.calibration_import import FORMATS, CalibrationError, import_calibration
from scenes.camera import FisheyeCamera
from scenes.lens_models import PARAM_NAMES
from scenes.profile import CameraProfile, ProfileError, load_profile, shipped_profiles
from scenes.validation import FieldError

#: importer fields that are options of ``camera import``; any other field is in FILE
IMPORT_OPTION_OF_FIELD = {
    "camera_index": "--camera-index",
    "theta_max_deg": "--theta-max-deg",
    "format": "--format",
}


def add_camera_parser(subparsers, parser_class: type[argparse.ArgumentParser]) -> None:
    """Register ``camera show|project|import|calibrate``; each sets ``func`` (args -> exit code)."""
    camera = subparsers.add_parser("camera", help="show or import camera profiles, project rays")
    sub = camera.add_subparsers(dest="camera_command", required=True, parser_class=parser_class)
    where = f"a shipped profile ({', '.join(shipped_profiles()) or 'none yet'}) or a JSON file"
    show = sub.add_parser("show", help="summary: lens model, field of view, optics, sensor")
    show.add_argument("camera", metavar="CAMERA", help=where)
    show.set_defaults(func=cmd_camera_show)
    project = sub.add_parser("project", help="pixel positions of rays, as CSV on stdout")
    project.add_argument("camera", metavar="CAMERA", help=where)
    project.add_argument(
        "--theta-deg",
        required=True,
        type=float_list("--theta-deg"),
        metavar="DEG,...",
        help="ray angles from the optical axis, 0..theta_max of the camera",
    )
    project.add_argument(
        "--azimuth-deg",
        type=float_list("--azimuth-deg"),
        default=(0.0,),
        metavar="DEG,...",
        help="azimuths, -360..360; 0 is image right (+x), 90 image down (+y) (default 0)",
    )
    project.set_defaults(func=cmd_camera_project)
    imp = sub.add_parser("import", help="a profile JSON from a Kalibr/Basalt/OCamCalib/OpenCV file")
    imp.add_argument("file", metavar="FILE", help="the calibration file")
    imp.add_argument("--format", required=True, choices=FORMATS, help="the file's format")
    imp.add_argument(
        "--camera-index", type=integer, default=0, help="camera in the file (default 0)"
    )
    imp.add_argument(
        "--theta-max-deg",
        type=float,
        help="image-circle limit (default: the farthest image corner's angle, capped at the "
        "model's own valid limit)",
    )
    imp.add_argument("--out", required=True, help="profile JSON to write")
    imp.add_argument("--name", help="profile name (default: the --out file's stem)")
    imp.set_defaults(func=cmd_camera_import)
    add_calibrate_parser(sub, where)


def _fail(args: argparse.Namespace, option: str, detail: str) -> int:
    print(f"whiskerbench camera {args.camera_command}: error: {option}: {detail}", file=sys.stderr)
    return 2


def _profile(args: argparse.Namespace) -> CameraProfile | str:
    """The CAMERA profile, or the error line's detail."""
    try:
        return load_profile(args.camera)
    except ProfileError as exc:
        return exc.option_detail


# --- show -------------------------------------------------------------------------------------


def _values(value) -> str:
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_values(v) for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


def lens_lines(lens: FisheyeCamera) -> list[str]:
    """Summary lines of a lens: model, size, focal, principal point, limits, field of view."""
    names = PARAM_NAMES[lens.model] or tuple(f"a{i}" for i in range(len(lens.params)))
    params = " ".join(f"{n}={p:.9g}" for n, p in zip(names, lens.params, strict=True))
    d_max = float(lens.distort(lens.theta_max_rad))
    rx = d_max * math.hypot(lens.fx_px, lens.shear[0])
    ry = d_max * math.hypot(lens.shear[1], lens.fy_px)
    h, v, diag = lens.fov_in_image_deg()
    shear = f", shear {lens.shear[0]:.6g}, {lens.shear[1]:.6g} px" if any(lens.shear) else ""
    cv = lens.to_opencv()
    return [
        f"lens model: {lens.model}" + (f" ({params})" if params else ""),
        f"image size: {lens.width_px} x {lens.height_px} px",
        f"focal length: fx {lens.fx_px:.6g} px, fy {lens.fy_px:.6g} px{shear}",
        f"principal point: cx {lens.cx_px:.6g} px, cy {lens.cy_px:.6g} px",
        f"theta_max (image circle): {lens.theta_max_deg:.4f} deg; "
        f"model valid limit: {lens.theta_valid_max_deg:.4f} deg",
        f"field of view in the image: horizontal {h:.2f} deg, vertical {v:.2f} deg, "
        f"diagonal {diag:.2f} deg",
        f"image circle radius: {rx:.1f} px (x), {ry:.1f} px (y)",
        f"OpenCV fisheye form (K, D): max error {cv['fit_max_err_px']:.3g} px up to "
        f"{min(lens.theta_max_deg, 89.0):g} deg",
    ]


def cmd_camera_show(args: argparse.Namespace) -> int:
    profile = _profile(args)
    if isinstance(profile, str):
        return _fail(args, "CAMERA", profile)
    data = profile.to_json()
    lines = [f"profile: {profile.name}"]
    if profile.description:
        lines.append(f"description: {profile.description}")
    lines += lens_lines(profile.lens)
    for section, values in data.items():  # optics, sensor, processing, stream
        if isinstance(values, dict) and section not in ("lens", "sources"):
            lines.append(f"{section}: " + ", ".join(f"{k} {_values(v)}" for k, v in values.items()))
    lines += [f"source of {key}: {text}" for key, text in sorted(profile.sources.items())]
    print("\n".join(lines))
    return 0


# --- project ----------------------------------------------------------------------------------


def cmd_camera_project(args: argparse.Namespace) -> int:
    profile = _profile(args)
    if isinstance(profile, str):
        return _fail(args, "CAMERA", profile)
    lens = profile.lens
    for theta in args.theta_deg:
        if not (math.isfinite(theta) and 0.0 <= theta <= lens.theta_max_deg):
            return _fail(
                args,
                "--theta-deg",
                f"{theta:g}: allowed range is [0, {lens.theta_max_deg:g}] (the image circle)",
            )
    for azimuth in args.azimuth_deg:
        if not (math.isfinite(azimuth) and -360.0 <= azimuth <= 360.0):
            return _fail(args, "--azimuth-deg", f"{azimuth:g}: allowed range is [-360, 360]")
    rays = len(args.theta_deg) * len(args.azimuth_deg)
    try:  # one CSV line of about 50 characters (a 100-byte str) per ray, held until printed
        check_memory("theta_deg", rays, 100, f"{rays} rays (--theta-deg x --azimuth-deg)")
    except FieldError as exc:
        return _fail(args, "--theta-deg", exc.detail)
    lines = ["theta_deg,azimuth_deg,x_px,y_px"]
    for azimuth in args.azimuth_deg:
        for theta in args.theta_deg:
            t, a = math.radians(theta), math.radians(azimuth)
            ray = [math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)]
            x, y = lens.project(ray)
            lines.append(f"{theta:g},{azimuth:g},{x:.6f},{y:.6f}")
    print("\n".join(lines))
    return 0


# --- import -----------------------------------------------------------------------------------


def cmd_camera_import(args: argparse.Namespace) -> int:
    out = Path(args.out)
    name = args.name if args.name is not None else out.stem
    if not name:
        return _fail(args, "--name", "must be a non-empty string")
    try:
        check_out_file(out, inputs=(Path(args.file),))
    except FieldError as exc:
        return _fail(args, "--out", exc.detail)
    try:
        lens = import_calibration(args.file, args.format, args.camera_index, args.theta_max_deg)
    except CalibrationError as exc:
        option = IMPORT_OPTION_OF_FIELD.get(exc.field)
        return _fail(args, option, exc.detail) if option else _fail(args, "FILE", str(exc))
    source = (
        f"{args.format} calibration {args.file} (camera {args.camera_index}), "
        "imported by whiskerbench camera import"
    )
    profile = CameraProfile(
        name=name,
        description=f"lens from {args.file}; optics, sensor and stream are the ideal defaults",
        lens=lens,
        sources={"lens": source},
    )
    write_json(out, profile.to_json())
    print(f"wrote {out}")
    print("\n".join(lens_lines(lens)))
    return 0

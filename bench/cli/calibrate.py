"""``whiskerbench camera calibrate``: fit a profile's estimates to what the real sensor did;
``camera check``: how the twin fares against each observation across its band.

Bad input (the observations file, an option, a parameter the profile does not mark as an
estimate) gets one line naming it, exit 2, nothing written. An empty interval (observations that
contradict each other or the model) is reported with each observation's own interval, exit 1,
nothing written.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from bench.cli.args import check_out_file
from bench.common.atomic import write_json
from scenes.validation import FieldError

DEFAULT_OBSERVATIONS = "scenes/observations/prototype.json"


def add_calibrate_parser(sub, where: str) -> None:
    from bench.twin.calibrate import DEFAULT_F_NUMBER, DEFAULT_TOLERANCE, PARAMS

    cal = sub.add_parser(
        "calibrate",
        help="the interval of an estimate (PSF scale, ...) consistent with observations of the "
        "real sensor; writes a profile whose band is that interval",
    )
    cal.add_argument("camera", metavar="CAMERA", help=where)
    cal.add_argument(
        "--observations",
        required=True,
        help=f"observations JSON (format in docs/observations.md; shipped: {DEFAULT_OBSERVATIONS})",
    )
    cal.add_argument(
        "--param", default="psf_scale", choices=tuple(PARAMS), help="the estimate to calibrate"
    )
    cal.add_argument("--out", required=True, help="calibrated profile JSON to write")
    cal.add_argument(
        "--f-number",
        type=float,
        default=DEFAULT_F_NUMBER,
        help=f"lens f-number for the diffraction limit that closes the PSF scale from below, "
        f"1..32 (default {DEFAULT_F_NUMBER:g}: the fast end of small fisheyes' F/2-F/2.8)",
    )
    cal.add_argument(
        "--tolerance",
        type=float,
        default=DEFAULT_TOLERANCE,
        help="bisection stops when an edge is this close, 0.001..0.5 "
        f"(default {DEFAULT_TOLERANCE:g})",
    )
    cal.add_argument(
        "--no-assumptions",
        action="store_true",
        help="skip rerunning each assumption's alternatives (faster; the report omits them)",
    )
    cal.set_defaults(func=cmd_camera_calibrate)
    check = sub.add_parser(
        "check",
        help="each observation checked at the profile's band levels: agrees or not, and each "
        "unit's count (what calibrate bisects over)",
    )
    check.add_argument("camera", metavar="CAMERA", help=where)
    check.add_argument("--observations", required=True, help="observations JSON")
    check.set_defaults(func=cmd_camera_check)


def _fail(option: str, detail: str, code: int = 2) -> int:
    print(f"whiskerbench camera calibrate: error: {option}: {detail}", file=sys.stderr)
    return code


def report_path(out: Path) -> Path:
    """The calibration report written beside the profile: ``NAME.calibration.json``."""
    return out.with_name(f"{out.stem}.calibration.json")


def _show(interval: dict) -> str:
    if interval["empty"]:
        return "empty"
    low = f"{interval['low']:.3g}" + (" (search limit)" if interval["low_open"] else "")
    high = f"{interval['high']:.3g}" + (" (search limit)" if interval["high_open"] else "")
    return f"[{low}, {high}]"


def summary_lines(report: dict) -> list[str]:
    """What the console shows: each observation's interval, the intersection, the nominal,
    and how each assumption's alternatives move the intersection."""
    lines = [
        f"{report['param']}: search range [{report['search_range'][0]:.3g}, "
        f"{report['search_range'][1]:.3g}]; low end closed by {report['limits']['low']}, "
        f"high end by {report['limits']['high']}"
    ]
    for name, interval in report["per_observation"].items():
        notes = "; ".join(interval["notes"])
        lines.append(f"  {name}: {_show(interval)}" + (f" ({notes})" if notes else ""))
    lines.append(f"consistent with every observation: {_show(report['interval'])}")
    if report["nominal"] is not None:
        lines.append(f"nominal ({report['nominal_rule']}): {report['nominal']:.3g}")
    for moved in report["assumptions"]:
        lines.append(
            f"  if {moved['observation']}.{moved['field']} = {moved['alternative']} "
            f"(assumed {moved['assumed']}): that observation "
            f"{_show(moved['observation_interval'])}, all {_show(moved['interval'])}"
        )
    return lines


def _inputs(args: argparse.Namespace):
    """(profile, observations), or the exit code of the one-line refusal."""
    from scenes.observations import ObservationError, check_against_lens, load_observations
    from scenes.profile import ProfileError, load_profile

    try:
        profile = load_profile(args.camera)
    except ProfileError as exc:
        return _fail("CAMERA", exc.option_detail)
    try:
        observations = load_observations(args.observations)
        check_against_lens(observations, profile.lens)
    except ObservationError as exc:
        return _fail("--observations", str(exc))
    from bench.twin.run import detector_of

    for i, o in enumerate(observations.observations):
        try:
            detector_of(o.detector)
        except ValueError as exc:
            return _fail("--observations", f"observations[{i}].detector: {exc}")
    return profile, observations


def cmd_camera_check(args: argparse.Namespace) -> int:
    """Print, per observation and band level, whether the twin agrees and every unit's k/n."""
    inputs = _inputs(args)
    if isinstance(inputs, int):
        return inputs
    profile, observations = inputs
    from bench.twin.evidence import evidence_of
    from bench.twin.run import detector_of
    from renderers.variant import init_worker

    init_worker(None)
    disagree = 0
    for o in observations.observations:
        evidence = evidence_of(o, profile, detector_of(o.detector))
        for scale in profile.band.psf_levels():
            verdict = evidence.check(profile.with_psf_scale(scale), scale, o)
            counts = ", ".join(f"{u.label} {u.k}/{u.n}" for u in verdict.units)
            word = "agrees" if verdict.consistent else "DISAGREES"
            print(f"{o.id} at PSF scale {scale:g}: {word}: {counts}")
            disagree += scale == 1.0 and not verdict.consistent
    return 1 if disagree else 0


def cmd_camera_calibrate(args: argparse.Namespace) -> int:
    from bench.twin.calibrate import (
        CalibrationInputError,
        calibrated_profile,
        check_param,
        search_range,
    )

    out = Path(args.out)
    try:
        check_out_file(out)
        check_out_file(report_path(out))
    except FieldError as exc:
        return _fail("--out", exc.detail)
    if not (math.isfinite(args.f_number) and 1.0 <= args.f_number <= 32.0):
        return _fail("--f-number", f"{args.f_number:g}: allowed range is 1..32")
    if not (math.isfinite(args.tolerance) and 0.001 <= args.tolerance <= 0.5):
        return _fail("--tolerance", f"{args.tolerance:g}: allowed range is 0.001..0.5")
    inputs = _inputs(args)
    if isinstance(inputs, int):
        return inputs
    profile, observations = inputs
    from scenes.observations import observations_path
    from scenes.profile import profile_path

    files = (profile_path(args.camera), observations_path(args.observations))
    try:
        check_out_file(out, inputs=files)
    except FieldError as exc:
        return _fail("--out", exc.detail)
    try:
        search_range(profile, check_param(profile, args.param), args.f_number)
    except CalibrationInputError as exc:
        return _fail("--param", str(exc))
    return _run(args, profile, observations, out, calibrated_profile)


def _run(args, profile, observations, out: Path, calibrated_profile) -> int:
    from tqdm import tqdm

    from bench.twin.run import run_calibration

    with tqdm(desc="calibrate", unit=" step", disable=None, file=sys.stderr) as bar:

        def progress(text: str) -> None:
            bar.set_postfix_str(text)
            bar.update()

        result = run_calibration(
            profile,
            observations,
            args.param,
            args.f_number,
            args.tolerance,
            assumptions=not args.no_assumptions,
            progress=progress,
        )
    report = result.to_json()
    report["camera"] = profile.name
    report["observations_file"] = str(args.observations)
    print("\n".join(summary_lines(report)))
    if result.interval.empty:
        print(
            "no value is consistent with every observation: the observations contradict each "
            "other or the model (each observation's own interval is above); nothing written",
            file=sys.stderr,
        )
        return 1
    calibrated = calibrated_profile(profile, result, str(args.observations))
    calibrated = dataclasses.replace(calibrated, name=out.stem or profile.name)
    write_json(report_path(out), report)
    write_json(out, calibrated.to_json())
    print(f"wrote {out} (band psf_scale {list(calibrated.band.psf_scale)}) and {report_path(out)}")
    return 0

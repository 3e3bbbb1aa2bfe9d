"""``whiskerbench detect``: options and command (bad input: one line, exit code 2)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipeline.presets import PRESETS


def add_detect_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", type=Path, help="video file (synthetic or recorded)")
    p.add_argument("--camera", type=Path, required=True, help="camera.json (model or OpenCV form)")
    p.add_argument(
        "--pipeline", default="paper", choices=tuple(PRESETS), help="preset (default paper)"
    )
    p.add_argument(
        "--foliage-threshold",
        type=float,
        metavar="MM",
        help="maximum foliage deflection (from a no-branch sample); default: inferred online",
    )
    p.add_argument("--out", type=Path, help="output folder (default: <video>.<pipeline>/)")


def cmd_detect(args: argparse.Namespace) -> int:
    from bench.detect import run_detect
    from pipeline.presets import get_pipeline
    from scenes.camera import FisheyeCamera

    def fail(message: str) -> int:
        print(f"whiskerbench detect: error: {message}", file=sys.stderr)
        return 2

    if args.foliage_threshold is not None and not args.foliage_threshold >= 0:
        return fail(f"--foliage-threshold: {args.foliage_threshold}: must be >= 0 mm")
    try:
        camera = FisheyeCamera.from_dict(json.loads(args.camera.read_text()))
    except (OSError, ValueError) as exc:
        return fail(f"--camera: {args.camera}: {exc}")
    if not args.video.is_file():
        return fail(f"{args.video}: no such file")
    out = args.out or args.video.with_name(f"{args.video.stem}.{args.pipeline}")
    try:
        record = run_detect(
            args.video, camera, get_pipeline(args.pipeline), out, args.foliage_threshold
        )
    except ValueError as exc:  # unreadable or truncated video, no no-contact frames, ...
        return fail(f"{args.video}: {exc}")
    gaps = ", ".join(f"{b['gap'][0]}-{b['gap'][1]}" for b in record["branches"]) or "none"
    print(
        f"{record['frames']} frames at {record['frames_per_s']:.1f} frames/s; branches between "
        f"whiskers: {gaps} (threshold {record['threshold_mm']:.2f} mm, "
        f"{record['threshold_source']}); wrote {out}/"
    )
    if record["unseen_markers"]:
        print(
            f"warning: markers of whiskers {record['unseen_markers']} never seen", file=sys.stderr
        )
    return 0


def add_score_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="dataset folder (made by whiskerbench dataset)")
    p.add_argument(
        "--pipeline", default="paper", choices=tuple(PRESETS), help="preset (default paper)"
    )
    p.add_argument("--out", type=Path, help="output folder (default <dataset>/scores/<pipeline>)")


def cmd_score(args: argparse.Namespace) -> int:
    from bench.score import score_dataset
    from pipeline.presets import get_pipeline

    out = args.out or args.dataset / "scores" / args.pipeline
    try:
        table = score_dataset(args.dataset, get_pipeline(args.pipeline), out)
    except (ValueError, FileNotFoundError) as exc:
        print(f"whiskerbench score: error: {exc}", file=sys.stderr)
        return 2
    correct = (table["outcome"] == "correct").mean()
    print(
        f"{len(table)} samples: branch outcome correct in {correct:.0%}, marker recall "
        f"{table['recall'].mean():.3f}; wrote {out}/samples.csv and grid-*.png"
    )
    return 0

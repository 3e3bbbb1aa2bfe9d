"""``whiskerbench detect``: run a pipeline on one video, synthetic or recorded, same code path.

Writes ``detections.parquet`` (per frame and marker: corners, pose, the backend's own pose,
deflection, contact), ``branches.json`` (the estimates as gaps between whiskers, angles and mm
along the array; the frames the detector backend crashed on and why refinement fell back) and
``branches.png`` (SPEC 3's per-sample plot; true branches drawn when the video's ``sample.json``
is beside it).
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from bench.common.atomic import atomic_path, write_json  # noqa: E402
from bench.common.figures import (  # noqa: E402
    BLACK,
    BLUE,
    GREEN,
    SKY_BLUE,
    VERMILLION,
    legend_outside,
    save,
)
from bench.common.manifest import (  # noqa: E402
    RunClock,
    build_manifest,
    hash_files,
    sha256,
    write_manifest,
)
from bench.common.run_folder import claim, open_folder  # noqa: E402
from pipeline.branches import BranchEstimate, estimate_branches, online_threshold  # noqa: E402
from pipeline.presets import PipelineConfig  # noqa: E402
from pipeline.track import MarkerSet, pose_arrays, track  # noqa: E402
from scenes.array import ArraySpec  # noqa: E402
from scenes.bounded_read import read_json
from scenes.camera import FisheyeCamera  # noqa: E402
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH
from scenes.tables import DETECTIONS, ordered  # noqa: E402


def estimate(
    detections, n_frames: int, n_whiskers: int, config: PipelineConfig, threshold_mm: float | None
) -> tuple[BranchEstimate, str]:
    """Branch estimate from a detections table, and where its threshold came from."""
    R, t = pose_arrays(detections, n_frames, n_whiskers)
    kwargs = {"aggregation": config.aggregation, "baseline_frames": config.baseline_frames}
    if threshold_mm is not None:
        return estimate_branches(R, t, threshold_mm, **kwargs), "given"
    first = estimate_branches(R, t, math.inf, **kwargs)
    source = "online" if config.threshold == "online" else "online (no foliage threshold given)"
    return estimate_branches(R, t, online_threshold(first.deflection), **kwargs), source


def gap_positions(gaps: list[tuple[int, int]], array: ArraySpec) -> list[dict]:
    """Each gap as whisker pair, angle of its middle (deg) and arc length at the couplings (mm)."""
    psi = array.headings_rad
    out = []
    for i, j in gaps:
        mid = 0.5 * (psi[i] + psi[j])
        out.append(
            {
                "gap": [i, j],
                "angle_deg": math.degrees(mid),
                "arc_mm": array.frame_radius_mm * mid,
            }
        )
    return out


def run_detect(
    video: Path,
    camera: FisheyeCamera,
    config: PipelineConfig,
    out_dir: Path,
    threshold_mm: float | None = None,
    array: ArraySpec | None = None,
    video_sha256: str | None = None,
) -> dict:
    """Detect, estimate and write the outputs and ``manifest.json``; return branches.json's content.

    ``out_dir`` is claimed before any work (ValueError if another command's). The manifest
    records the video's SHA-256: ``video_sha256`` when the caller has just verified it (score),
    else hashed here.
    """
    from bench.common.video import read_video

    out_dir = Path(out_dir)
    clock = RunClock()
    claim(out_dir, "detect")
    array = array or ArraySpec()
    markers = MarkerSet(array.marker_ids, array.marker_size_mm)
    t0 = time.perf_counter()
    result = track(
        read_video(video), camera, markers, config.detector, config.search, config.pose_method
    )
    track_s = time.perf_counter() - t0
    truth = _truth_gaps(video)
    facts = {
        "video": str(video),
        "track_s": track_s,
        "frames_per_s": result.frames / track_s if track_s > 0 else None,
        "foreign_ids": result.foreign_ids,
        "pose_failures": result.pose_failures,
        "detector": config.detector.backend,
        "failed_frames": result.failed_frames,  # the backend crashed: no detections there
        "refine_failures": dict(result.refine_failures),
    }
    inputs = {str(video): video_sha256 or sha256(video)}
    if truth is not None:
        inputs[str(video.parent / "sample.json")] = sha256(video.parent / "sample.json")
    return write_estimate(
        out_dir, clock, result.detections, result.frames, camera, config, array, threshold_mm,
        truth, video.parent.name, facts, inputs,
    )  # fmt: skip


def write_estimate(
    out_dir: Path,
    clock: RunClock,
    tracked: pd.DataFrame,
    n_frames: int,
    camera: FisheyeCamera,
    config: PipelineConfig,
    array: ArraySpec,
    threshold_mm: float | None,
    truth: list[list[int]] | None,
    title: str,
    facts: dict,
    inputs: dict[str, str] | None = None,
) -> dict:
    """The stages after tracking, shared by a pipeline's detections and a results file's
    (:mod:`bench.evaluate.external`): deflection, contact and branches from the tracked table,
    then ``detections.parquet``, ``branches.json`` (``facts``: what the tracking adds) and
    ``branches.png`` and the manifest; returns branches.json's content."""
    est, source = estimate(tracked, n_frames, array.n_whiskers, config, threshold_mm)
    f, w = tracked["frame"].to_numpy(), tracked["whisker"].to_numpy()
    estimated = {"deflection_mm": est.deflection[f, w], "contact": est.contact[f, w]}
    with open_folder(out_dir, "detect"):  # claimed again, and locked while it is written
        table = pd.DataFrame(ordered(DETECTIONS, {**tracked.to_dict("series"), **estimated}))
        with atomic_path(out_dir / "detections.parquet") as tmp:
            table.to_parquet(tmp, index=False)
        record = {
            "pipeline": config.to_json(),
            "frames": n_frames,
            "threshold_mm": est.threshold_mm,
            "threshold_source": source,
            "branches": gap_positions(est.gaps, array),
            "peaks": est.peaks,
            "unseen_markers": est.unseen_markers,
            **facts,
            "true_gaps": truth,
        }
        write_json(out_dir / "branches.json", record)
        plot_estimate(est, out_dir / "branches.png", truth, title)
        config_record = {
            "pipeline": config.to_json(),
            "camera": dataclasses.asdict(camera),
            "array": array.to_json(),
            "threshold_mm": threshold_mm,
        }
        written = [out_dir / n for n in ("detections.parquet", "branches.json", "branches.png")]
        manifest = build_manifest(
            "detect", clock, config_record, inputs=inputs, outputs=hash_files(written, out_dir)
        )
        write_manifest(out_dir, manifest)
    return record


def _truth_gaps(video: Path) -> list[list[int]] | None:
    """The true gaps from the ``sample.json`` beside the video; None without one."""
    sample = video.parent / "sample.json"
    if not sample.exists():
        return None
    try:
        record = read_json(sample, RECORD_BYTES, RECORD_DEPTH)
    except ValueError as exc:
        raise ValueError(f"{sample}: not readable JSON ({exc})") from None
    return record.get("branch_gaps") if isinstance(record, dict) else None


def plot_estimate(
    est: BranchEstimate, path: Path, truth: list[list[int]] | None, title: str
) -> None:
    """SPEC 3's plot: max deflection in contact, the curve, threshold, peaks and estimates."""
    n = len(est.curve)
    x = np.arange(n)
    fig, ax = plt.subplots(figsize=(8, 3.6), layout="constrained")
    ax.bar(x, est.max_deflection, color=SKY_BLUE, label="max deflection in contact")
    ax.plot(x, est.curve, "o-", color=BLUE, label=f"{est.aggregation} (scaled)")
    ax.axhline(est.threshold_mm, color=BLACK, ls="--", label="threshold")
    if est.peaks:
        ax.plot(est.peaks, est.curve[est.peaks], "v", color=BLACK, ms=9, label="peaks")
    for k, (i, _) in enumerate(est.gaps):
        ax.axvline(i + 0.5, color=VERMILLION, lw=2, label="estimate" if k == 0 else None)
    for k, (i, _) in enumerate(truth or []):
        ax.axvline(i + 0.5, color=GREEN, ls=":", lw=2, label="true branch" if k == 0 else None)
    ax.set_xticks(x)
    ax.set_xlabel("whisker")
    ax.set_ylabel("mm")
    ax.set_title(title, fontsize=9)
    handles, labels = ax.get_legend_handles_labels()
    legend_outside(fig, handles, labels, fontsize=7)
    save(fig, path)

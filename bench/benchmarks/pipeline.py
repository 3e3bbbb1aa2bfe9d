"""``whiskerbench bench pipeline``: frames/s of each pipeline on full 2592 x 1944 frames, one core.

The frames are rendered whole (``full_frame``: vegetation in every pixel, not the dataset's black
outside the band), in time order around the largest deflection of a busy sample (foliage and a
branch), so ROI tracking sees real motion. OpenCV runs on one thread. Each pipeline's tracking
(detection and pose of every frame; the branch stages after it are a few ms per sample) is timed
as ``compare`` times a dataset's frames (:mod:`bench.evaluate.timing`, ``docs/speed.md``): the
first frame is the untimed lead-in, the pipelines alternate, ``rounds`` times, and frames/s is
the median over rounds with the slowest and fastest round beside it. Recall and corner
error on the same frames are printed beside each speed, so a fast pipeline that misses markers
or places corners badly shows it, and then who leads on each measure, the best peer detector
beside the best project pipeline (:mod:`bench.evaluate.leaders`, the wording of ``compare``'s
report). Peers run in their worker process; their frames/s include it.

The camera twin's lens blur is uncertain (its profile's band of PSF scales), so the same frames
are also recorded at the band's low and high ends (one render, the same noise: only the lens
differs) and each pipeline's recall and errors are given there too, untimed; who leads says
whether each accuracy lead holds at both ends (:mod:`bench.evaluate.band`).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import pandas as pd

from bench.common.atomic import write_json
from bench.common.manifest import RunClock, build_manifest, hash_files, write_manifest
from bench.common.run_folder import claim_out
from bench.dataset.config import DatasetConfig
from bench.evaluate.band import rows_band_values
from bench.evaluate.leaders import leader_lines, leaders
from bench.evaluate.score import score_markers
from bench.evaluate.speed import SPEED_SAMPLE, full_frames, full_run
from bench.evaluate.timing import (
    SPEED_ROUNDS,
    one_opencv_thread,
    speed_figures,
    speed_of,
    time_pipelines,
    track_run,
)
from pipeline.backends import BackendError, require
from pipeline.presets import PipelineConfig
from renderers.variant import init_worker

#: frames/s each preset should reach (the issue's targets); others have none.
TARGET_FPS = {"paper": 15.0, "fast": 100.0}
#: What is scored on the timed frames (:func:`bench.evaluate.score.score_markers`), where given.
MEASURES = (
    "recall", "corner_err_px", "rot_err_deg", "trans_err_mm", "own_rot_err_deg",
    "own_trans_err_mm",
)  # fmt: skip


def bench_pipeline(
    pipelines: list[PipelineConfig],
    config: DatasetConfig = SPEED_SAMPLE,
    frames: int = 30,
    rounds: int = SPEED_ROUNDS,
    variant: str | None = None,
    out: Path | None = None,
) -> dict:
    """Print and return frames/s (median over ``rounds``, slowest and fastest round), ratio
    to the first pipeline, recall and the errors
    (:data:`MEASURES`) per pipeline, the same errors at the camera band's ends
    (:func:`band_scales`), and who leads.

    A peer that is not installed is refused first
    (:class:`pipeline.backends.BackendUnavailableError`). With ``out``, also write
    ``bench.json`` and ``manifest.json`` there; the folder is claimed before any work
    (FieldError on ``out`` if another command's).
    """
    for backend in dict.fromkeys(b for p in pipelines for b in p.backends):
        require(backend)
    clock = RunClock()
    if out is not None:
        claim_out(out, "bench-pipeline")
    init_worker(variant)
    ends = band_scales(config)
    by_scale, labels = full_frames(config, frames, (1.0, *ends))
    images = by_scale[1.0]

    def measured(detections: pd.DataFrame) -> dict:
        scores = score_markers(detections, labels)
        return {k: float(scores[k]) for k in MEASURES if k in scores}

    run = full_run(config, images)
    timing = time_pipelines([run], {p.name: p for p in pipelines}, rounds)
    if timing.failed:  # a ratio needs every pipeline's speed: the failure stops the benchmark
        raise BackendError("; ".join(timing.failed.values()))
    speed = speed_figures(timing.rounds)
    rows, at_ends = [], {end: [] for end in ends}
    with one_opencv_thread():
        for pipeline in pipelines:
            detections = timing.detections[pipeline.name][0]
            rows.append(
                {
                    "pipeline": pipeline.name,
                    **speed_of(speed, pipeline.name),
                    **measured(detections),
                }
            )
            for end in ends:
                result = track_run(full_run(config, by_scale[end]), pipeline)
                at_ends[end].append({"pipeline": pipeline.name, **measured(result.detections)})
    base = rows[0]
    h, w = images[0].shape
    print(
        f"{run.timed_frames} frames of {w}x{h} px timed (after a lead-in frame), one core, "
        f"{rounds} rounds alternating; ratio against {base['pipeline']}"
    )
    for row in rows:
        row["ratio"] = row["fps"] / base["fps"]
        row["recall_pp_vs_base"] = 100 * (row["recall"] - base["recall"])
        target = TARGET_FPS.get(row["pipeline"])
        row["target_fps"] = target
        verdict = (
            ""
            if target is None
            else (f"  target {target:g}: {'met' if row['fps'] >= target else 'MISSED'}")
        )
        print(
            f"{row['pipeline']:>12}: {row['fps']:7.1f} frames/s "
            f"({row['fps_min']:.1f}-{row['fps_max']:.1f})  {row['ratio']:5.2f}x  "
            f"recall {row['recall']:.3f} ({row['recall_pp_vs_base']:+.1f} pp)  "
            f"corner error {row['corner_err_px']:.3f} px{verdict}"
        )
    if ends:
        print(
            f"the same frames at the camera band's ends (PSF scale "
            f"{' and '.join(f'{e:g}' for e in ends)} times the table; untimed):"
        )
        for k, row in enumerate(rows):
            print(
                f"{row['pipeline']:>12}: "
                + "; ".join(
                    f"PSF {end:g}: recall {at_ends[end][k]['recall']:.3f}, corner error "
                    f"{at_ends[end][k]['corner_err_px']:.3f} px"
                    for end in ends
                )
            )
    leads = leaders(pd.DataFrame(rows), band=rows_band_values(at_ends) if ends else None)
    print("who leads:")
    for line in leader_lines(leads):
        print(f"  {line}")
    figures = {
        "frames": len(images),
        "timed_frames": run.timed_frames,
        "rounds": rounds,
        "frame_px": [w, h],
        "cpu_count": os.cpu_count(),
        "opencv": cv2.__version__,
        "pipelines": rows,
        # the accuracy at each band end, untimed: {"0.5": [{"pipeline": ..., "recall": ...}]}
        "band_ends": {f"{end:g}": at_ends[end] for end in ends},
        "leaders": leads.to_dict("records"),
    }
    if out is not None:
        write_json(Path(out) / "bench.json", figures)
        config_record = {
            "pipelines": [p.to_json() for p in pipelines],
            "frames": frames,
            "rounds": rounds,
            "sample": config.to_json(),
        }
        record = build_manifest(
            "bench-pipeline",
            clock,
            config_record,
            seed=config.seed,
            outputs=hash_files([Path(out) / "bench.json"], Path(out)),
        )
        write_manifest(Path(out), record)
        print(f"wrote {out}/bench.json")
    return figures


def band_scales(config: DatasetConfig) -> tuple[float, ...]:
    """The PSF scales of the camera band's ends (times the table as calibrated) other than the
    nominal 1: none for a profile without a band."""
    return tuple(e for e in dict.fromkeys(config.twin.band.psf_ends) if e != 1.0)

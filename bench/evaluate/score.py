"""Scoring a pipeline's output against a sample's labels: per marker and frame, and per sample.

Marker level (detections joined with labels on frame and marker id): recall over visible
markers, false detections (ids not on the array, or a marker reported where the labels say it is
not visible), corner error (px, mean of the 4 corners), pose error (rotation deg, translation
mm) of the project's pose and, beside it, of the detector backend's own pose (``own_``; NaN for
a backend without one), deflection error (mm), contact precision and recall.

A dataset rendered with another marker family (its array's ``dictionary``) is scored with each
pipeline's detector set to that family; a pipeline whose backend cannot detect it is refused in
one line before any work. Frames on which the backend crashed (no detections there) are counted
per sample (``failed_frames``, their indices in ``failed_frame_ids``).

Sample level: each true branch is *found* when an estimated gap starts within one whisker of its
true gap; an estimate within one gap of no true branch is a false positive. The outcome is
``correct`` (all found, no false positive), else ``false_positive`` and/or ``false_negative``.
"""

from __future__ import annotations

import json
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common.atomic import atomic_path
from bench.common.executor import TaskPool  # noqa: E402
from bench.common.manifest import (  # noqa: E402
    RunClock,
    build_manifest,
    hash_files,
    json_sha256,
    read_manifest,
    write_manifest,
)
from bench.common.run_folder import claim, open_folder  # noqa: E402
from bench.dataset.verify import VerifiedDataset, verify_dataset  # noqa: E402
from bench.evaluate.results_file import ExternalDetections, frames_per_s  # noqa: E402
from bench.evaluate.score_units import check_own_samples, reused_row, run_units, seal_row
from pipeline.presets import PipelineConfig  # noqa: E402
from scenes.array import ArraySpec  # noqa: E402
from scenes.marker import check_dictionary  # noqa: E402
from scenes.tables import (  # noqa: E402
    DETECTIONS,
    JOIN_KEY,
    OWN_POSE_PREFIX,
    TRUTH_SUFFIX,
    check_table,
    corners_of,
    rotations_of,
    translations_of,
)


def branch_outcome(
    estimated: list[tuple[int, int]] | list[list[int]],
    true: list[tuple[int, int]] | list[list[int]],
) -> dict:
    """{outcome, found, missed, false_positives} for estimated vs true gaps (i, i + 1)."""
    est = [int(g[0]) for g in estimated]
    tru = [int(g[0]) for g in true]
    found = sum(any(abs(e - t) <= 1 for e in est) for t in tru)
    false_pos = sum(not any(abs(e - t) <= 1 for t in tru) for e in est)
    missed = len(tru) - found
    parts = [name for name, n in (("false_positive", false_pos), ("false_negative", missed)) if n]
    return {
        "outcome": "+".join(parts) or "correct",
        "found": found,
        "missed": missed,
        "false_positives": false_pos,
    }


def score_markers(detections: pd.DataFrame, labels: pd.DataFrame, foreign_ids: int = 0) -> dict:
    """Marker-level accuracy of one sample (see the module docstring)."""
    joined = detections.merge(labels, on=list(JOIN_KEY), suffixes=("", TRUTH_SUFFIX))
    visible = labels["visible"].to_numpy(bool)
    matched = joined[joined["visible"]]
    corner_err = np.linalg.norm(
        corners_of(matched) - corners_of(matched, TRUTH_SUFFIX), axis=-1
    ).mean(axis=1)
    out = {
        "markers_visible": int(visible.sum()),
        "markers_found": len(matched),
        "recall": len(matched) / visible.sum() if visible.any() else float("nan"),
        "false_detections": int(foreign_ids + (~joined["visible"]).sum()),
        "corner_err_px": finite_median(corner_err),
        **_pose_errors(matched, ""),
        **_pose_errors(matched, OWN_POSE_PREFIX),  # NaN where the backend has no pose
    }
    if "deflection_mm" in detections:  # a tracking-only table has no deflection to score
        out["deflection_err_mm"] = finite_median(
            np.abs(matched["deflection_mm"] - matched["deflection_mm" + TRUTH_SUFFIX])
        )
        out.update(_precision_recall(matched["contact"], matched["contact" + TRUTH_SUFFIX]))
    return out


def _pose_errors(matched: pd.DataFrame, prefix: str) -> dict:
    """Median rotation (deg) and translation (mm) errors of the pose columns named by
    ``prefix`` against the truth, as ``{prefix}rot_err_deg`` and ``{prefix}trans_err_mm``."""
    truth_R = rotations_of(matched, TRUTH_SUFFIX)
    cos = (np.einsum("nij,nij->n", rotations_of(matched, prefix=prefix), truth_R) - 1) / 2
    moved = translations_of(matched, prefix=prefix) - translations_of(matched, TRUTH_SUFFIX)
    return {
        f"{prefix}rot_err_deg": finite_median(np.degrees(np.arccos(np.clip(cos, -1, 1)))),
        f"{prefix}trans_err_mm": finite_median(np.linalg.norm(moved, axis=1)),
    }


def finite_median(values) -> float:
    """The median of the finite values (NaN where there are none)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else float("nan")


def _precision_recall(predicted: pd.Series, truth: pd.Series) -> dict:
    p, t = predicted.to_numpy(bool), truth.to_numpy(bool)
    tp = int((p & t).sum())
    return {
        "contact_precision": tp / p.sum() if p.any() else float("nan"),
        "contact_recall": tp / t.sum() if t.any() else float("nan"),
    }


# -- a whole dataset ------------------------------------------------------------------------


def dataset_family(dataset: Path) -> str | None:
    """The marker family the dataset's array was rendered with (its manifest's config); None
    without a readable dataset manifest (:func:`verify_dataset` then says what is wrong)."""
    config = (read_manifest(dataset) or {}).get("config")
    try:
        return check_dictionary(config["array"]["dictionary"])
    except (KeyError, TypeError):
        return None


def dataset_psf_scale(dataset: Path) -> float:
    """The PSF scale the dataset's frames were recorded at (its manifest's config; 1 where the
    config has none: the table as calibrated, and every dataset made before the option)."""
    config = (read_manifest(dataset) or {}).get("config") or {}
    return float(config.get("psf_scale", 1.0))


def for_family(config: PipelineConfig, family: str | None) -> PipelineConfig:
    """``config`` with its detector set to the marker ``family`` (None: unchanged); ValueError
    in one line when its backend cannot detect that family."""
    if family is None or family == config.detector.dictionary:
        return config
    try:
        return config.with_family(family)
    except ValueError as exc:
        raise ValueError(f"pipeline {config.name}: {exc}") from None


def _array(record: dict) -> ArraySpec | None:
    """The array a sample was rendered with (its ``sample.json``); None in an old one."""
    if "array" not in record:
        return None
    return ArraySpec(**{**record["array"], "marker_ids": tuple(record["array"]["marker_ids"])})


#: ``threshold_source`` of a sample whose twin shares its foliage layout, and of one from a
#: dataset made before layouts were shared (its twin is other foliage of the same kind).
SAME_LAYOUT_TWIN = "none-sample twin"
OTHER_LAYOUT_TWIN = "none-sample twin (other layout)"


def _none_twin(record: dict, records: dict[str, dict]) -> tuple[str | None, str]:
    """(id, threshold source) of the no-branch sample of the same foliage, distance, protocol
    and lighting; no id where there is none, or where it records another foliage layout."""
    parts = record["sample_id"].split("-")
    if len(parts) < 3:  # not an id the dataset command makes: no twin
        return None, ""
    parts[2] = "none"
    twin = records.get("-".join(parts))
    if twin is None:
        return None, ""
    groups = (record.get("foliage_group"), twin.get("foliage_group"))
    if None in groups:
        return twin["sample_id"], OTHER_LAYOUT_TWIN
    return (twin["sample_id"], SAME_LAYOUT_TWIN) if groups[0] == groups[1] else (None, "")


#: The columns of ``samples.csv`` that only a scored sample fills (a refused one has
#: ``refused_reason`` instead). A table gets every one, NaN where no sample filled it, so a
#: pipeline that refuses every sample still has a table its readers (``score``'s summary line,
#: ``compare``) can read.
SCORED_COLUMNS = (
    "threshold_mm", "threshold_source", "estimated_gaps", "unseen_markers",
    "found", "missed", "false_positives",
    "markers_visible", "markers_found", "recall", "false_detections",
    "corner_err_px", "rot_err_deg", "trans_err_mm", "own_rot_err_deg", "own_trans_err_mm",
    "deflection_err_mm", "contact_precision", "contact_recall",
    "frames_per_s", "failed_frames", "failed_frame_ids", "refine_failures",
)  # fmt: skip


@dataclass(frozen=True)
class _SampleTask:
    """One sample to detect on and score (an executor task: picklable, idempotent)."""

    folder: Path
    record: dict
    config: PipelineConfig
    out_dir: Path
    threshold: float | None
    threshold_source: str  # where ``threshold`` came from (when it is not None)
    video_sha256: str
    external: pd.DataFrame | None = None  # another tool's detections: no detector runs
    frames_per_s: float | None = None  # theirs (None: accuracy only)


def sample_columns(record: dict) -> dict:
    """The columns of ``samples.csv`` that say what a sample is (from its ``sample.json``)."""
    return {
        "sample_id": record["sample_id"],
        "foliage": record["foliage"],
        "distance": record["distance"],
        "branches": "+".join(f"{b:g}" for b in record["branches_mm"]) or "none",
        "protocol": record["protocol"]["name"],
        "lighting": record["lighting"],
        "foliage_group": record.get("foliage_group", ""),
        "true_gaps": json.dumps(record["branch_gaps"]),
    }


def _score_sample(task: _SampleTask, _context: None) -> tuple[dict, float | None]:
    """The sample's row of ``samples.csv``, and its foliage threshold if it has no branch."""
    from bench.evaluate.detect import run_detect
    from bench.evaluate.external import run_external
    from pipeline.branches import foliage_threshold
    from pipeline.deflection import NoBaselineError
    from scenes.profile import load_profile

    record, folder = task.record, task.folder
    labels = pd.read_parquet(folder / "labels.parquet")  # fits the sample: verify_dataset
    n_frames = record["frames"]  # the video's too (verify_dataset)
    camera = load_profile(folder / "camera.json").lens  # a profile, or an old bare camera
    common = sample_columns(record)
    out = task.out_dir / record["sample_id"]
    try:
        if task.external is None:
            result = run_detect(
                folder / "video.mp4",
                camera,
                task.config,
                out,
                task.threshold,
                array=_array(record),
                video_sha256=task.video_sha256,
            )
        else:  # the stages after detection on another tool's detections
            result = run_external(
                task.external, camera, task.config, out, n_frames, task.threshold,
                _array(record), task.frames_per_s, record["branch_gaps"],
            )  # fmt: skip
    except NoBaselineError as exc:  # flagged and reported, never scored as an answer
        return {**common, "outcome": "refused", "refused_reason": str(exc)}, None
    detections = pd.read_parquet(out / "detections.parquet")
    check_table(detections, DETECTIONS, out / "detections.parquet")
    threshold = None
    if not record["branches_mm"]:
        threshold = foliage_threshold(detections["deflection_mm"].to_numpy())
    estimated = [b["gap"] for b in result["branches"]]
    row = {
        **common,
        "threshold_mm": result["threshold_mm"],
        "threshold_source": task.threshold_source
        if task.threshold is not None
        else result["threshold_source"],
        "estimated_gaps": json.dumps(estimated),
        "unseen_markers": json.dumps(result["unseen_markers"]),
        **branch_outcome(estimated, record["branch_gaps"]),
        **score_markers(detections, labels, result["foreign_ids"]),
        "frames_per_s": result["frames_per_s"],
        "failed_frames": len(result["failed_frames"]),  # the backend crashed on them
        "failed_frame_ids": json.dumps(result["failed_frames"]),
        "refine_failures": sum(result["refine_failures"].values()),
    }
    return row, threshold


def score_dataset(
    dataset: Path,
    config: PipelineConfig,
    out_dir: Path,
    verified: VerifiedDataset | None = None,
    workers: int = 1,
    executor: str = "pool",
    scheduler: str | None = None,
    pool: TaskPool | None = None,
    external: ExternalDetections | None = None,
    fps: float | None = None,
) -> pd.DataFrame:
    """Run ``config`` on every sample and score it; write ``samples.csv`` and the grids.

    A sample the pipeline refuses (no no-contact frames at its start) gets the outcome
    ``refused`` and its reason, not scores (NaN in :data:`SCORED_COLUMNS`). The fixed foliage
    threshold of a sample is the highest deflection that the same pipeline measures on its
    no-branch twin (SPEC 3 step 4); without a twin, or for an ``online`` pipeline, it is
    inferred from the sample itself (column ``threshold_source``).

    The detector is set to the dataset's marker family (:func:`for_family`: a backend that
    cannot detect it is refused). Before any work ``out_dir`` is claimed (ValueError if another
    command's or another run's: it stays locked for the run) and every sample's file checked
    against its SHA-256 (DatasetIntegrityError naming the file), unless ``verified`` says it
    was, in this command; ``manifest.json`` is written last. With ``external`` (another
    tool's detections, validated) no detector runs: ``config``'s stages after detection run on
    them (no family check), frames/s is ``fps`` or the file's times, else NaN (accuracy only;
    the grids say so). The samples are tasks on ``executor``
    (:class:`~bench.common.executor.TaskPool`), or on ``pool`` when the caller keeps one for
    several pipelines (``compare``): the no-branch twins first, then the others with their
    twins' thresholds.
    """

    if not isinstance(config, PipelineConfig):  # e.g. the name "fast" from a script
        raise TypeError(
            f"config: {config!r} is a {type(config).__name__}, not a PipelineConfig; "
            "get_pipeline(name) makes one"
        )
    dataset, out_dir = Path(dataset), Path(out_dir)
    if external is None:
        config = for_family(config, dataset_family(dataset))  # refused here, before any work
    clock = RunClock()
    claim(out_dir, "score")  # reads only: refused before the dataset is hashed
    verified = verified or verify_dataset(dataset)
    records = verified.records
    settings = {"pipeline": config.to_json(), "dataset": str(dataset)}
    if external is not None:
        settings["results"] = {"source": str(external.source), "fps": fps}
    settings_sha256 = json_sha256(settings)
    check_own_samples(out_dir, records)  # refused before anything is written
    units = run_units(settings_sha256, config, external is not None)
    with open_folder(out_dir, "score", ("", *records), settings_sha256):
        thresholds: dict[str, float] = {}
        rows, reused = [], []
        # the caller's pool stays open for its next use; without one, this call's own
        own = TaskPool(workers, executor=executor, scheduler=scheduler) if pool is None else None
        with nullcontext(pool) if own is None else own as pool:
            ran_on = pool.describe()
            for twins in (True, False):  # a sample's threshold is its twin's: twins first
                tasks, done = {}, {}
                for sample_id, record in sorted(records.items()):
                    if (record["branches_mm"] == []) != twins:
                        continue
                    twin, source = _none_twin(record, records)
                    fixed = config.threshold == "fixed" and twin is not None
                    task = _SampleTask(
                        dataset / sample_id,
                        record,
                        config,
                        out_dir,
                        thresholds.get(twin) if fixed else None,
                        source,
                        verified.digests[f"{sample_id}/video.mp4"],
                        *_external_of(external, sample_id, fps),
                    )
                    found = reused_row(out_dir, units, task) if units else None
                    if found:
                        done[sample_id] = found
                        reused.append(sample_id)
                    else:
                        tasks[sample_id] = task
                desc = f"score {config.name}" + ("" if twins else " (branches)")
                for row, threshold in pool.map(
                    _score_sample, list(tasks.values()), desc=desc, unit="sample"
                ):
                    sample_id = row["sample_id"]
                    if units:  # sealed, and read back as a rerun will read it
                        row, threshold = seal_row(out_dir, units, tasks[sample_id], row, threshold)
                    done[sample_id] = row, threshold
                for sample_id, (row, threshold) in sorted(done.items()):
                    rows.append(row)
                    if threshold is not None:
                        thresholds[sample_id] = threshold
        table = pd.DataFrame(rows).sort_values("sample_id").reset_index(drop=True)
        table = table.reindex(columns=[*table, *(c for c in SCORED_COLUMNS if c not in table)])
        with atomic_path(out_dir / "samples.csv") as tmp:
            table.to_csv(tmp, index=False)
        # pyplot loaded here, not in the pool's workers, which import this module for
        # _score_sample and draw nothing: 0.2-0.3 s a worker
        from bench.evaluate.grid_plot import plot_grid

        untimed = external is not None and table["frames_per_s"].isna().all()
        for (protocol, lighting), part in table.groupby(["protocol", "lighting"]):
            plot_grid(
                part,
                out_dir / f"grid-{protocol}-{lighting}.png",
                f"{config.name}: {protocol}, {lighting}" + (" (accuracy only)" if untimed else ""),
            )
        written = [out_dir / "samples.csv", *out_dir.glob("grid-*.png")]
        inputs = verified.inputs()
        if external is not None:
            settings["results"]["timed"] = not untimed
            inputs.update(external.files)
        record = build_manifest(
            "score",
            clock,
            settings,
            inputs=inputs,
            outputs=hash_files(written, out_dir),
            **ran_on,
            units=sorted(records),  # a sample's folder of detections each
            settings_sha256=settings_sha256,
            reused=sorted(reused),  # scored by an earlier run (bench.evaluate.score_units)
        )
        write_manifest(out_dir, record)
        table.attrs["reused"] = sorted(reused)
        return table


def _external_of(
    external: ExternalDetections | None, sample_id: str, fps: float | None
) -> tuple[pd.DataFrame | None, float | None]:
    """A sample's rows of another tool's detections and their frames/s (None, None: none)."""
    if external is None:
        return None, None
    rows = external.tables[sample_id]
    return rows, frames_per_s(rows, fps)

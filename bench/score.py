"""Scoring a pipeline's output against a sample's labels: per marker and frame, and per sample.

Marker level (detections joined with labels on frame and marker id): recall over visible
markers, false detections (ids not on the array, or a marker reported where the labels say it is
not visible), corner error (px, mean of the 4 corners), pose error (rotation deg, translation
mm), deflection error (mm), contact precision and recall.

Sample level: each true branch is *found* when an estimated gap starts within one whisker of its
true gap; an estimate within one gap of no true branch is a false positive. The outcome is
``correct`` (all found, no false positive), else ``false_positive`` and/or ``false_negative``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

CORNERS = [(f"c{k}_x_px", f"c{k}_y_px") for k in range(4)]


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
    joined = detections.merge(labels, on=["frame", "marker_id"], suffixes=("", "_gt"))
    visible = labels["visible"].to_numpy(bool)
    matched = joined[joined["visible"]]
    corner_err = np.mean(
        [
            np.hypot(matched[x] - matched[f"{x}_gt"], matched[y] - matched[f"{y}_gt"])
            for x, y in CORNERS
        ],
        axis=0,
    )
    R = matched[[f"R_CM_{i}{j}" for i in range(3) for j in range(3)]].to_numpy().reshape(-1, 3, 3)
    R_gt = matched[[f"R_CM_{i}{j}_gt" for i in range(3) for j in range(3)]].to_numpy()
    cos = (np.einsum("nij,nij->n", R, R_gt.reshape(-1, 3, 3)) - 1) / 2
    rot_err = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    trans_err = np.linalg.norm(
        matched[[f"t_CM_{a}_mm" for a in "xyz"]].to_numpy()
        - matched[[f"t_CM_{a}_mm_gt" for a in "xyz"]].to_numpy(),
        axis=1,
    )
    out = {
        "markers_visible": int(visible.sum()),
        "markers_found": len(matched),
        "recall": len(matched) / visible.sum() if visible.any() else float("nan"),
        "false_detections": int(foreign_ids + (~joined["visible"]).sum()),
        "corner_err_px": _median(corner_err),
        "rot_err_deg": _median(rot_err),
        "trans_err_mm": _median(trans_err),
    }
    if "deflection_mm" in matched:
        out["deflection_err_mm"] = _median(
            np.abs(matched["deflection_mm"] - matched["deflection_mm_gt"])
        )
        out.update(_precision_recall(matched["contact"], matched["contact_gt"]))
    return out


def _median(values) -> float:
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

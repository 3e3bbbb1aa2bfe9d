"""What a low marker recall or a refused sample means, and where to look: the lines under the
console summaries of ``score`` and ``compare``. A first-time user reads the console before the
docs; a recall of 0.3 or a grey grid cell says nothing on its own."""

from __future__ import annotations

import math
from pathlib import Path

#: Below this marker recall the console explains it: the detector missed most visible markers.
LOW_RECALL = 0.5
#: Where the meaning is written down (a heading of docs/pipelines.md, checked by test_readme).
#: The per-sample table of a scored method, in its output folder.
CSV = "samples.csv"
DOCS = "docs/pipelines.md#reading-a-low-recall-or-a-refused-sample"


def summary_hints(
    name: str, recall: float, refused: int, samples: int, samples_csv: Path
) -> list[str]:
    """The note lines for one scored method: none when recall >= LOW_RECALL and nothing was
    refused. ``recall`` is over the samples scored (NaN when every one was refused)."""
    hints = []
    if refused:
        hints.append(
            f"note: {name} refused {refused} of {samples} samples: no no-contact pose to measure "
            "deflections from (the markers moved within their first sightings, or were never "
            "seen), so no answer "
            f"rather than a wrong one; why, per sample: refused_reason in {samples_csv} ({DOCS})"
        )
    if not math.isnan(recall) and recall < LOW_RECALL:
        hints.append(
            f"note: {name} read only {recall:.0%} of the visible markers (lens blur, tilt, "
            f"lighting or motion); per sample: recall, markers_found in {samples_csv}, per "
            f"frame: {samples_csv.parent}/<sample id>/detections.parquet ({DOCS})"
        )
    return hints

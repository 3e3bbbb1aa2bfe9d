"""The console's notes under score's and compare's summaries: what a low recall or a refused
sample means and which file says more; silent when there is nothing to explain."""

import math
from pathlib import Path

import pytest

from bench.cli.hints import DOCS, LOW_RECALL, summary_hints

ROOT = Path(__file__).resolve().parents[1]
CSV = Path("data/quick/scores/paper/samples.csv")


def test_nothing_to_explain_prints_nothing():
    assert summary_hints("paper", 0.99, 0, 3, CSV) == []
    assert summary_hints("paper", LOW_RECALL, 0, 3, CSV) == []


def test_a_refused_sample_says_why_and_where():
    (line,) = summary_hints("naive", 0.99, 2, 24, CSV)
    assert line.startswith("note: naive refused 2 of 24 samples: no no-contact pose")
    assert f"refused_reason in {CSV}" in line and DOCS in line


@pytest.mark.parametrize("refused", [0, 3])
def test_a_low_recall_points_at_the_tables(refused):
    lines = summary_hints("paper", 0.31, refused, 3, CSV)
    assert len(lines) == 1 + bool(refused)
    assert "read only 31% of the visible markers" in lines[-1]
    assert f"{CSV.parent}/<sample id>/detections.parquet" in lines[-1]


def test_every_sample_refused_has_no_recall_note():
    (line,) = summary_hints("naive", math.nan, 3, 3, CSV)
    assert "refused 3 of 3" in line


def test_the_docs_section_exists():
    from test_readme import anchors

    page, anchor = DOCS.split("#")
    assert anchor in anchors(ROOT / page)

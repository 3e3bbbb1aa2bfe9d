"""Corner refinements on the real photographs (``tests/data/real_markers``): ``lines`` from each
detector's corners, under both transfer curves, beside OpenCV's ``subpix``, locus' and
AprilTag 3's own corners, against the detectors' consensus (:mod:`bench.evaluate.photos`).

Run: ``python -m bench.benchmarks.refine_photos`` (about 10 s; the peers need the ``peers``
extra). Prints one line per method: markers, fallback rate and reasons, median distance of the
input and output corners to the consensus, markers with a corner moved further from it than
its input by more than ``WORSE_PX`` without a reported failure, and the mean signed outward
offset on large markers. locus and AprilTag are themselves among the references: their
distances are not independent of the consensus.
"""

from __future__ import annotations

from bench.evaluate.photos import (
    LARGE_SIDE_PX,
    WORSE_PX,
    Figures,
    figures,
    measure,
)
from pipeline.backends import available

#: (label, method, start, transfer)
RUNS = (
    *(
        (f"lines from {start}, {curve}", "lines", start, curve)
        for start in ("opencv", "locus", "apriltag")
        for curve in ("auto", "srgb", "linear")
    ),
    ("opencv subpix", "subpix", "opencv", "auto"),
    ("locus (own corners)", "locus", "locus", "auto"),
    ("apriltag (own corners)", "apriltag", "apriltag", "auto"),
)


def line(label: str, f: Figures) -> str:
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(f.reasons.items())) or "-"
    return (
        f"{label:28s} {f.markers:3d} {f.fallback_rate:6.0%}  {f.median_before_px:6.3f} "
        f"{f.median_after_px:6.3f} {f.worse_markers:5d} {f.large_markers:5d} "
        f"{f.large_outward_px:+7.3f}  {reasons}"
    )


def main() -> None:
    print(
        f"{'method':28s} {'n':>3s} {'fallbk':>6s}  {'in px':>6s} {'out px':>6s} "
        f"{'worse':>5s} {'large':>5s} {'outwd':>7s}  fallback reasons"
    )
    for label, method, start, transfer in RUNS:
        if not available(start):
            print(f"{label:28s} skipped: {start} is not installed")
            continue
        print(line(label, figures(measure(method, start, transfer))))
    print(
        f"in/out px: median corner distance to the consensus; worse: refined markers with a "
        f"corner > {WORSE_PX} px further than its input; large: refined markers >= "
        f"{LARGE_SIDE_PX:.0f} px a side; outwd: their mean signed outward offset (px)"
    )


if __name__ == "__main__":
    main()

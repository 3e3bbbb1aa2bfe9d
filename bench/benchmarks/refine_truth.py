"""The references of the real-photograph consensus, measured where the truth is known: each
detector's corners, their consensus and ``lines`` on ray-cast prints (:mod:`bench.evaluate.prints`)
under blur before and after the transfer curve, with a wide or a one-module quiet zone.

Run: ``python -m bench.benchmarks.refine_truth`` (about a minute; the peers need the ``peers``
extra). Prints, per kind of print, each method's mean signed outward offset from the true corners
(+: outside the marker) and, in brackets, its median corner error (px); "-" where it found no
marker. A reference biased by more than the limits that ``lines`` is held to on the real set
(docs/refine_real.md) moves the consensus by as much.
"""

from __future__ import annotations

from bench.evaluate.prints import FAMILIES, METHODS, offsets
from pipeline.backends import available


def main() -> None:
    methods = tuple(m for m in METHODS if m in ("consensus", "lines") or available(m))
    print(f"{'print':28s}" + "".join(f"{m:>16s}" for m in methods))
    for narrow in (False, True):
        for family, (photo, light) in FAMILIES.items():
            for size in ("large", "small"):
                zone = "1-module zone" if narrow else "wide zone"
                row = offsets(photo, light, size, narrow, methods)
                cells = "".join(
                    f"{r.outward_px:+7.2f} ({r.median_px:4.2f})" if r.found else f"{'-':>16s}"
                    for r in row.values()
                )
                print(f"{family:8s} {size:5s} {zone:14s}{cells}")
    print(
        "mean signed outward offset from the true corners, px (median corner error); OpenCV: "
        "CORNER_REFINE_SUBPIX; locus, apriltag: their own corners; consensus: the mean of the "
        "largest group agreeing within 1 px, as on the real set; lines: from OpenCV's unrefined "
        "corners, transfer auto"
    )


if __name__ == "__main__":
    main()

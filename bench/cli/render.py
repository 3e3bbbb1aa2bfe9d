"""``whiskerbench bench render``: options, their limits, and the call to the benchmark."""

from __future__ import annotations

import argparse

from bench.benchmarks.render import SCENES
from bench.cli import limits
from bench.cli.args import check_out_folder, integer
from renderers.variant import VARIANTS
from scenes.validation import FieldError

#: Cycles' cost of one sample per pixel of a full frame, CPU s: a lower bound (docs/performance.md,
#: "Against Blender Cycles" measured 10.8 s at 4 spp on 2 cores) for the time limit of --spp.
CYCLES_CPU_S_PER_SPP = 1.0
#: Memory per sample per pixel, the limit of --spp, per scene. ``marker``: one full-frame row in
#: flight in the study's renderer (jittered positions, directions and the traced outputs of every
#: sample). ``array``: the dataset's renderer holds every ray of the whole frame at once; measured
#: peak RSS 0.97 GB at 1 spp and 2.47 GB at 3 spp (bench_render(scene="array", use_cycles=False),
#: resource.getrusage), i.e. 0.75 GB per spp.
BYTES_PER_SPP = {
    "marker": (2592 * 128, "one row of samples"),
    "array": (750e6, "every ray of a full frame"),
}


def check_render_options(spp: int, threads: int | None, scene: str = "marker") -> None:
    """FieldError naming ``spp`` or ``threads`` and its allowed range, before any work."""
    if spp < 1:
        raise FieldError("spp", f"{spp}: must be >= 1")
    limits.check_memory("spp", spp, *BYTES_PER_SPP[scene])
    per_spp = 2 * CYCLES_CPU_S_PER_SPP  # two Cycles renders
    limits.check_time("spp", spp * per_spp, "two Cycles renders", spp, per_spp)
    if threads is not None and not 1 <= threads <= limits.cores():
        raise FieldError("threads", f"{threads}: allowed range is 1..{limits.cores()} (cores)")


def cmd_bench_render(args: argparse.Namespace) -> int:
    from bench.benchmarks.render import bench_render

    check_render_options(args.spp, args.threads, args.scene)
    out = None if args.out is None else check_out_folder(args.out)
    bench_render(args.scene, args.spp, args.threads, args.variant, out)
    return 0


def add_bench_render_parser(bench_sub) -> None:
    """The ``render`` parser under ``bench``."""
    p = bench_sub.add_parser(
        "render",
        help="the project's renderer against Blender Cycles (make cycles installs bpy)",
    )
    p.add_argument(
        "--scene",
        choices=SCENES,
        default="marker",
        help="marker: the study's marker; array: the whisker array in foliage (default marker)",
    )
    p.add_argument("--spp", type=integer, default=4, help="samples per pixel, both (default 4)")
    p.add_argument("--threads", type=integer, help="threads of both renderers (default: cores)")
    p.add_argument("--variant", choices=VARIANTS, help="Mitsuba variant (default: fastest)")
    p.add_argument("--out", help="also write bench.json and both 8-bit images here")
    p.set_defaults(func=cmd_bench_render)

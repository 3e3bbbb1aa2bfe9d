"""``whiskerbench bench targets``: issue 25's targets, each figure against its threshold, one run.

Each target is measured by the project's own code (the dataset generator, ``bench render``,
the Makefile's test targets), never by a second copy of it; a target this run cannot measure
says why instead of showing a figure. Whether a target is met is only ever the figure against
its threshold (:func:`judge`); the ratios against a baseline measured in the same run go beside
it. The table is printed as Markdown (docs/speed.md pastes it) and written as ``targets.csv``
with a ``manifest.json``.
"""

from __future__ import annotations

import csv
import io
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

from bench.benchmarks.scale import default_dataset_frames
from bench.common.atomic import write_bytes
from bench.common.manifest import RunClock, build_manifest, hash_files, machine, write_manifest
from bench.common.run_folder import claim_out, open_folder
from bench.dataset.config import DatasetConfig
from bench.dataset.generate import run_dataset
from renderers.variant import gpu_present
from scenes.validation import FieldError

#: Where the committed GPU figures are (measured on a lent device, not by this run).
GPU_FIGURES = "results/gpu/figures.md"
#: Every ``step``-th frame of the targets' datasets in ``--quick``: a few seconds per dataset.
QUICK_FRAMES_STEP = 10
#: The dataset options of :func:`fewest_rays`, as 1a's row names them.
FEWEST_RAYS_OPTIONS = "--spp 1 --subframes 1"
#: The columns of ``targets.csv``.
CSV_COLUMNS = ("target", "what", "figure", "unit", "threshold", "met", "baseline", "command")


@dataclass(frozen=True)
class Target:
    """One of the issue's targets: met when the figure is at least (``above``) or under the
    threshold."""

    key: str
    what: str
    unit: str
    threshold: float
    above: bool
    command: str


@dataclass(frozen=True)
class Outcome:
    """A target's figure in this run, or None with the reason in ``why``; ``baseline``: the
    ratio against a baseline of the same run, how an estimate was made, or the CPU it took."""

    target: Target
    figure: float | None
    baseline: str = ""
    why: str = ""
    command: str = ""

    @property
    def met(self) -> bool | None:
        """The figure against the threshold; None when not measured."""
        if self.figure is None:
            return None
        return judge(self.figure, self.target.threshold, self.target.above)


def judge(figure: float, threshold: float, above: bool) -> bool:
    """Whether ``figure`` meets ``threshold``: at least it (``above``) or strictly under it."""
    return figure >= threshold if above else figure < threshold


TARGETS = (
    Target(
        "1a",
        "dataset --quick, 2 workers",
        "frames/s",
        15.0,
        True,
        "whiskerbench dataset --quick --workers 2",
    ),
    Target(
        "1b",
        "dataset --quick, 1 worker",
        "frames/s",
        8.0,
        True,
        "whiskerbench dataset --quick --workers 1",
    ),
    Target(
        "1c",
        "indoor grid (make indoor), 2 workers",
        "h",
        1.5,
        False,
        "make indoor",
    ),
    Target(
        "2a",
        "renderer vs Cycles, array scene",
        "x",
        10.0,
        True,
        "whiskerbench bench render --scene array --spp 4",
    ),
    Target(
        "2b",
        "renderer vs Cycles, one-marker scene",
        "x",
        10.0,
        True,
        "whiskerbench bench render --spp 4",
    ),
    Target(
        "3",
        "GPU: dataset --quick, 1 worker, cuda_ad_rgb",
        "frames/s",
        300.0,
        True,
        "whiskerbench dataset --quick --variant cuda_ad_rgb",
    ),
    Target("4a", "make test", "s", 240.0, False, "make test"),
    Target("4b", "make test-fast", "s", 30.0, False, "make test-fast"),
)
BY_KEY = {t.key: t for t in TARGETS}


def dataset_rate(config: DatasetConfig, workers: int, variant: str | None) -> dict:
    """``run_dataset`` from scratch in a temporary folder: its manifest (``frames_per_s``),
    with ``cpu_s``: the CPU seconds it took in this process and in its pool's workers (joined
    when the pool closes, so counted among this process's children)."""
    before = cpu_seconds()
    with tempfile.TemporaryDirectory() as tmp:
        manifest = run_dataset(config, Path(tmp) / "data", variant, workers, progress=False)
    return {**manifest, "cpu_s": cpu_seconds() - before}


def fewest_rays(config: DatasetConfig) -> DatasetConfig:
    """``config`` traced with the fewest rays the renderer takes: one a pixel, at one time
    sample. The fidelity ladder keeps 4 spp for video (results/ladder: marker spp 1 and 2 stray
    from the reference, at 4 time samples), so this is no setting to use, only the bound on
    what fewer rays can give: where even it misses 1a, no ray count meets it."""
    sampling = replace(config.sampling, marker_spp=1, background_spp=1, subframes=1)
    return replace(config, sampling=sampling)


def leading_samples(config: DatasetConfig, workers: int) -> DatasetConfig:
    """``config`` cut to the first ``workers`` samples of its grid, the ones ``make indoor``
    starts together: its first foliage, distance, protocol and lighting, with as many of its
    branch configurations (the grid's innermost axis, :meth:`DatasetConfig.samples`)."""
    s = config.samples()[0]
    return replace(
        config,
        foliage=(s.foliage,),
        distances=(s.distance,),
        branches=config.branches[:workers],
        protocols=(s.protocol,),
        lightings=(s.lighting,),
    )


def cpu_seconds() -> float:
    """User and system CPU seconds of this process and of its children that have ended."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def cpu_bound(cpu_s: float, frames: int, cores: int) -> str:
    """The CPU a frame took and the rate ``cores`` would give if every core did nothing else."""
    per_frame = cpu_s / frames
    return (
        f"{per_frame:.3f} s of CPU a frame: {cores} cores allow at most "
        f"{cores / per_frame:.1f} frames/s"
    )


def render_ratio(scene: str, key: str) -> Outcome:
    """``bench render`` of ``scene`` at 4 spp: the smaller of its wall and CPU ratios; not
    measured without bpy, or when the two renders' detections differ, or when the marker's
    crop + sky frame strays outside the traced frame's seed spread."""
    from bench.benchmarks.cycles_scene import INSTALL_HINT, import_bpy
    from bench.benchmarks.render import bench_render

    target = BY_KEY[key]
    if import_bpy() is None:
        return Outcome(target, None, why=f"not measured: bpy not installed ({INSTALL_HINT})")
    figures = bench_render(scene, spp=4)
    ratio = min(figures["ratio_wall"], figures["ratio_cpu"])
    seconds = f"Cycles {figures['cycles']['wall_s'][1]:.2f} s, this renderer " + (
        f"{figures['project']['wall_s'][1]:.2f} s a frame (wall)"
    )
    if "traced" in figures:
        traced = figures["traced"]["wall_s"][1]
        seconds += f", crop + sky ({traced:.2f} s with every pixel traced)"
    if not figures["detection_equal"]:
        why = f"not counted: detections differ between the renders (ratio {ratio:.1f}x)"
        return Outcome(target, None, seconds, why)
    if not figures.get("within_seed_spread", True):
        why = f"not counted: the crop + sky frame strays from the traced one (ratio {ratio:.1f}x)"
        return Outcome(target, None, seconds, why)
    return Outcome(target, ratio, seconds)


def time_make(target: str, root: Path) -> tuple[float, int]:
    """(wall s, exit code) of ``make <target>`` in ``root``, its output passed through."""
    t0 = time.perf_counter()
    code = subprocess.run(["make", "-s", "-C", str(root), target], check=False).returncode
    return time.perf_counter() - t0, code


def suite_outcome(key: str, root: Path, measure: bool) -> Outcome:
    """``make test`` or ``make test-fast`` timed in ``root`` when ``measure``; a failed run has
    no figure (a fast failure is no speed)."""
    target = BY_KEY[key]
    if not measure:
        return Outcome(target, None, why="not measured: takes minutes; --time-tests times it")
    if not (root / "Makefile").is_file():
        return Outcome(target, None, why=f"not measured: no Makefile in {root}")
    name = target.command.removeprefix("make ")
    wall_s, code = time_make(name, root)
    if code != 0:
        return Outcome(
            target, None, why=f"not measured: make {name} failed (exit {code}) after {wall_s:.0f} s"
        )
    return Outcome(target, wall_s, "this checkout (not a fresh clone), this machine's load")


def measure(
    quick_dataset: DatasetConfig,
    indoor: DatasetConfig,
    quick: bool = False,
    time_tests: bool = False,
    root: Path = Path("."),
) -> list[Outcome]:
    """Every target's outcome, in :data:`TARGETS` order, each line printed as it is measured.

    ``quick``: ``quick_dataset`` and 1c's indoor samples at every :data:`QUICK_FRAMES_STEP`-th
    frame and no Cycles renders (a test's run). Where a GPU is present the CPU rows run on
    llvm_ad_rgb, so they stay CPU figures; elsewhere on the fastest variant, as ``dataset``
    does.
    """
    cpu_variant = "llvm_ad_rgb" if gpu_present() else None
    config, suffix = quick_dataset, ""
    if quick:
        config = replace(quick_dataset, frames_step=QUICK_FRAMES_STEP)
        suffix = f" --frames-step {QUICK_FRAMES_STEP}"
    variant_option = " --variant llvm_ad_rgb" if cpu_variant else ""
    rates, bound, cores = {}, {}, os.cpu_count() or 1
    for key, workers in (("1b", 1), ("1a", 2)):  # one worker first: the baseline
        manifest = dataset_rate(config, workers, cpu_variant)
        rates[key] = manifest["frames_per_s"]
        bound[key] = cpu_bound(manifest["cpu_s"], manifest["frames_rendered"], cores)
        print(
            f"  {key}: {manifest['frames_rendered']} frames in {manifest['wall_s']:.1f} s, "
            f"{rates[key]:.2f} frames/s ({workers} worker(s), {manifest['variant']}); "
            f"{bound[key]}",
            flush=True,
        )
    floor = dataset_rate(fewest_rays(config), 2, cpu_variant)
    floor_text = (
        f"the fewest rays ({FEWEST_RAYS_OPTIONS}, under the 4 spp the ladder keeps for video): "
        f"{floor['frames_per_s']:.2f} frames/s, "
        f"{cpu_bound(floor['cpu_s'], floor['frames_rendered'], cores)}"
    )
    print(f"  1a at {floor_text}", flush=True)
    out = [
        Outcome(
            BY_KEY["1a"],
            rates["1a"],
            f"{rates['1a'] / rates['1b']:.2f}x the 1-worker rate; {bound['1a']}; at {floor_text}",
            command=BY_KEY["1a"].command + suffix + variant_option,
        ),
        Outcome(
            BY_KEY["1b"],
            rates["1b"],
            bound["1b"],
            command=BY_KEY["1b"].command + suffix + variant_option,
        ),
    ]
    out.append(indoor_estimate(indoor, quick, cpu_variant, cores))
    print(f"  1c: {_figure(out[-1])}; {out[-1].baseline}", flush=True)
    for scene, key in (("array", "2a"), ("marker", "2b")):
        if quick:
            out.append(Outcome(BY_KEY[key], None, why="not measured: --quick renders no Cycles"))
        else:
            out.append(render_ratio(scene, key))
        print(f"  {key}: {_figure(out[-1])}", flush=True)
    out.append(gpu_outcome(config, rates["1b"], suffix))
    out += [suite_outcome(key, root, time_tests) for key in ("4a", "4b")]
    return [replace(o, command=o.command or o.target.command) for o in out]


def indoor_estimate(indoor: DatasetConfig, quick: bool, variant: str | None, cores: int) -> Outcome:
    """1c: the indoor grid's frames at the rate of its first two samples, made from scratch
    with two workers as ``make indoor`` makes the grid (every :data:`QUICK_FRAMES_STEP`-th
    frame with ``quick``): indoor frames as the grid makes them, not 1a's outdoor ones, whose
    samples reuse the optical image in 14 of their 74 frames (the still lead-in) where an indoor
    sample does in 14 of about 980."""
    lead = leading_samples(indoor, 2)
    if quick:
        lead = replace(lead, frames_step=max(lead.frames_step, QUICK_FRAMES_STEP))
    made = dataset_rate(lead, 2, variant)
    frames, rate = default_dataset_frames(indoor), made["frames_per_s"]
    every = f", one in {lead.frames_step}" if lead.frames_step > 1 else ""
    names = ", ".join(s.sample_id for s in lead.samples())
    return Outcome(
        BY_KEY["1c"],
        frames / rate / 3600,
        f"estimate: {frames:,} indoor frames at the rate of its first samples on 2 workers, "
        f"{names} ({made['frames_rendered']} frames{every}: {rate:.2f} frames/s; "
        f"{cpu_bound(made['cpu_s'], made['frames_rendered'], cores)})",
    )


def gpu_outcome(config: DatasetConfig, cpu_rate: float, suffix: str) -> Outcome:
    """Target 3 on this machine's GPU, against the CPU's one-worker rate of the same run."""
    target = BY_KEY["3"]
    if not gpu_present():
        return Outcome(
            target,
            None,
            why=f"not measured: no device on this machine (figures from a lent GPU: {GPU_FIGURES})",
        )
    rate = dataset_rate(config, 1, "cuda_ad_rgb")["frames_per_s"]
    return Outcome(
        target,
        rate,
        f"{rate / cpu_rate:.1f}x the CPU 1-worker rate (1b)",
        command=target.command + suffix,
    )


def _figure(o: Outcome) -> str:
    if o.figure is None:
        return o.why
    digits = 2 if o.target.unit in ("h", "x") or o.figure < 100 else 0
    text = f"{o.figure:.{digits}f} {o.target.unit}"
    return f"{text} ({o.why})" if o.why else text


def _met(o: Outcome) -> str:
    return {True: "yes", False: "no", None: "n/a"}[o.met]


def _threshold(t: Target) -> str:
    return f"{'>=' if t.above else '<'} {t.threshold:g} {t.unit}"


def table(outcomes: list[Outcome]) -> str:
    """The outcomes as a Markdown table: target, figure, threshold, met, baseline, command."""
    lines = [
        "| target | figure | threshold | met | baseline / ratio | command |",
        "|---|---|---|---|---|---|",
    ]
    for o in outcomes:
        cells = (
            f"{o.target.key} {o.target.what}",
            _figure(o),
            _threshold(o.target),
            _met(o),
            o.baseline or "-",
            f"`{o.command or o.target.command}`",
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def csv_text(outcomes: list[Outcome]) -> str:
    """``targets.csv``: :data:`CSV_COLUMNS`, an empty figure and met where not measured (the
    reason in ``baseline``)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for o in outcomes:
        met = "" if o.met is None else str(o.met).lower()
        figure = "" if o.figure is None else repr(float(o.figure))
        baseline = "; ".join(x for x in (o.baseline, o.why) if x)
        writer.writerow(
            (
                o.target.key,
                o.target.what,
                figure,
                o.target.unit,
                f"{o.target.threshold:g}",
                met,
                baseline,
                o.command,
            )
        )
    return buffer.getvalue()


def bench_targets(
    quick_dataset: DatasetConfig,
    indoor: DatasetConfig,
    out_dir: Path,
    quick: bool = False,
    time_tests: bool = False,
) -> list[Outcome]:
    """Measure every target (:func:`measure`), print the table, write ``targets.csv`` and
    ``manifest.json`` into ``out_dir`` (claimed before any work, locked while written)."""
    out_dir = Path(out_dir)
    clock = RunClock()
    claim_out(out_dir, "bench-targets")
    load = [os.getloadavg()[0]]  # a shared machine's load: what the figures were measured under
    cpu = machine()
    simd = cpu["simd"] or "no SIMD level named"
    print(
        f"targets of issue 25 on {cpu['cores']} cores ({cpu['cpu']}, {simd}), load average "
        f"{load[0]:.1f}" + (" (--quick)" if quick else "")
    )
    outcomes = measure(quick_dataset, indoor, quick, time_tests)
    load.append(os.getloadavg()[0])
    print(table(outcomes))
    met = [o for o in outcomes if o.met is not None]
    print(
        f"{sum(bool(o.met) for o in met)} of {len(met)} measured targets met; "
        f"{len(outcomes) - len(met)} not measured (the reason in its row); load average "
        f"{load[1]:.1f} at the end"
    )
    try:
        lock = open_folder(out_dir, "bench-targets")
    except ValueError as exc:
        raise FieldError("out", str(exc)) from None
    with lock:
        path = out_dir / "targets.csv"
        write_bytes(path, csv_text(outcomes).encode())
        config = {"quick": quick, "time_tests": time_tests, "dataset": quick_dataset.to_json()}
        record = build_manifest(
            "bench-targets", clock, config, outputs=hash_files([path], out_dir), load_average=load
        )
        write_manifest(out_dir, record)
    print(f"wrote {out_dir}/targets.csv and manifest.json")
    return outcomes

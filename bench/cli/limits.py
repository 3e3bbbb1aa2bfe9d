"""Upper limits of the options that size work or memory, estimated before anything is allocated.

Each command's work is estimated from its options with costs measured on this project's 2-core
machine (docs/performance.md; the figures are lower bounds: the fastest rates seen). A run is
refused, naming the option that grows it most, when it would need more memory than half of this
machine's physical memory or run longer than :data:`TIME_BUDGET_S` on all of its cores. The
message says the estimate, the limit on that option and how it was derived.

The files a user hands over are bounded by :mod:`scenes.input_limits` (a lower layer, so that
every reader can import them); docs/limits.md lists both kinds.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping

from renderers.frame_sampling import FrameSampling
from scenes.validation import FieldError

#: A run longer than this is refused: a week on every core of this machine.
TIME_BUDGET_S = 7 * 24 * 3600.0
TIME_BUDGET_TEXT = "7 days"

# --- measured costs (seconds, bytes), lower bounds
#: Clean render of one study cell at 16 spp (docs/performance.md: about 83 ms per cell,
#: llvm_ad_rgb).
STUDY_RENDER_S_AT_16_SPP = 0.083
#: One study image through the twin and the detector, render excluded (docs/performance.md:
#: 0.17 + 0.78 + 1.72 ms CPU per image).
STUDY_IMAGE_S = 0.0027
#: One band frame of a dataset at 4 spp and 4 subframes, render only (docs/datasets.md:
#: 17.7 frames/s, `bench dataset`, llvm_ad_rgb).
DATASET_FRAME_S_AT_16_RAYS = 1 / 17.7
#: Full frames render this many times slower than the band (docs/datasets.md: 17.7 against
#: 6.4 frames/s).
FULL_FRAME_FACTOR = 17.7 / 6.4
#: Memory of a simulated sample per time sample (frames x (subframes + 1)): 6.3 kB measured
#: with tracemalloc over simulate_sample (peak 31.5 kB per frame at 4 subframes).
SAMPLE_BYTES_PER_TIME_SAMPLE = 6.3e3
#: Resident memory of a worker after its Mitsuba set-up: 206 MB measured (llvm_ad_rgb); twice
#: that per worker leaves room for its renderer and a cell's images.
WORKER_BYTES = 2 * 206e6
#: A full frame in flight of a dataset worker: float32 RGB radiance, irradiance and sensor
#: stages, about eight W x H x 3 float32 buffers.
FRAME_BUFFERS = 8


def memory_budget_bytes() -> float:
    """Half of this machine's physical memory (the rest for the system and other jobs)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2
    except (ValueError, OSError, AttributeError):  # no sysconf: assume 8 GiB
        return 4 * 2**30


def cores() -> int:
    return os.cpu_count() or 1


def _num(value: float) -> str:
    """An integer as digits, anything else in %g."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else f"{value:g}"


def _gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.3g} GiB"


def _duration(seconds: float) -> str:
    for unit, size in (("years", 365 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


def check_memory(field: str, value: float, bytes_each: float, what: str) -> None:
    """Refuse ``value`` units of ``bytes_each`` beyond the memory budget, naming the limit."""
    budget = memory_budget_bytes()
    if value * bytes_each > budget:
        limit = max(0, math.floor(budget / bytes_each))
        raise FieldError(
            field,
            f"{_num(value)}: {what} would need {_gib(value * bytes_each)}; limit {limit} "
            f"(memory budget {_gib(budget)}, half of this machine's memory)",
        )


def check_time(field: str, seconds: float, what: str, value: float, per_unit_s: float) -> None:
    """Refuse a run estimated at ``seconds`` beyond the time budget; ``value`` is the culprit
    option's value and ``per_unit_s`` what one unit of it costs (for the limit)."""
    budget = TIME_BUDGET_S * cores()
    if seconds > budget:
        fixed = seconds - value * per_unit_s  # what the other options cost on their own
        limit = max(0, math.floor((budget - max(fixed, 0.0)) / per_unit_s))
        raise FieldError(
            field,
            f"{_num(value)}: {what} would take at least {_duration(seconds / cores())} on "
            f"{cores()} cores; limit {limit} ({TIME_BUDGET_TEXT} at the fastest measured rates, "
            "docs/performance.md)",
        )


def culprit(ratios: Mapping[str, float]) -> str:
    """The field whose value is farthest above its default (ratio value / default)."""
    return max(ratios, key=lambda k: ratios[k])


def default_workers(bytes_each: float = WORKER_BYTES) -> int:
    """One worker per core, as many as the memory budget holds (at least one)."""
    return max(1, min(cores(), math.floor(memory_budget_bytes() / bytes_each)))


def check_camera(profile) -> None:
    """A full frame of the profile's lens, in flight through the renderer and the twin (about
    :data:`FRAME_BUFFERS` W x H x 3 float32 buffers), must fit the memory budget."""
    lens = profile.lens
    pixels = lens.width_px * lens.height_px
    frame_bytes = FRAME_BUFFERS * 3 * 4
    if pixels * frame_bytes > memory_budget_bytes():
        raise FieldError(
            "camera",
            f"{profile.name}: a {lens.width_px}x{lens.height_px} px frame would need "
            f"{_gib(pixels * frame_bytes)} in flight; limit "
            f"{math.floor(memory_budget_bytes() / frame_bytes):,} px (memory budget "
            f"{_gib(memory_budget_bytes())}, half of this machine's memory)",
        )


def check_workers(field: str, workers: int, bytes_each: float = WORKER_BYTES) -> None:
    if workers < 1:
        raise FieldError(field, f"{workers}: must be >= 1")
    check_memory(field, workers, bytes_each, f"{workers} workers")


# --- per command ------------------------------------------------------------------------------


def check_study(config, workers: int) -> None:
    """A study's render and image time; names --spp, --images or the grid, whichever grows it.

    ``config``: a :class:`bench.study.config.StudyConfig`.
    """
    from bench.study.config import DEFAULT_ALPHAS_DEG, StudyConfig, alphas_within

    check_camera(config.camera)
    check_workers("workers", workers)
    cells = len(config.cells())
    render_s = STUDY_RENDER_S_AT_16_SPP * config.spp / 16
    image_s = STUDY_IMAGE_S * len(config.psf_scales)
    total = cells * (render_s + config.images * image_s)
    # the default grid on this camera: its alphas end at a narrow lens's edge, as the CLI's do
    default = StudyConfig(
        camera=config.camera, alphas_deg=alphas_within(DEFAULT_ALPHAS_DEG, config.camera)
    )
    field = culprit(
        {
            "spp": config.spp / default.spp,
            "images": config.images / default.images,
            "study_grid": cells / len(default.cells()),
        }
    )
    what = f"{cells} cells x up to {config.images} images at {config.spp} spp"
    if field == "spp":
        check_time("spp", total, what, config.spp, cells * STUDY_RENDER_S_AT_16_SPP / 16)
    elif field == "images":
        check_time("images", total, what, config.images, cells * image_s)
    else:
        check_time("study_grid", total, what, cells, render_s + config.images * image_s)


def dataset_frames(config, protocol: str) -> float:
    """Frames of one sample of ``protocol`` (after --frames-step), counted without allocating
    (:attr:`scenes.motion.MotionSpec.frame_count`); inf beyond floats. ``config``: a
    :class:`bench.dataset.config.DatasetConfig`."""
    full = config.motion(protocol).frame_count
    return full if math.isinf(full) else float(-(-full // config.frames_step))


def _motion_growth(config, protocol: str) -> dict[str, float]:
    """How many times longer each motion option makes a sample of ``protocol`` than the
    protocol's own (a slower speed lengthens it)."""
    from scenes.motion import get_protocol

    base, m = get_protocol(protocol), config.motion(protocol)
    return {
        "passes": m.passes / base.passes,
        "amplitude_mm": m.amplitude_mm / base.amplitude_mm,
        "speed_mm_s": base.speed_mm_s / m.speed_mm_s,
        "fps": m.fps / base.fps,
    }


def _check_sample_memory(config, protocol: str, frames: float, workers: int) -> None:
    """Refuse a sample whose simulation would not fit, naming the option that lengthened it."""
    k = config.sampling.subframes
    bytes_per_frame = (k + 1) * SAMPLE_BYTES_PER_TIME_SAMPLE
    per_sample = frames * bytes_per_frame
    budget = memory_budget_bytes() / workers
    if per_sample <= budget:
        return
    m = config.motion(protocol)
    growth = {**_motion_growth(config, protocol), "subframes": k / FrameSampling().subframes}
    field = culprit(growth)

    def value_of(motion) -> float:
        return {
            "amplitude_mm": motion.amplitude_mm,
            "speed_mm_s": motion.speed_mm_s,
            "fps": motion.fps,
            "passes": motion.passes,
        }.get(field, k)

    value = scaled = value_of(m)
    factor = budget / per_sample  # how much smaller the sample has to be
    if factor == 0 and field != "subframes":  # more frames than a float holds: scale the
        # protocol's own value of the culprit instead, the frames growing in proportion
        own = dataclasses.replace(config, **{field: None})
        scaled = value_of(own.motion(protocol))
        factor = budget / (dataset_frames(own, protocol) * bytes_per_frame)
    if field == "speed_mm_s":
        bound = f"lowest allowed about {scaled / factor:.3g}"
    elif field == "subframes":
        bound = f"limit {max(0, math.floor((k + 1) * factor) - 1)}"
    else:
        bound = f"limit about {scaled * factor:.3g}"
    raise FieldError(
        field,
        f"{_num(value)}: one {protocol} sample of {frames:.4g} frames x {k + 1} time samples would "
        f"hold {_gib(per_sample)} in each of {workers} worker(s); {bound} (memory budget "
        f"{_gib(memory_budget_bytes())}, half of this machine's memory)",
    )


def check_dataset(config, workers: int = 1) -> None:
    """A sample's memory and the whole grid's render time, before any sample is simulated."""
    check_camera(config.camera)
    lens = config.camera.lens
    frame_bytes = FRAME_BUFFERS * lens.width_px * lens.height_px * 3 * 4
    check_workers("workers", workers, WORKER_BYTES + frame_bytes)
    k = config.sampling.subframes
    rays = config.sampling.marker_spp * k
    frame_s = DATASET_FRAME_S_AT_16_RAYS * rays / 16
    if config.sampling.full_frame:
        frame_s *= FULL_FRAME_FACTOR
    total = 0.0
    for protocol in config.protocols:
        frames = dataset_frames(config, protocol)
        if frames < 2:
            full = dataset_frames(dataclasses.replace(config, frames_step=1), protocol)
            raise FieldError(
                "frames_step",
                f"{config.frames_step}: leaves {frames:g} frame of one {protocol} sample of "
                f"{full:g}; allowed range is 1..{full - 1:g}",
            )
        _check_sample_memory(config, protocol, frames, workers)
        samples = sum(1 for s in config.samples() if s.protocol == protocol)
        total += samples * frames * frame_s
    # the culprit: the grid on a tie, else the option farthest above its default, the
    # motion options (which lengthen every sample) included
    growth = {"dataset_grid": 1.0, "marker_spp": config.sampling.marker_spp / 4, "subframes": k / 4}
    values = {"marker_spp": config.sampling.marker_spp, "subframes": k}
    for protocol in config.protocols:
        m = config.motion(protocol)
        for name, ratio in _motion_growth(config, protocol).items():
            if ratio > growth.get(name, 0.0):
                growth[name], values[name] = ratio, getattr(m, name)
    field = culprit(growth)
    value = values.get(field, len(config.samples()))
    what = f"{len(config.samples())} samples at {rays} rays per pixel"
    if field == "speed_mm_s" and total > TIME_BUDGET_S * cores():  # shorter when larger
        raise FieldError(
            field,
            f"{_num(value)}: {what} would take at least {_duration(total / cores())} on "
            f"{cores()} cores; lowest allowed about {value * total / (TIME_BUDGET_S * cores()):.3g}"
            f" ({TIME_BUDGET_TEXT} at the fastest measured rates, docs/performance.md)",
        )
    check_time(field, total, what, value, total / value)


def check_frames(field: str, frames: int, width_px: int, height_px: int, what: str) -> None:
    """``frames`` full grey frames held in memory at once."""
    check_memory(field, frames, width_px * height_px, f"{frames} {what} of {width_px}x{height_px}")


def check_sweep(sweep, pipelines: int) -> None:
    """The failure-boundary sweeps, with their reruns at the band's ends: renders and images
    per seed and point, per pipeline."""

    def per_seed(run) -> float:
        point_s = STUDY_RENDER_S_AT_16_SPP * run.spp / 16 + pipelines * run.images * STUDY_IMAGE_S
        return len(run.points()) * point_s

    ends = sweep.band_end_sweeps()
    fixed = sum(run.seeds * per_seed(run) for run in ends)
    points = len(sweep.points())
    what = f"{sweep.seeds} seeds x {points} sweep points x {pipelines} pipelines" + (
        f" (and {len(ends)} band ends x {sweep.band_seeds} seeds)" if ends else ""
    )
    seconds = sweep.seeds * per_seed(sweep) + fixed
    check_time("seeds", seconds, what, sweep.seeds, per_seed(sweep))


#: A full 2592 x 1944 study frame: about 20 s to render and 0.9 s per image through the twin
#: (docs/performance.md).
FULL_FRAME_RENDER_S = 20.0
FULL_FRAME_IMAGE_S = 0.9


def check_full_frame_cells(count: int, config) -> None:
    """``bench detectability --full-frame-cells``: 1 (the frontal cell is always timed) up to
    the grid's cells, within the time budget."""
    cells = len(config.cells())
    if not 1 <= count <= cells:
        raise FieldError("full_frame_cells", f"{count}: allowed range is 1..{cells} (the grid)")
    per_cell = FULL_FRAME_RENDER_S + config.images * FULL_FRAME_IMAGE_S
    what = f"{count} full-frame cells x up to {config.images} images"
    check_time("full_frame_cells", count * per_cell, what, count, per_cell)


#: ``compare --speed-frames``: timed frames of the dataset, held in memory at once.
MAX_SPEED_FRAMES = 2000
#: ``--speed-rounds`` (``bench pipeline --rounds``): a median and a spread need 3 at least.
SPEED_ROUNDS_RANGE = (3, 100)


def check_speed_rounds(field: str, rounds: int) -> None:
    low, high = SPEED_ROUNDS_RANGE
    if not low <= rounds <= high:
        raise FieldError(
            field, f"{rounds}: allowed range is {low}..{high} (a median and a spread need 3)"
        )


def check_speed_frames(field: str, frames: int, lens=None) -> None:
    """Timed frames in range and, with the dataset's ``lens``, in memory with each run's
    lead-in frame (:data:`bench.evaluate.timing.RUN_FRAMES` timed frames a run)."""
    from bench.evaluate.timing import RUN_FRAMES

    if not 1 <= frames <= MAX_SPEED_FRAMES:
        raise FieldError(field, f"{frames}: allowed range is 1..{MAX_SPEED_FRAMES}")
    if lens is not None:
        held = frames + math.ceil(frames / RUN_FRAMES)
        check_frames(field, held, lens.width_px, lens.height_px, "frames (lead-ins included)")

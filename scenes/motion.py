"""How a sample is taken (SPEC section 2): the array's path through the vegetation over time.

The path is the array's offset (x, z) in the vegetation frame (:mod:`scenes.obstacles`), in mm,
piecewise linear in time:

1. lead-in: still, withdrawn by ``approach_mm`` along -z so no whisker touches anything, for
   ``lead_in_s`` (the pipeline takes its no-contact pose here);
2. approach: pushed in along +z to the sampling position at ``approach_speed_mm_s``;
3. whisking: sideways along x at ``speed_mm_s``, first from 0 to -amplitude, then ``passes``
   translations between -amplitude and +amplitude (SPEC: indoor two at 4 mm/s, outdoor three at
   80 mm/s). Reversals are instantaneous (a 3-D printer axis or a hand reverses in well under a
   frame at these speeds; the blur of a frame around a reversal is all that changes).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from scenes.validation import FieldError, shown_value


class MotionSpecError(FieldError):
    """An invalid motion parameter; ``field`` names it."""


#: Whisking passes of one sample, at most: a bound for the arithmetic of the path (the memory
#: and time limits of the command line name the far tighter one a machine sets).
MAX_PASSES = 10**9


@dataclass(frozen=True)
class MotionSpec:
    """One whisking protocol, with every number a parameter."""

    name: str
    amplitude_mm: float = 50.0
    speed_mm_s: float = 4.0
    passes: int = 2
    fps: float = 15.0
    #: Held still before the approach, where the pipeline takes its no-contact pose. An estimate:
    #: SPEC gives no lead-in; the indoor grid shows what 1 s does with the prototype camera
    #: (docs/datasets.md, "The indoor default grid").
    lead_in_s: float = 1.0
    approach_mm: float = 150.0
    approach_speed_mm_s: float = 50.0

    def __post_init__(self) -> None:
        for name in ("amplitude_mm", "speed_mm_s", "fps", "approach_speed_mm_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise MotionSpecError(name, f"must be a finite number > 0, got {value}")
        for name in ("lead_in_s", "approach_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise MotionSpecError(name, f"must be a finite number >= 0, got {value}")
        if self.lead_in_s * self.fps < 1:
            raise MotionSpecError("lead_in_s", "must hold at least one frame (no-contact pose)")
        p = self.passes
        whole = isinstance(p, numbers.Integral) or (isinstance(p, float) and p.is_integer())
        if isinstance(p, bool) or not (whole and 1 <= p <= MAX_PASSES):
            raise MotionSpecError(
                "passes", f"must be an integer 1..{MAX_PASSES}, got {shown_value(p)}"
            )

    def waypoints(self) -> tuple[np.ndarray, np.ndarray]:
        """(times_s (W,), offsets_mm (W, 2)): the corners of the piecewise-linear path."""
        a = self.amplitude_mm
        xs = [0.0, -a] + [a if k % 2 == 0 else -a for k in range(self.passes)]
        points = [(0.0, -self.approach_mm), (0.0, -self.approach_mm), (0.0, 0.0)]
        points += [(x, 0.0) for x in xs[1:]]
        times = [0.0, self.lead_in_s, self.lead_in_s + self.approach_mm / self.approach_speed_mm_s]
        for x0, x1 in zip(xs[:-1], xs[1:], strict=True):
            times.append(times[-1] + abs(x1 - x0) / self.speed_mm_s)
        return np.asarray(times), np.asarray(points, dtype=float)

    @property
    def duration_s(self) -> float:
        """The path's end: lead-in, approach, then legs to -a and 2a per pass (closed form, so
        a hostile ``passes`` is sized before anything is allocated)."""
        legs_mm = self.amplitude_mm * (1 + 2 * self.passes)
        return (
            self.lead_in_s + self.approach_mm / self.approach_speed_mm_s + legs_mm / self.speed_mm_s
        )

    @property
    def frame_count(self) -> float:
        """How many frames :meth:`frame_times` gives; inf for a path beyond floats."""
        count = self.duration_s * self.fps
        if not math.isfinite(count) or count > 1e15:
            return math.inf
        return float(math.floor(count + 1e-9) + 1)

    @property
    def whisking_start_s(self) -> float:
        """When the sideways motion begins (the end of the approach)."""
        return float(self.waypoints()[0][2])

    def frame_times(self) -> np.ndarray:
        """(F,) frame timestamps (s): every 1/fps from 0 to the end of the path."""
        return np.arange(int(self.frame_count)) / self.fps

    def offsets_at(self, times_s: np.ndarray) -> np.ndarray:
        """(..., 2) array offset (x, z) in mm at the given times (clamped to the path's ends)."""
        t, p = self.waypoints()
        times_s = np.asarray(times_s, dtype=float)
        x = np.interp(times_s, t, p[:, 0])
        z = np.interp(times_s, t, p[:, 1])
        return np.stack([x, z], axis=-1)


PROTOCOLS: dict[str, MotionSpec] = {
    "indoor": MotionSpec("indoor", amplitude_mm=50.0, speed_mm_s=4.0, passes=2),
    "outdoor": MotionSpec("outdoor", amplitude_mm=50.0, speed_mm_s=80.0, passes=3),
}


def get_protocol(name: str) -> MotionSpec:
    """The protocol of that name, or ValueError listing them."""
    if name not in PROTOCOLS:
        raise ValueError(f"protocol={name!r}: unknown; choose from {', '.join(PROTOCOLS)}")
    return PROTOCOLS[name]

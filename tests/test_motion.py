"""Whisking protocols: SPEC 2 numbers, the still lead-in, parameters and their validation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scenes.motion import MotionSpec, MotionSpecError, get_protocol


@pytest.mark.parametrize(("name", "speed", "passes"), [("indoor", 4.0, 2), ("outdoor", 80.0, 3)])
def test_protocols_follow_the_spec(name: str, speed: float, passes: int) -> None:
    m = get_protocol(name)
    assert (m.amplitude_mm, m.speed_mm_s, m.passes, m.fps) == (50.0, speed, passes, 15.0)
    t = np.arange(0, m.duration_s, 1e-3)
    x = m.offsets_at(t)[:, 0]
    whisk = t >= m.whisking_start_s
    assert x.min() == pytest.approx(-50.0) and x.max() == pytest.approx(50.0 if passes else 0)
    # speed while whisking: |dx/dt| = speed except at the reversals
    v = np.abs(np.diff(x[whisk])) / 1e-3
    assert np.median(v) == pytest.approx(speed, rel=1e-6)
    # translations: the sign of the motion changes passes times after the first half move
    moving = np.sign(np.diff(x[whisk]))
    moving = moving[moving != 0]
    assert np.count_nonzero(np.diff(moving)) == passes


def test_lead_in_is_still_and_withdrawn() -> None:
    m = get_protocol("outdoor")
    times = m.frame_times()
    lead = times < m.lead_in_s
    assert lead.sum() == 15  # one second at 15 frames/s
    off = m.offsets_at(times[lead])
    np.testing.assert_array_equal(off, np.tile([0.0, -m.approach_mm], (lead.sum(), 1)))
    assert m.offsets_at(m.whisking_start_s) == pytest.approx([0.0, 0.0])
    np.testing.assert_allclose(np.diff(times), 1 / 15)


def test_parameters_change_the_path() -> None:
    base = get_protocol("indoor")
    fast = dataclasses.replace(base, speed_mm_s=8.0, amplitude_mm=30.0, passes=1, fps=30.0)
    assert fast.offsets_at(1e3)[0] == pytest.approx(30.0)  # ends at +amplitude after one pass
    whisk = fast.duration_s - fast.whisking_start_s
    assert whisk == pytest.approx((30 + 60) / 8.0)
    assert len(fast.frame_times()) == int(fast.duration_s * 30) + 1


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"speed_mm_s": -4.0}, "speed_mm_s"),
        ({"amplitude_mm": 0.0}, "amplitude_mm"),
        ({"passes": 0}, "passes"),
        ({"fps": float("nan")}, "fps"),
        ({"lead_in_s": 0.01}, "lead_in_s"),
    ],
)
def test_bad_parameters_name_the_field(kwargs, field) -> None:
    with pytest.raises(MotionSpecError, match=field):
        MotionSpec("x", **kwargs)

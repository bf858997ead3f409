"""Eq. (F5), phase-matched: a still tip that the beat and the breath swing by centimetres
is not taken for a moved patient, a shifted one is, whatever the phase."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ShapeError
from icenav.recovery.drift import (
    GUARD_S,
    NEIGHBOURS,
    REST_WINDOW_S,
    RestReference,
    check_q,
    tip_drift,
)

BEAT_S, BREATH_S = 0.83, 4.1


def _signals(t: float) -> tuple[float, float]:
    """(respiratory signal, cardiac phase) at ``t`` (s): incommensurate periods."""
    return math.sin(2 * math.pi * t / BREATH_S), (t / BEAT_S) % 1.0


def _tip(t: float, shift: float = 0.0) -> np.ndarray:
    """A still tip at a moving wall (mm): 5 mm with each beat, 5 mm with each breath."""
    resp, phase = _signals(t)
    return np.array(
        [shift + 5.0 * math.sin(2 * math.pi * phase), 5.0 * resp, 40.0 + 3.0 * phase**2]
    )


def _reference(dt: float = 0.025) -> RestReference:
    ref = RestReference(0.0, _tip(0.0), [0.0, 0.0, 0.0, 10.0], *_signals(0.0))
    for t in np.arange(dt, REST_WINDOW_S + 3.0, dt):  # readings beyond the window are ignored
        ref.add(float(t), _tip(float(t)), *_signals(float(t)))
    return ref


def test_a_still_tip_at_every_phase_matches_its_reference_and_a_shift_does_not() -> None:
    ref = _reference()
    assert abs(ref.n_readings - (REST_WINDOW_S / 0.025 + 1)) <= 1  # then no more
    assert 4.0 < ref.spread_mm() < 8.0  # the beat's and the breath's 5 mm each
    times = np.linspace(10.0, 60.0, 400)  # phases never seen in this order
    still = [ref.drift(_tip(t), *_signals(t)) for t in times]
    instant = [ref.drift(_tip(t)) for t in times]  # no signals: against the stop
    shifted = [ref.drift(_tip(t, shift=5.0), *_signals(t)) for t in times]
    assert max(instant) > 7.0  # the instantaneous form would refuse many returns
    assert max(still) < 4.0 and float(np.mean(still)) < 1.0  # a few phases poorly covered
    assert min(shifted) > 2.0 and np.median(shifted) == pytest.approx(5.0, abs=0.6)


def test_a_missing_or_flat_signal_is_left_out_and_without_both_it_is_instantaneous() -> None:
    ref = RestReference(0.0, [0.0, 0.0, 40.0], None, None, 0.0)
    for k in range(1, 40):  # a phantom: no breathing signal, the beat alone
        t = 0.1 * k
        ref.add(t, [3.0 * math.sin(2 * math.pi * t / BEAT_S), 0.0, 40.0], None, (t / BEAT_S) % 1.0)
    t = 7.31
    tip = [3.0 * math.sin(2 * math.pi * t / BEAT_S), 0.0, 40.0]
    assert ref.drift(tip, None, (t / BEAT_S) % 1.0) < 0.5
    assert ref.drift(tip) == pytest.approx(abs(tip[0]))  # the instantaneous form
    flat = RestReference(0.0, [0.0, 0.0, 40.0], None, 0.3, None)
    flat.add(0.1, [1.0, 0.0, 40.0], 0.3, None)
    assert flat.drift([2.0, 0.0, 40.0], 0.3, None) == pytest.approx(2.0)  # vs the stop
    assert NEIGHBOURS >= 1


def test_the_reference_keeps_its_first_reading_and_its_motor_state() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    ref = RestReference(5.0, pose, [0.1, 0.2, 0.3, 4.0])
    ref.add(5.0 + REST_WINDOW_S + 0.1, [9.0, 9.0, 9.0], None, None)
    assert ref.n_readings == 1 and not ref.wants(5.0 + REST_WINDOW_S + 0.1)
    assert ref.spread_mm() == 0.0
    np.testing.assert_array_equal(ref.tip, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(ref.q, [0.1, 0.2, 0.3, 4.0])
    assert tip_drift([1.0, 2.0, 3.0], pose) == 0.0 and tip_drift(None, pose) is None


def test_bad_readings_are_refused_with_their_name() -> None:
    with pytest.raises(ShapeError, match="tip"):
        RestReference(0.0, [1.0, 2.0])
    with pytest.raises(ShapeError, match="q"):
        RestReference(0.0, [1.0, 2.0, 3.0], [0.0, math.nan, 0.0, 0.0])
    with pytest.raises(ShapeError, match="tip2base"):
        RestReference(0.0, [1.0, 2.0, 3.0]).drift(np.eye(3))
    with pytest.raises(ShapeError, match="rest_q"):
        check_q([0.0] * 3, "rest_q")


def test_readings_younger_than_the_guard_are_not_the_reference() -> None:
    """A patient who moved 2 s after the stop, within the reference window, and a return
    3 s after the stop: the readings of the last GUARD_S (the moved tip) are not matched;
    with every reading counted the moved tip would match itself."""
    ref = RestReference(0.0, _tip(0.0), None, *_signals(0.0))
    for t in np.arange(0.025, 3.0, 0.025):
        ref.add(float(t), _tip(float(t), shift=8.0 if t >= 2.0 else 0.0), *_signals(float(t)))
    now = 3.0
    moved = _tip(now, shift=8.0)
    assert ref.drift(moved, *_signals(now), t=now) > 5.0
    assert ref.drift(moved, *_signals(now)) < 3.0  # what the guard prevents
    assert GUARD_S <= 2.0


def _wandering(seed: int = 0, dt: float = 0.025) -> RestReference:
    """A still tip pushed about by a wall it touches: a random walk of about 8 mm over the
    window that no phase explains (mm)."""
    rng = np.random.default_rng(seed)
    p = np.array([0.0, 0.0, 40.0])
    ref = RestReference(0.0, p, None, *_signals(0.0))
    for t in np.arange(dt, REST_WINDOW_S, dt):
        p = p + rng.normal(0.0, 0.6, 3)
        ref.add(float(t), p, *_signals(float(t)))
    return ref


def test_the_resolution_is_small_where_the_phase_explains_the_motion_and_not_elsewhere() -> None:
    """Eq. (F6): for the tip swung 5 mm by the beat and 5 mm by the breath, the reference's
    own scatter is close to what Eq. (F5) sees at later times (a 90th percentile of 2 mm,
    against 7 mm of spread); the same tip judged without its phases, or a tip that wanders
    where no phase explains it, cannot be told apart from a 5 mm shift."""
    periodic = _reference()
    times = np.linspace(10.0, 60.0, 400)
    later = np.percentile([periodic.drift(_tip(t), *_signals(t)) for t in times], 90)
    assert 0.8 * later < periodic.resolution_mm() < min(1.5 * later, 3.0)
    assert periodic.spread_mm() > 4.0
    plain = RestReference(0.0, _tip(0.0))
    for t in np.arange(0.025, REST_WINDOW_S, 0.025):
        plain.add(float(t), _tip(float(t)), None, None)
    assert plain.resolution_mm() > 5.0  # the instantaneous form: against the stop
    wandering = _wandering()
    assert wandering.resolution_mm() > 5.0
    assert wandering.resolution_mm() == wandering.resolution_mm()  # cached, unchanged
    # too few readings, or none GUARD_S apart: unknown, the check applies as it is
    short = RestReference(0.0, _tip(0.0), None, *_signals(0.0))
    for t in (0.1, 0.2, 0.3, 0.4):
        short.add(t, _tip(t) + 20.0, *_signals(t))
    assert short.resolution_mm() == 0.0


def test_a_question_is_confirmed_only_by_a_second_press_soon_after_it() -> None:
    from icenav.recovery.drift import CONFIRM_S

    ref = _wandering()
    assert ref.asked_at is None and not ref.confirmed(10.0)
    ref.ask(10.0)
    assert ref.confirmed(10.0 + CONFIRM_S) and not ref.confirmed(10.0 + CONFIRM_S + 0.1)
    ref.ask(None)  # no clock: any later press confirms
    assert ref.confirmed(1e6) and ref.confirmed(None)


def test_the_status_line_reuses_a_resolution_until_the_readings_grow_by_a_quarter() -> None:
    """Eq. (F6) costs about a millisecond; the status line is built every control cycle
    while the reference grows, so with ``within`` it takes the value computed over at least
    that fraction of the readings; the check (the default) always takes the exact one."""
    ref = _wandering()
    first = ref.resolution_mm()
    n = ref.n_readings
    t = ref._rows[n - 1, 0]  # noqa: SLF001 - the newest reading's time
    for k in range(1, n // 10):  # 10 % more readings, far off: the exact value changes
        ref._append(t + 0.025 * k, [60.0, 0.0, 40.0], *_signals(t + 0.025 * k))  # noqa: SLF001
    assert ref.resolution_mm(within=0.8) == first
    assert ref.resolution_mm() != first

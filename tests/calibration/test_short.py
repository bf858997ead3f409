"""Tests of icenav.calibration.short: the short calibration along knob rings (the 5-point
search plus at most 100 moves), on a synthetic catheter with knob play (not the model's
form of F: a distortion of the knob frame and per-knob backlash)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.calibration.procedure import run_procedure, run_visits
from icenav.calibration.procedures import make_procedure, plan_visits
from icenav.calibration.short import (
    KNOB_RINGS,
    RING_RADII,
    ShortRingCalibration,
    fit_short_rings,
    ring_path,
    short_ring_plan,
    turn_sense,
)
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import forward
from tests.support.calibration import SyntheticCatheter, Tracker

DEG = math.pi / 180


def test_ring_path_turns_one_way_at_constant_radius() -> None:
    q = ring_path(n_stops=12)
    assert q.shape == (3 * 13, 4) and np.all(q[:, 2:] == 0.0)
    for i, r in enumerate(RING_RADII):
        ring = q[13 * i : 13 * (i + 1), :2]
        np.testing.assert_allclose(np.hypot(ring[:, 0], ring[:, 1]), r, atol=1e-12)
        np.testing.assert_allclose(ring[0], ring[-1], atol=1e-12)  # one full turn
        cross = ring[:-1, 0] * ring[1:, 1] - ring[:-1, 1] * ring[1:, 0]
        assert np.all(cross > 0.0)  # counter-clockwise
    cw = ring_path(n_stops=12, direction=-1)
    np.testing.assert_allclose(cw[:, 1], -q[:, 1], atol=1e-12)
    with pytest.raises(ConfigurationError, match="n_stops"):
        ring_path(n_stops=2)
    with pytest.raises(ConfigurationError, match="radii"):
        ring_path(radii=(2.0,))


def test_the_short_plan_stays_within_100_moves_from_rest_to_rest() -> None:
    sp = short_ring_plan()
    assert sp.plan.n <= 100 and short_ring_plan(both_ways=False).plan.n <= 100
    np.testing.assert_array_equal(sp.plan.q_motor[-1], np.zeros(4))
    rings = sp.plan.segment(KNOB_RINGS)
    assert np.all(sp.plan.n_average[rings] == 1)


def _tip_error(emap: object, cath: SyntheticCatheter, path: np.ndarray) -> float:
    """RMS distance (mm) between the tip F predicts for each command of ``path`` and the
    catheter's, driven along it from rest."""
    cath.move(np.zeros(4))
    tips = []
    for q in path:
        cath.move(q)
        tips.append(cath.pose()[:3, 3])
    m1, m2 = emap.motor_to_model_knobs(path[:, 0], path[:, 1], check=False)  # type: ignore[attr-defined]
    q_model = np.zeros((len(path), 4))
    q_model[:, 0], q_model[:, 1] = m1, m2
    pred = forward(q_model, check=False)[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum((pred - np.array(tips)) ** 2, axis=-1))))


def _driven_error(cal: ShortRingCalibration, cath: SyntheticCatheter, model: np.ndarray) -> float:
    """RMS distance (mm) of the tip from the model's along a model knob path (n, 4) driven
    from rest (a radial approach first) through :meth:`model_to_motor_path`."""
    approach = np.linspace(np.zeros(4), model[0], 9)[1:]
    path = np.vstack([approach, model])
    cmd = cal.model_to_motor_path(path)
    cath.move(np.zeros(4))
    tips = []
    for q in cmd:
        cath.move(q)
        tips.append(cath.pose()[:3, 3])
    tips = tips[approach.shape[0] :]
    want = forward(model, check=False)[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum((want - np.array(tips)) ** 2, axis=-1))))


def test_the_rings_turned_both_ways_hold_for_circles_turned_either_way() -> None:
    """Each ring turned both ways gives an F per sense, blended by the sense a path turns
    (S1): a knob circle between the rings is followed either way about as well as the
    one-way rings follow their own sense, where the one-way rings miss the other sense."""
    cath = SyntheticCatheter(r=(3 * DEG, 3 * DEG, 1 * DEG), d=1 * DEG)
    tracker = Tracker(cath)
    five = make_procedure("five_point")
    five_set = five.fit(run_procedure(five, cath.move, tracker)).calibration_set
    cals = {}
    for both in (False, True):
        cath.p = [0.0, 0.0, 0.0]
        sp = short_ring_plan(both_ways=both)
        cals[both] = fit_short_rings(
            sp, run_visits(plan_visits(sp.plan), cath.move, tracker), five_set
        )
    assert cals[True].reverse_map is not None and cals[False].reverse_map is None
    t = np.linspace(0.0, 2.0 * math.pi, 73)
    ccw = np.zeros((t.size, 4))
    ccw[:, 0], ccw[:, 1] = 40 * DEG * np.cos(t), 40 * DEG * np.sin(t)
    cw = ccw * np.array([1.0, -1.0, 1.0, 1.0])
    err = {
        (b, name): _driven_error(cals[b], cath, m)
        for b in cals
        for name, m in (("ccw", ccw), ("cw", cw))
    }
    assert err[(False, "cw")] > 4.0 * err[(False, "ccw")]  # one way: the other sense misses
    # both ways: either sense alike (about 1.4 mm), a third of the one-way rings' other
    # sense (5.0 mm); its own sense the one-way rings follow better (0.7 mm: 12 stops a
    # turn where both ways have 7 in each sense)
    assert abs(err[(True, "ccw")] - err[(True, "cw")]) < 0.2 * err[(True, "ccw")]
    assert max(err[(True, "ccw")], err[(True, "cw")]) < 0.4 * err[(False, "cw")]


def test_turn_sense_reads_counter_clockwise_clockwise_and_radial() -> None:
    t = np.linspace(0.0, math.pi, 7)
    circle = np.stack([np.cos(t), np.sin(t)], axis=-1)
    np.testing.assert_allclose(turn_sense(circle)[1:-1], 1.0)  # the ends: one-sided, chords
    np.testing.assert_allclose(turn_sense(circle[:, ::-1])[1:-1], -1.0)
    assert np.all(turn_sense(circle)[[0, -1]] > 0.9)
    ray = np.stack([np.linspace(0.0, 1.0, 5), np.zeros(5)], axis=-1)
    np.testing.assert_allclose(turn_sense(ray), 0.0, atol=1e-12)
    with pytest.raises(ConfigurationError, match="shape"):
        turn_sense(np.zeros((3, 3)))

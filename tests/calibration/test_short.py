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
    fit_short_rings,
    ring_path,
    short_ring_plan,
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
    assert sp.plan.n <= 100
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


def test_the_rings_f_follows_a_circle_turned_their_way_and_says_so_for_the_other() -> None:
    """F over the five points and the ring stops predicts the tip along a circle between
    the rings turned the rings' way much better than the 5-point F; turned the other way
    it meets the knobs' lag twice (the condition's stated assumption)."""
    cath = SyntheticCatheter(r=(3 * DEG, 3 * DEG, 1 * DEG), d=1 * DEG)
    tracker = Tracker(cath)
    five = make_procedure("five_point")
    outcome = five.fit(run_procedure(five, cath.move, tracker))
    cath.p = [0.0, 0.0, 0.0]
    sp = short_ring_plan()
    cal = fit_short_rings(
        sp, run_visits(plan_visits(sp.plan), cath.move, tracker), outcome.calibration_set
    )
    assert cal.n_moves == sp.plan.n
    t = np.linspace(0.0, 2.0 * math.pi, 73)
    ccw = np.zeros((t.size, 4))
    ccw[:, 0], ccw[:, 1] = 40 * DEG * np.cos(t), 40 * DEG * np.sin(t)
    cw = ccw * np.array([1.0, -1.0, 1.0, 1.0])
    rings_ccw = _tip_error(cal.elasticity_map, cath, ccw)
    five_ccw = _tip_error(outcome.knob_map, cath, ccw)
    rings_cw = _tip_error(cal.elasticity_map, cath, cw)
    assert rings_ccw < 0.5 * five_ccw
    assert rings_cw > 2.0 * rings_ccw

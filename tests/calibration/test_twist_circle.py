"""The spin circle: the image frame's play over the whole knob plane, read while turning."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from icenav.calibration.hysteresis import _circle_law, fit_hysteresis, hysteresis_plan
from icenav.calibration.plans import MotionPlan, Recording
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.twist_circle import (
    AGREEMENT,
    CIRCLE_KNOB,
    CIRCLE_LEAD,
    CIRCLE_STEP,
    SPIN_CIRCLE,
    _periodic_interp,
    circle_twist_readings,
    spin_circle_path,
)
from icenav.compensation.bend_play import KnobPlanePlay
from icenav.errors import ConfigurationError
from icenav.sim.plugins import make_plant

DEG = math.pi / 180.0


def test_the_spin_circle_turns_the_bend_once_round_and_back_with_the_roll_against_it() -> None:
    path = spin_circle_path()
    t = -path[:, 2]
    np.testing.assert_allclose(np.hypot(path[:, 0], path[:, 1]), CIRCLE_KNOB)
    np.testing.assert_allclose(np.arctan2(path[:, 1], path[:, 0]), np.angle(np.exp(1j * t)))
    steps = np.diff(np.concatenate([[0.0], t]))
    np.testing.assert_allclose(np.abs(steps), CIRCLE_STEP)
    n = path.shape[0] // 2
    assert np.all(steps[:n] > 0) and np.all(steps[n:] < 0)
    # each sense turns a whole turn beyond its lead-in, and the circle ends where it began
    assert t[n - 1] >= 2 * math.pi + CIRCLE_LEAD - 1e-9 and t[-1] == pytest.approx(0.0)
    assert np.all(path[:, 3] == 0.0)
    for kw in ({"knob": 0.0}, {"step": -1.0}, {"lead": 4.0}):
        with pytest.raises(ConfigurationError, match="spin circle"):
            spin_circle_path(**kw)


def _drive(family: str, seed: int) -> tuple[Any, Any, Any, Any]:
    """The circle on a family's plant: the motor path, tracked poses, the plant's own lag of
    the image frame behind the motor roll (rad) and its section's direction (rad)."""
    plant, tracker = make_plant(family, seed, "straight")
    path = spin_circle_path()
    plant.reset()
    plant.move(np.array([path[-1, 0], path[-1, 1], 0.0, 0.0]))
    poses, lag, psi = [], [], []
    for q in path:
        plant.move(q)
        m = tracker.measure_tip2base()
        poses.append(np.full((4, 4), np.nan) if m is None else m)
        s = plant.state
        lag.append(q[2] - (s.roll + s.twist))
        psi.append(math.atan2(s.effective_knobs[1], s.effective_knobs[0]))
    return path, np.array(poses), np.array(lag), np.array(psi)


@pytest.mark.parametrize(("family", "seed"), [("rate-dependent", 213), ("nonlinear-play", 211)])
def test_the_image_frame_s_play_over_the_knob_plane_is_read_on_plants_of_other_forms(
    family: str, seed: int
) -> None:
    """Development catheters of two families whose plays grow with the tendons' tension (Dahl
    friction with relaxation; Bouc-Wen tendons and Coulomb plays): the half difference
    between the two senses (TC1) is the plant's own (read from its state) within 1.1 deg RMS
    in 12 directions (3 deg at most), and it differs between psi and psi + 180 deg as the
    plant's does (which a law of period 180 deg could not hold)."""
    path, poses, lag, psi = _drive(family, seed)
    dirs, bends, total = circle_twist_readings(path, poses, None, 0.0)
    n = path.shape[0] // 2
    k = round(CIRCLE_LEAD / CIRCLE_STEP)
    truth = 0.5 * (
        _periodic_interp(dirs, psi[n + k :], lag[n + k :])
        - _periodic_interp(dirs, psi[k:n], lag[k:n])
    )
    assert np.all(np.isfinite(total)) and np.all(bends > 45 * DEG)
    assert np.sqrt(np.mean((total - truth) ** 2)) < 1.1 * DEG
    assert np.max(np.abs(total - truth)) < 3.0 * DEG
    half = dirs.size // 2
    opposite = np.abs(truth - np.roll(truth, half))
    assert np.max(opposite) > 5 * DEG
    np.testing.assert_allclose(
        total - np.roll(total, half), truth - np.roll(truth, half), atol=3.5 * DEG
    )
    # less a roll play (TC2): the twist's, never negative
    _, _, twist = circle_twist_readings(path, poses, None, 0.1)
    assert np.all(twist >= 0.0)
    assert np.mean(total - twist) == pytest.approx(0.1, abs=0.5 * DEG)


def test_a_circle_missing_half_a_sense_reads_nothing() -> None:
    path, poses, _, _ = _drive("default", 213)
    n = path.shape[0] // 2
    poses[n + 2 : n + 9] = np.nan
    dirs, bends, twist = circle_twist_readings(path, poses, None, 0.0)
    assert dirs.size == 12 and np.all(np.isnan(twist)) and np.all(np.isnan(bends))


def test_the_full_plan_s_twist_law_is_read_off_the_circle_over_the_whole_plane() -> None:
    """fit_hysteresis of a plan with the circle (the roll's sweeps straight and at one bend,
    nonlinear-play 211): the twist's law is a 360-deg law over the knob plane whose
    directions each pass through the circle's reading; the roll's plays stay the sweeps'."""
    plant, tracker = make_plant("nonlinear-play", 211, "straight")
    hplan = hysteresis_plan(joints=(2,), more_roll_bends=(), spin_circle=True)
    assert hplan.spin_circle and SPIN_CIRCLE in {s[2] for s in hplan.plan.segments}
    plant.reset()
    rec = run_visits(plan_visits(hplan.plan), plant.move, tracker)
    comp = fit_hysteresis(hplan, rec).compensator
    twist, roll = comp.twist_play, comp.roll_play
    assert isinstance(twist, KnobPlanePlay) and twist.period == 2 * math.pi
    q, poses = rec.part(SPIN_CIRCLE)
    dirs, bends, extra = circle_twist_readings(q, poses, roll, comp.joints[2].backlash)
    np.testing.assert_allclose(twist.directions, dirs)
    for d, b, e in zip(dirs, bends, extra, strict=True):
        # through the reading, within the law's bounds (B6's scale, a line's slope)
        assert twist.at(float(b), float(d)) == pytest.approx(float(e), abs=0.5 * DEG)
    # a plan without it keeps the 180-deg law of the sweeps
    assert not hysteresis_plan(joints=(2,)).spin_circle
    assert not hysteresis_plan(joints=(0, 1), spin_circle=True).spin_circle


def test_the_sweeps_law_is_kept_where_it_predicts_the_circle_and_replaced_where_not() -> None:
    """(TC3): the circle is held out from the sweeps' law; a law that predicts its readings
    within AGREEMENT RMS is kept as it is, one 1.5x too wide (here 4-6 deg) is replaced by
    the circle's 360-deg law through the readings (default twin 213, the image frame's
    whole play: no roll law)."""
    path, poses, _, _ = _drive("default", 213)
    rec = Recording(
        plan=MotionPlan.make(path, SPIN_CIRCLE, n_average=1, retries=0),
        tip2base=poses,
        attempts=np.ones(path.shape[0], dtype=np.int64),
    )
    circle = _circle_law(None, None, 0.0, rec)
    assert isinstance(circle, KnobPlanePlay) and circle.period == 2 * math.pi
    assert _circle_law(circle, None, 0.0, rec) is circle
    wide = KnobPlanePlay(
        circle.directions, tuple(x.scaled(1.5) for x in circle.laws), period=circle.period
    )
    again = _circle_law(wide, None, 0.0, rec)
    assert again is not wide and isinstance(again, KnobPlanePlay)
    b = np.radians(np.linspace(20.0, 80.0, 7))
    for d in circle.directions:
        np.testing.assert_allclose(again(b, d), circle(b, d), atol=0.5 * DEG)
    assert pytest.approx(1.0 * DEG) == AGREEMENT

"""Tests of icenav.calibration.short: the short calibration along knob rings (the 5-point
search plus at most 100 moves), on a synthetic catheter with knob play (not the model's
form of F: a distortion of the knob frame and per-knob backlash)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import ArrayLike

from icenav.calibration.plans import MotionPlan
from icenav.calibration.play_prior import make_play_prior
from icenav.calibration.procedure import run_procedure, run_visits
from icenav.calibration.procedures import make_procedure, plan_visits
from icenav.calibration.short import (
    KNOB_RINGS,
    RING_RADII,
    ROLL_CIRCLE,
    ShortRingCalibration,
    bias_circle_path,
    fit_short_bias,
    fit_short_plays,
    fit_short_rings,
    ring_path,
    short_ring_plan,
    turn_sense,
)
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay
from icenav.compensation.calibration_set import CalibrationSet
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory
from tests.support.calibration import SyntheticCatheter, Tracker, distortion

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


def test_spin_rings_turn_the_roll_against_the_knobs_and_back() -> None:
    q = ring_path(n_stops=10, both_ways=True, spin=True)
    flat = ring_path(n_stops=10, both_ways=True)
    np.testing.assert_array_equal(q[:, :2], flat[:, :2])  # the same knob stops
    for i in range(len(RING_RADII)):
        ring = q[21 * i : 21 * (i + 1)]
        knob_angle = np.unwrap(np.arctan2(ring[:, 1], ring[:, 0]))
        # phi3 = -(the knobs' angle turned), continued over the turn and back (S2)
        np.testing.assert_allclose(ring[:, 2], -knob_angle, atol=1e-9)
        assert ring[10, 2] == pytest.approx(-2.0 * math.pi) and ring[-1, 2] == pytest.approx(0.0)


def test_the_short_plan_stays_within_100_moves_from_rest_to_rest() -> None:
    sp = short_ring_plan()
    assert sp.plan.n <= 100 and short_ring_plan(both_ways=False).plan.n <= 100
    np.testing.assert_array_equal(sp.plan.q_motor[-1], np.zeros(4))
    rings = sp.plan.segment(KNOB_RINGS)
    assert np.all(sp.plan.n_average[rings] == sp.n_average)
    flat = short_ring_plan(spin=False, n_average=1)
    assert flat.plan.n == sp.plan.n and not flat.spin
    assert np.all(flat.plan.n_average[rings] == 1)
    # a finer, narrower straight sweep in the same moves; the bent sweep as it was
    fine = short_ring_plan(straight=(10 * DEG, 5 * DEG))
    assert fine.plan.n == sp.plan.n
    roll = fine.plan.q_motor[fine.plan.segment("sweep phi3"), 2]
    np.testing.assert_allclose(np.max(np.abs(roll)), 10 * DEG)
    np.testing.assert_allclose(np.max(np.abs(np.diff(roll))), 5 * DEG)
    bent = fine.plan.segment("sweep phi3, phi1 bent")
    np.testing.assert_allclose(fine.plan.q_motor[bent], sp.plan.q_motor[bent], atol=1e-12)


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


class _PlaneRollCatheter(SyntheticCatheter):
    """The synthetic catheter with a roll play of another form than any line: it grows as
    the bend to the power 2.3 and is 2.2x as wide along the RL knob as along the AP knob
    (the bend and its direction of the effective knobs)."""

    def __init__(self, level: float) -> None:
        super().__init__(r=(1 * DEG, 1 * DEG, 1 * DEG))
        self.level = level

    def extra(self, bend: ArrayLike, psi: ArrayLike) -> np.ndarray:
        return np.asarray(
            self.level * np.abs(np.asarray(bend)) ** 2.3 * (1.0 + 1.2 * np.sin(psi) ** 2)
        )

    def move(self, q: ArrayLike) -> None:
        q = np.asarray(q, dtype=np.float64)
        k = distortion(np.array(self.p[:2])[None, :])[0]
        w = self.r[2] + float(self.extra(np.hypot(*k), math.atan2(self.p[1], self.p[0])))
        for j in range(2):
            self.p[j] = min(max(self.p[j], q[j] - self.r[j]), q[j] + self.r[j])
        self.p[2] = min(max(self.p[2], q[2] - w), q[2] + w)
        self.q = q
        self.moves += 1


def test_a_play_prior_gives_the_short_calibration_the_plays_shape_over_the_knob_plane() -> None:
    """``fit_short_plays(prior=...)`` (as ``fit_short_rings`` calls it): the prior made from
    three catheters of the line (their laws, as full calibrations measure them), the short
    calibration's one bent sweep sets the level (P1). Its roll play then follows the
    catheter's over bend and direction within 15 %, where the short calibration's line is
    off by up to 2x."""
    grid = np.radians(np.arange(1.0, 131.0))
    dirs = tuple(np.arange(8) * math.pi / 8)

    def full(level: float) -> HysteresisCompensator:
        cath = _PlaneRollCatheter(level)
        laws = tuple(BendPlay("table", (), tuple(grid), tuple(cath.extra(grid, d))) for d in dirs)
        plane = KnobPlanePlay(dirs, laws)
        return HysteresisCompensator([None] * 4, roll_play=plane, twist_play=plane)

    prior = make_play_prior([full(a) for a in (0.03, 0.04, 0.05)], "line", ["a", "b", "c"])
    cath = _PlaneRollCatheter(0.06)
    sp = short_ring_plan()
    rec = run_visits(plan_visits(sp.sweeps.plan), cath.move, Tracker(cath))  # the sweeps
    with_prior = fit_short_plays(sp, rec, prior)
    lines = fit_short_plays(sp, rec)
    knob = np.radians([30.0, 50.0, 70.0])
    for psi in np.radians([0.0, 45.0, 90.0, 135.0]):
        true_bend = np.hypot(*distortion(np.stack([knob * np.cos(psi), knob * np.sin(psi)], -1)).T)
        want = cath.extra(true_bend, psi)
        got = with_prior.roll_extra(true_bend, psi)
        line = lines.roll_extra(true_bend, psi)
        np.testing.assert_allclose(got, want, rtol=0.15)
        if psi == math.radians(90.0):
            assert np.max(np.abs(line / want - 1.0)) > 0.45


class _FieldTracker(Tracker):
    """The synthetic catheter read through a field bias that stays in the base frame (2 mm
    along x, -1 mm along y: it does not turn with the roll, as the tracker's field)."""

    def measure_tip2base(self, n_average: int = 1) -> np.ndarray | None:
        pose = super().measure_tip2base(n_average)
        if pose is None:
            return None
        pose = pose.copy()
        pose[:3, 3] += (2.0, -1.0, 0.0)
        return pose


def _five_points(cath: SyntheticCatheter, tracker: Tracker) -> CalibrationSet:
    """The origin and four points beyond the rings, as the 5-point search's, at roll 0."""
    q5 = np.zeros((5, 4))
    q5[1:, :2] = 85 * DEG * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])
    five = run_visits(plan_visits(MotionPlan.make(q5, "five", 1)), cath.move, tracker)
    return CalibrationSet(q_motor=q5, tip2base=five.tip2base, method="five")


def _spin_commands(cal: ShortRingCalibration, model: np.ndarray) -> np.ndarray:
    """Motor commands (9 + n, 4) of an approach and a spin ``model`` (n, 4), as a spin is
    commanded: the twist pre-shaped, F, the roll's play inverse."""
    path = np.vstack([np.linspace(np.zeros(4), model[0], 9), model])
    comp = cal.hysteresis
    eff = cal.model_to_motor_path(comp.preshape_model(path))
    comp.reset(np.zeros(4))
    return np.asarray(comp.command_path(eff, bends=np.hypot(path[:, 0], path[:, 1])))


def test_spin_rings_calibrate_the_tip_where_the_tracker_reads_it_during_a_spin() -> None:
    """Rings at roll 0 teach F the field bias at each stop as if it turned with the knobs:
    a spin through them makes the tracked tip orbit the intended one (about sqrt 2 x the
    bias, 3.2 mm RMS). Spin rings read the tip standing where the spin holds it, so the
    tracked tip of a spin between their radii stays near the intended one: 1.1 mm, against
    0.7 mm for F's own error between these rings without any bias (the turning bias is
    interpolated between 8 stops a ring). The section's length is not fitted (the bias
    reads as length on either rings)."""
    cath = SyntheticCatheter(r=(2 * DEG, 2 * DEG, 0.0))
    model = spin_trajectory([40 * DEG, 0.0, 0.0, 0.0], 37, include_end=True).q_model
    want = forward(model[0], check=False)[:3, 3]
    err = {}
    for spin in (False, True):
        tracker = _FieldTracker(cath)
        cath.p = [0.0, 0.0, 0.0]
        five_set = _five_points(cath, tracker)
        sp = short_ring_plan((30 * DEG, 50 * DEG), 8, both_ways=False, spin=spin)
        rec = run_visits(plan_visits(sp.plan), cath.move, tracker)
        cal = fit_short_rings(sp, rec, five_set, fit_length=False)
        cmd = _spin_commands(cal, model)
        cath.p = [0.0, 0.0, 0.0]
        read = []
        for q in cmd:
            cath.move(q)
            read.append(tracker.measure_tip2base()[:3, 3])  # type: ignore[index]
        err[spin] = float(np.sqrt(np.mean(np.sum((np.array(read[9:]) - want) ** 2, -1))))
    assert err[False] > 2.5  # the orbit
    assert err[True] < 1.25


class _AffineFieldTracker(Tracker):
    """The synthetic catheter read through an affine field bias of the base frame,
    ``b(x) = b0 + B x`` (mm), which does not turn with the roll."""

    B0 = np.array([2.0, -1.0, 0.5])
    GRADIENT = np.array([[0.03, -0.02, 0.01], [0.02, 0.04, -0.02], [0.0, 0.01, 0.02]])

    def measure_tip2base(self, n_average: int = 1) -> np.ndarray | None:
        pose = super().measure_tip2base(n_average)
        if pose is None:
            return None
        pose = pose.copy()
        pose[:3, 3] += self.B0 + self.GRADIENT @ pose[:3, 3]
        return pose


def test_the_short_roll_circle_keeps_the_plan_within_100_moves() -> None:
    sp = short_ring_plan(bias_circle=True)
    assert sp.bias_circle and sp.plan.n == short_ring_plan().plan.n == 100
    np.testing.assert_array_equal(sp.rings, short_ring_plan().rings)  # the map prior's stops
    circle = sp.plan.q_motor[sp.plan.segment(ROLL_CIRCLE)]
    np.testing.assert_array_equal(circle, bias_circle_path())
    assert np.all(np.diff(circle[:, 2]) > 0.0) and circle[0, 2] == pytest.approx(72 * DEG)
    assert np.all(circle[:, 0] == pytest.approx(50 * DEG)) and np.all(circle[:, 1] == 0.0)
    bent = sp.plan.q_motor[sp.plan.segment("sweep phi3, phi1 bent"), 2]
    assert np.max(np.abs(np.diff(bent))) == pytest.approx(25 * DEG)
    assert np.max(bent) == pytest.approx(50 * DEG)
    with pytest.raises(ConfigurationError, match="n_stops"):
        bias_circle_path(n_stops=2)


def test_the_short_roll_circle_reads_the_field_bias_and_f_aims_the_true_tip() -> None:
    """F built on samples read through a field bias learns it at each ring stop as if it
    turned with the knobs: a spin makes the true tip orbit the intended one. The short roll
    circle (five stops at one bend) reads the field's bias where it varies around the rings
    (B1), and F built on the samples without it keeps the true tip of the spin close: 0.6
    against 3.4 mm RMS (two rings of 8 stops turned one way)."""
    cath = SyntheticCatheter(r=(1 * DEG, 1 * DEG, 0.0))
    model = spin_trajectory([40 * DEG, 0.0, 0.0, 0.0], 37, include_end=True).q_model
    want = forward(model[0], check=False)[:3, 3]
    err = {}
    for circle in (False, True):
        tracker = _AffineFieldTracker(cath)
        cath.p = [0.0, 0.0, 0.0]
        five_set = _five_points(cath, tracker)
        sp = short_ring_plan((30 * DEG, 50 * DEG), 8, both_ways=False, bias_circle=circle)
        rec = run_visits(plan_visits(sp.plan), cath.move, tracker)
        cal = fit_short_rings(sp, rec, five_set, fit_length=False)
        assert (cal.tracker_bias.n_samples > 0) == circle
        cmd = _spin_commands(cal, model)
        cath.p = [0.0, 0.0, 0.0]
        true = []
        for q in cmd:
            cath.move(q)
            true.append(cath.pose()[:3, 3])
        err[circle] = float(np.sqrt(np.mean(np.sum((np.array(true[9:]) - want) ** 2, -1))))
    assert err[False] > 1.5, err
    assert err[True] < 0.5 * err[False], err


def test_fit_short_bias_needs_the_circle_and_enough_tracked_stops() -> None:
    cath = SyntheticCatheter()
    sp = short_ring_plan(bias_circle=True)
    circle = sp.plan.segment(ROLL_CIRCLE)
    misses = set(range(circle.start + 1, circle.start + 1 + sp.plan.n_average[circle].sum()))
    rec = run_visits(plan_visits(sp.plan), cath.move, Tracker(cath, misses))
    assert fit_short_bias(sp, rec).n_samples == 0  # no stop tracked: no bias
    plain = short_ring_plan()
    rec = run_visits(plan_visits(plain.plan), cath.move, Tracker(cath))
    assert fit_short_bias(plain, rec).n_samples == 0

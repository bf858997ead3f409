"""Tests of icenav.calibration.hysteresis: identification of the per-joint play models, on
data of the model's own form and of another form (a distributed, Preisach-like play)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.calibration.hysteresis import fit_hysteresis, hysteresis_plan, identify, sweep_path
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.compensation.hysteresis import JointHysteresis
from icenav.errors import ConfigurationError
from tests.support.calibration import SyntheticCatheter, Tracker

DEG = math.pi / 180


@pytest.mark.parametrize(
    ("r_deg", "slope", "d_deg", "c_deg"),
    [(3.0, 0.0, 2.0, 0.5), (1.0, 0.0, 4.0, -0.5), (0.5, 0.06, 1.5, 0.3), (2.0, 0.12, 0.5, 0.0)],
)
def test_identify_recovers_a_known_transmission(
    r_deg: float, slope: float, d_deg: float, c_deg: float
) -> None:
    m = JointHysteresis(
        backlash=r_deg * DEG, backlash_slope=slope, dead_zone=d_deg * DEG, centre=c_deg * DEG
    )
    x = sweep_path(60 * DEG, 1.5 * DEG)
    z = m.simulate(x, p0=0.0)
    rng = np.random.default_rng(int(10 * r_deg + d_deg))
    y = 0.02 + 0.9 * z - 0.05 * z**3 + rng.normal(0, 0.1 * DEG, z.shape)
    y[::17] = np.nan  # missing samples are skipped
    fit = identify(x, y)
    assert fit.model.backlash == pytest.approx(r_deg * DEG, abs=0.25 * DEG)
    assert fit.model.backlash_slope == pytest.approx(slope, abs=0.01)
    assert fit.model.dead_zone == pytest.approx(d_deg * DEG, abs=0.25 * DEG)
    assert fit.model.centre == pytest.approx(c_deg * DEG, abs=0.25 * DEG)
    assert fit.gain[1] == pytest.approx(0.9, abs=0.05)
    assert fit.rms < 0.2 * DEG


def test_identify_backlash_only() -> None:
    m = JointHysteresis(backlash=2 * DEG)
    x = sweep_path(60 * DEG, 1.5 * DEG)
    y = 1.0 * m.simulate(x, p0=0.0) + 0.3
    fit = identify(x, y, cubic=False, with_dead_zone=False)
    assert fit.model.backlash == pytest.approx(2 * DEG, abs=0.13 * DEG)
    assert fit.model.dead_zone == 0.0


def _distributed_play(x: np.ndarray, widths: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """A Prandtl-Ishlinskii plant: a weighted sum of play operators of graded widths (rounded
    loops), not the model's single play with a dead-zone."""
    out = np.zeros_like(x)
    for r, w in zip(widths, weights, strict=True):
        p, ys = 0.0, []
        for xi in x:
            p = min(max(p, xi - r), xi + r)
            ys.append(p)
        out += w * np.array(ys)
    return out


def test_identify_on_a_distributed_play_matches_its_loop() -> None:
    """On a plant of another form the single play cannot be exact, but the identified model
    must reproduce the loop's width at its centre (what the compensation inverts) and leave a
    residual well below the loop it explains."""
    x = sweep_path(60 * DEG, 1.5 * DEG)
    widths = np.linspace(0.5, 6.0, 12) * DEG
    weights = np.full(12, 1.0 / 12)
    y = 0.9 * _distributed_play(x, widths, weights)
    fit = identify(x, y)
    z = fit.model.simulate(x, p0=0.0)
    # loop width of plant and model at x = 0 (the two passes of the sweep through zero)
    zero = np.flatnonzero(np.abs(x) < 1e-9)[1:3]
    plant_width = abs(float(np.diff(y[zero])[0]))
    g0, g1, g3 = fit.gain
    model_out = g0 + g1 * z + g3 * z**3
    model_width = abs(float(np.diff(model_out[zero])[0]))
    assert plant_width > 2.0 * DEG  # there is a loop to explain
    assert model_width == pytest.approx(plant_width, rel=0.35)
    assert fit.rms < 0.25 * plant_width


def test_identify_rejects_bad_input() -> None:
    with pytest.raises(ConfigurationError, match="need 0 < step < amplitude"):
        sweep_path(0.1, 0.2)
    with pytest.raises(ConfigurationError, match=">= 10 samples"):
        identify([0.0, 1.0], [0.0, 1.0])


def test_the_sweeps_identify_the_synthetic_catheters_plays() -> None:
    """The sweeps' plan recorded through the runner and fitted: each joint's play and
    dead-zone, and the roll's play growing with the bend."""
    cath = SyntheticCatheter(r=(3 * DEG, 2 * DEG, 1.5 * DEG), d=2 * DEG, roll_per_bend=0.06)
    hplan = hysteresis_plan()
    ident = fit_hysteresis(hplan, run_visits(plan_visits(hplan.plan), cath.move, Tracker(cath)))
    assert cath.moves == hplan.plan.n == ident.n_moves
    # the roll's play grows with the bend (per rad of the tracked bend), the knobs' does not
    assert ident.compensator.roll_play_per_bend == pytest.approx(0.06, abs=0.015)
    assert ident.compensator.knob_play_per_bend < 0.01
    assert ident.compensator.twist_play_per_bend < 0.015  # no distal twist here
    m1, m2, m3, m4 = ident.compensator.joints
    assert m1 is not None and m2 is not None and m3 is not None and m4 is None
    assert m1.backlash == pytest.approx(3 * DEG, abs=0.3 * DEG)
    assert m2.backlash == pytest.approx(2 * DEG, abs=0.3 * DEG)
    assert m1.dead_zone == pytest.approx(2 * DEG, abs=0.3 * DEG)
    assert m3.backlash == pytest.approx(1.5 * DEG, abs=0.3 * DEG)
    assert m3.dead_zone == 0.0


def test_the_roll_play_law_is_measured_on_a_plant_of_another_form() -> None:
    """Data from the nonlinear-play family (roll play growing with bend x tension, about the
    bend squared, not our model's form): the law chosen by held-out residual predicts the
    plant's own play at bends between and beyond the sweeps, where the two-point line of
    the straight and the 50 deg sweep misses it."""
    from icenav.compensation.bend_play import BendPlay
    from icenav.sim.families import NonlinearPlayPlant
    from icenav.sim.tracker import EMTracker

    plant = NonlinearPlayPlant(seed=210)
    hplan = hysteresis_plan(joints=(2,), play_directions=())  # the AP knob's law alone
    plant.reset()
    comp = fit_hysteresis(
        hplan, run_visits(plan_visits(hplan.plan), plant.move, EMTracker(plant, seed=210))
    ).compensator
    assert comp.roll_play is not None and comp.roll_play.form != "linear"
    line = BendPlay.linear(comp.roll_play_per_bend)
    plant.reset()
    straight = plant.roll_play()
    assert comp.twist_play is not None and len(comp.twist_play.bends) == 3  # none saturated
    for knob in (40.0, 60.0, 75.0):
        pose = plant.move([math.radians(knob), 0.0, 0.0, 0.0])
        bend = math.acos(float(pose[2, 2]))
        truth = plant.roll_play() - straight
        err = abs(comp.roll_play.at(bend) - truth)
        assert err < math.radians(1.0)
        if knob < 75.0:
            assert err < 0.5 * abs(line.at(bend) - truth)
        # the twist play too, up to the largest bend swept (about 30 deg there; read at
        # 9 deg when the sweep was narrower than the plays together)
        assert abs(comp.twist_play.at(bend) - plant.twist_play()) < math.radians(1.5)


def test_the_plays_over_the_knob_plane_are_measured_on_a_plant_of_another_form() -> None:
    """Data from the nonlinear-play family (plays growing with the total tendon tension, so
    with the bend's direction as well as its size): the roll's play read by the direction
    of the bend matches the plant's own in the three further directions swept and between
    them, where the AP knob's law alone misses it by more."""
    from icenav.compensation.bend_play import KnobPlanePlay
    from icenav.sim.families import NonlinearPlayPlant
    from icenav.sim.tracker import EMTracker

    plant = NonlinearPlayPlant(seed=211)
    hplan = hysteresis_plan(joints=(2,), roll_step=10 * DEG)
    assert len(hplan.play_directions) == 3
    plant.reset()
    comp = fit_hysteresis(
        hplan, run_visits(plan_visits(hplan.plan), plant.move, EMTracker(plant, seed=211))
    ).compensator
    plane = comp.roll_play
    assert isinstance(plane, KnobPlanePlay) and plane.directions[0] == 0.0
    plant.reset()
    straight = plant.roll_play()
    ours, ap_only = [], []
    for psi_deg in (45.0, 70.0, 90.0, 135.0):
        psi = math.radians(psi_deg)
        pose = plant.move([50 * DEG * math.cos(psi), 50 * DEG * math.sin(psi), 0.0, 0.0])
        bend = math.acos(float(pose[2, 2]))
        truth = plant.roll_play() - straight
        ours.append(abs(plane.at(bend, psi) - truth))
        ap_only.append(abs(plane.laws[0].at(bend) - truth))
        plant.reset()
    assert max(ours) < math.radians(1.5)  # measured 0.2-0.8 deg
    assert max(ap_only) > 3.0 * max(ours)  # measured 1.3-6.7 deg


def test_a_play_reading_at_the_search_bound_is_dropped() -> None:
    """A roll sweep narrower than the play (plus the margin) cannot read it: the reading at
    the search bound is dropped from the law, the others kept; a sweep widened with the
    bend reads every one (data of a single play growing with the knob, 0.5 rad/rad)."""
    cath = SyntheticCatheter(r=(0.0, 0.0, 1.5 * DEG), roll_per_bend=0.5)
    narrow = hysteresis_plan(
        joints=(2,), roll_amplitude=40 * DEG, roll_widening=0.0, play_directions=()
    )
    comp = fit_hysteresis(narrow, run_visits(plan_visits(narrow.plan), cath.move, Tracker(cath)))
    play = comp.compensator.roll_play
    assert play is not None and len(play.bends) == 2  # 37.5 deg of play at 75 deg: dropped
    np.testing.assert_allclose(play.extra, np.radians([12.5, 25.0]), atol=1.0 * DEG)
    cath = SyntheticCatheter(r=(0.0, 0.0, 1.5 * DEG), roll_per_bend=0.5)
    wide = hysteresis_plan(
        joints=(2,), roll_amplitude=40 * DEG, roll_widening=0.8, play_directions=()
    )
    comp = fit_hysteresis(wide, run_visits(plan_visits(wide.plan), cath.move, Tracker(cath)))
    play = comp.compensator.roll_play
    assert play is not None and len(play.bends) == 3
    np.testing.assert_allclose(play.extra, np.radians([12.5, 25.0, 37.5]), atol=1.0 * DEG)


def test_the_full_plan_sweeps_the_roll_bent_in_four_directions() -> None:
    """The AP knob's bends and one bend in each further direction (the knobs along it); the
    short plan none; bad directions refused."""
    hplan = hysteresis_plan(joints=(2,))
    assert hplan.play_directions == pytest.approx(np.radians([45.0, 90.0, 135.0]))
    for psi in (45, 90, 135):
        knobs = hplan.plan.q_motor[hplan.plan.segment(f"sweep phi3, bent {psi} deg")][:, :2]
        want = hplan.bend * np.array([math.cos(math.radians(psi)), math.sin(math.radians(psi))])
        np.testing.assert_allclose(knobs, np.tile(want, (len(knobs), 1)), atol=1e-12)
    assert hysteresis_plan(joints=(2,), more_roll_bends=()).play_directions == ()
    assert hysteresis_plan(joints=(0, 1)).play_directions == ()
    with pytest.raises(ConfigurationError, match=r"play_directions must be in \(0, 180\)"):
        hysteresis_plan(play_directions=(0.0,))
    with pytest.raises(ConfigurationError, match="ascending"):
        hysteresis_plan(play_directions=(1.0, 0.5))

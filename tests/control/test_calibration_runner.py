"""The calibration runner: a procedure's visits in the loop, as a bench procedure (back to
the start, not in the roadmap), and the preview the console confirms with."""

from __future__ import annotations

import math

import numpy as np

from icenav.apps.wiring import make_sim_controller
from icenav.calibration.procedures import make_procedure
from icenav.control.calibration_runner import preview
from icenav.control.config import ControllerConfig
from icenav.control.modes import Mode


def test_five_point_returns_to_the_start_and_keeps_its_states_out_of_the_roadmap() -> None:
    session = make_sim_controller(seed=103, imaging=False)
    ctrl = session.controller
    try:
        for _ in range(50):  # the operator drives somewhere first
            ctrl.jog([math.radians(40), math.radians(-20), 0.3, 2.0], "knob")
            ctrl.step()
        ctrl.run_cycles(30)
        start = ctrl.robot.read_state().q.copy()
        vertices = ctrl.roadmap.vertices().copy()
        ticket = ctrl.start_calibration("five_point")
        state = ctrl.run_until(lambda s: s.mode is Mode.IDLE and s.cycle > 5, 40000)
        ctrl.run_cycles(3)  # the fit is installed by the loop
        result = ticket.final(timeout=0)
        assert result.outcome.value == "done", result.reason
        assert "residual" in result.reason and "compensation on" in result.reason
        np.testing.assert_allclose(ctrl.robot.read_state().q, start, atol=1e-9)  # back
        assert state.progress is None
        # the roadmap holds what the operator drove: no calibration state was recorded (at
        # most the start itself, where the operator's last state had been merged)
        after = ctrl.roadmap.vertices()
        np.testing.assert_array_equal(after[: len(vertices)], vertices)
        assert len(after) - len(vertices) <= 1
        np.testing.assert_allclose(
            after[len(vertices) :], start[np.newaxis].repeat(len(after) - len(vertices), 0)
        )
        assert ctrl.roadmap.n_edges > 0
    finally:
        session.close()


def test_preview_counts_the_visits_and_the_time_at_the_controller_speeds() -> None:
    cfg = ControllerConfig()
    proc = make_procedure("dense")
    pv = preview(
        proc,
        np.zeros(4),
        np.asarray(cfg.max_velocity),
        settle_s=cfg.plan_settle_s,
        ramp_s=cfg.calibration_ramp_s,
        dt=cfg.dt,
    )
    assert pv.n_readings == 361 and pv.n_visits == 363
    assert pv.max_knob_rad == np.radians(90.0)
    # each of the 360 moves between grid points is at least 10 deg at half the knob speed
    assert pv.duration_s > 360 * math.radians(10) / (0.5 * cfg.max_velocity[0])
    text = pv.describe()
    assert "bench procedure" in text and "not recorded in the roadmap" in text and "min" in text

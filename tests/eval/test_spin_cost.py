"""The calibrations' robot time: the runner's own estimate over the procedures' own visits."""

from __future__ import annotations

from dataclasses import replace

import pytest

from icenav.calibration.catheter import catheter_plan
from icenav.control.config import ControllerConfig
from icenav.eval import spin_cli
from icenav.eval.spin_cost import calibration_costs, format_costs, short_calibration_cost


def test_the_costs_count_the_procedures_visits_and_time_them_at_the_stated_speeds() -> None:
    dense, five, ours = calibration_costs()
    assert dense.n_readings == 361  # the paper's 19 x 19 raster
    assert ours.n_moves == catheter_plan().plan.n
    cfg = ControllerConfig()
    for c in (dense, five, ours):
        # every reading waits the settling time; every move takes at least its ramp
        assert c.robot_s > c.n_readings * cfg.plan_settle_s + c.n_moves * cfg.calibration_ramp_s
    fast = replace(cfg, max_velocity=tuple(2.0 * v for v in cfg.max_velocity))
    (ours_fast,) = calibration_costs(("dense+hysteresis",), fast)
    assert ours_fast.n_moves == ours.n_moves and ours_fast.robot_s < ours.robot_s
    assert "dense+hysteresis" in format_costs([dense, five, ours])


def test_the_command_line_prints_them(capsys: pytest.CaptureFixture[str]) -> None:
    assert spin_cli.main(["--costs"]) == 0
    out = capsys.readouterr().out
    assert "five_point" in out and "min" in out


def test_the_short_calibration_is_the_5_points_and_at_most_100_moves() -> None:
    (five,) = calibration_costs(("five_point",))
    short = short_calibration_cost()
    assert five.n_readings == 10  # the paper's 5 points, two readings each on the model
    assert 0 < short.n_moves - five.n_moves <= 100
    assert five.robot_s < short.robot_s < 0.2 * calibration_costs(("dense+hysteresis",))[0].robot_s
    rings = short_calibration_cost(rings=True)
    assert rings.kind == "short+rings" and 0 < rings.n_moves - five.n_moves <= 100
    # with the short roll circle: the same moves, its one long roll turn back costs seconds
    circle = short_calibration_cost(rings=True, bias_circle=True)
    assert circle.kind == "short+rings+prior" and circle.n_moves == rings.n_moves
    assert rings.robot_s < circle.robot_s < rings.robot_s + 30.0


def test_ours_is_under_10_minutes_of_robot_time() -> None:
    (ours,) = calibration_costs(("dense+hysteresis",))
    assert ours.robot_s < 600.0

"""The published state: its drawing data is computed when first read, and is the shape of
the cycle that published it, whenever it is read."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from icenav.control.config import ControllerConfig
from icenav.control.controller import Controller
from icenav.control.modes import Mode
from icenav.control.state import ControllerState
from icenav.devices.robot import RobotStatus
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.geometry.kinematics import backbone


def test_the_backbone_read_later_is_the_one_of_the_cycle_that_published_it() -> None:
    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    for _ in range(20):
        ctrl.jog([0.5, -0.4, 0.3, 2.0], "knob")
        ctrl.step()
    early = ctrl.snapshot()
    for _ in range(40):  # the robot moves on before anyone reads the early state
        ctrl.jog([0.5, -0.4, 0.3, 2.0], "knob")
        ctrl.step()
    late = ctrl.snapshot()
    assert not np.allclose(early.q_model, late.q_model)
    n = ctrl.config.backbone_points
    for state in (late, early):
        expected = backbone(state.q_model, ctrl.config.geometry, n).points_in_base
        got = state.backbone_model
        assert got is not None and got.shape == (n, 3)
        np.testing.assert_allclose(got, expected, atol=1e-12)
        assert state.backbone_model is got  # computed once, then kept


def test_a_state_given_values_keeps_them_and_stays_frozen() -> None:
    points = np.zeros((3, 3))
    state = ControllerState(
        0.0, 0, Mode.IDLE, RobotStatus.ENABLED, np.zeros(4), np.zeros(4), np.eye(4),
        backbone_model=points,
    )  # fmt: skip
    assert state.backbone_model is points and state.backbone_true is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        state.backbone_model = None  # type: ignore[misc]
    copy = dataclasses.replace(state, message="x")
    assert copy.backbone_model is points and copy.message == "x"

"""SimulatedRobot: the RobotBackend protocol, the status table, limits, faults."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.devices.robot import TRANSITIONS, RobotBackend, RobotStatus
from icenav.devices.sim_robot import CommandStepError, IdealPlant, Plant, SimulatedRobot
from icenav.errors import (
    DriveFaultError,
    EmergencyStopError,
    HardwareError,
    JointLimitError,
)
from icenav.geometry.kinematics import forward


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_implements_the_protocols() -> None:
    robot = SimulatedRobot(IdealPlant())
    assert isinstance(robot, RobotBackend)
    assert isinstance(IdealPlant(), Plant)


def test_drives_the_physics_plant() -> None:
    from icenav.sim import CatheterPlant

    plant = CatheterPlant(seed=0)
    assert isinstance(plant, Plant)
    robot = SimulatedRobot(plant)
    robot.enable()
    p0 = robot.tip2base[:3, 3].copy()
    q = np.array([0.5, 0.0, 0.0, 0.0])
    for s in np.linspace(0, 1, 30)[1:]:
        robot.command_position(s * q)
    model = forward(q)
    # the physics catheter bends, but not exactly as the constant-curvature model says
    assert np.linalg.norm(robot.tip2base[:3, 3] - p0) > 5.0
    assert np.linalg.norm(robot.tip2base[:3, 3] - model[:3, 3]) > 1e-3


def test_commands_move_the_ideal_plant() -> None:
    clock = FakeClock()
    robot = SimulatedRobot(IdealPlant(), clock=clock)
    with pytest.raises(HardwareError, match="not enabled"):
        robot.command_position([0, 0, 0, 0])
    robot.enable()
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform([-1.5, -1.5, -4, -50], [1.5, 1.5, 4, 50])
        robot.command_position(q)
        clock.t += 0.01
        state = robot.read_state()
        np.testing.assert_array_equal(state.q, q)
        assert state.timestamp == clock.t and state.status is RobotStatus.ENABLED
        np.testing.assert_allclose(robot.tip2base, forward(q), atol=1e-12)
    with pytest.raises(JointLimitError, match="phi1"):
        robot.command_position([2.0, 0, 0, 0])


def test_max_step_refuse_or_clip() -> None:
    robot = SimulatedRobot(IdealPlant(), max_step=[0.01, 0.01, 0.01, 0.1])
    robot.enable()
    robot.command_position([0.01, 0, 0, 0.1])
    with pytest.raises(CommandStepError, match="d4 by 0.5 mm"):
        robot.command_position([0.01, 0, 0, 0.6])
    np.testing.assert_array_equal(robot.read_state().q, [0.01, 0, 0, 0.1])
    clip = SimulatedRobot(IdealPlant(), max_step=[0.01, 0.01, 0.01, 0.1], on_excess="clip")
    clip.enable()
    clip.command_position([0.5, 0, 0, -3.0])
    np.testing.assert_allclose(clip.read_state().q, [0.01, 0, 0, -0.1])
    assert clip.excess_count == 1 and "clipped" in clip.read_state().message


def test_status_follows_the_transition_table() -> None:
    events = ["enable", "disable", "estop", "reset_fault", "fault"]
    for (start, event), nxt in TRANSITIONS.items():
        robot = SimulatedRobot(IdealPlant())
        # drive the robot into `start`
        if start is RobotStatus.ENABLED:
            robot.enable()
        elif start is RobotStatus.FAULT:
            robot.inject_fault("x")
        elif start is RobotStatus.ESTOP:
            robot.estop()
        assert robot.status is start
        {
            "enable": robot.enable,
            "disable": robot.disable,
            "estop": robot.estop,
            "reset_fault": robot.reset_fault,
            "fault": lambda r=robot: r.inject_fault("y"),
        }[event]()
        assert robot.status is nxt
    # refused transitions: not in the table
    for status in RobotStatus:
        for event in events:
            if (status, event) not in TRANSITIONS:
                robot = SimulatedRobot(IdealPlant())
                if status is RobotStatus.FAULT:
                    robot.inject_fault("x")
                elif status is RobotStatus.ESTOP:
                    robot.estop()
                elif status is RobotStatus.ENABLED:
                    robot.enable()
                with pytest.raises(HardwareError, match="not allowed"):
                    {
                        "enable": robot.enable,
                        "disable": robot.disable,
                        "estop": robot.estop,
                        "reset_fault": robot.reset_fault,
                        "fault": lambda r=robot: r.inject_fault("z"),
                    }[event]()
                assert robot.status is status


def test_faults_and_estop_refuse_motion_until_reset() -> None:
    robot = SimulatedRobot(IdealPlant())
    robot.enable()
    robot.inject_fault("following error on phi2")
    with pytest.raises(DriveFaultError, match="following error"):
        robot.command_position([0, 0, 0, 0])
    assert robot.read_state().message == "following error on phi2"
    robot.estop()
    with pytest.raises(EmergencyStopError, match="e-stopped"):
        robot.command_position([0, 0, 0, 0])
    robot.reset_fault()
    assert robot.status is RobotStatus.DISABLED
    robot.enable()
    robot.command_position([0.1, 0, 0, 1.0])
    robot.home()
    np.testing.assert_array_equal(robot.read_state().q, np.zeros(4))
    robot.close()
    assert robot.status is RobotStatus.DISABLED

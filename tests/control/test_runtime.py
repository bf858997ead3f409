"""The loop never dies; the supervisor e-stops a loop that stops advancing."""

from __future__ import annotations

import threading

import numpy as np

from icenav.control.config import ControllerConfig
from icenav.control.controller import Controller
from icenav.control.modes import Mode
from icenav.devices.robot import RobotStatus
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot


class Breaking(SimulatedRobot):
    """A robot whose encoder read raises once (a bug or a driver that vanished)."""

    def __init__(self) -> None:
        super().__init__(IdealPlant())
        self.fail = False

    def read_state(self):  # type: ignore[no-untyped-def]
        if self.fail:
            self.fail = False
            raise ZeroDivisionError("driver bug (injected)")
        return super().read_state()


def test_an_exception_in_a_cycle_ends_in_fault_and_reset_works() -> None:
    robot = Breaking()
    ctrl = Controller(robot, ControllerConfig())
    ctrl.jog([0.5, 0, 0, 0], "knob")
    ctrl.run_cycles(10)
    robot.fail = True
    state = ctrl.run_cycles(3)
    assert state.mode is Mode.FAULT and robot.status is RobotStatus.ESTOP  # quick-stopped
    assert "ZeroDivisionError: driver bug (injected)" in state.message
    ticket = ctrl.reset_fault()
    ctrl.step()
    assert ticket.final(timeout=0).outcome.value == "done" and ctrl.mode is Mode.IDLE
    ctrl.jog([0.5, 0, 0, 0], "knob")
    before = robot.read_state().q.copy()
    ctrl.run_cycles(5)
    assert not np.array_equal(robot.read_state().q, before)  # it drives again


class Hanging(SimulatedRobot):
    """A robot whose command call blocks until released (a stuck driver call)."""

    def __init__(self) -> None:
        super().__init__(IdealPlant())
        self.hang = threading.Event()
        self.release = threading.Event()
        self.entered = threading.Event()

    def command_position(self, q_motor):  # type: ignore[no-untyped-def]
        if self.hang.is_set():
            self.entered.set()
            self.release.wait(10.0)
        super().command_position(q_motor)


def test_the_supervisor_estops_a_loop_that_stops_advancing() -> None:
    robot = Hanging()
    ctrl = Controller(robot, ControllerConfig(stall_estop_s=0.2, plan_in_process=False))
    stopped = threading.Event()
    ctrl.add_listener(lambda s: stopped.set() if s.mode is Mode.ESTOP else None)
    ctrl.start()
    try:
        robot.hang.set()
        for _ in range(3):
            ctrl.jog([0.5, 0, 0, 0], "knob")
        assert robot.entered.wait(10.0)  # the loop is stuck inside the robot call
        assert ctrl.machine.halted is False or ctrl.mode is Mode.ESTOP
        robot.release.set() if stopped.wait(0.0) else None
        # the supervisor e-stops from its own thread while the loop hangs
        deadline_cycles = ctrl.heartbeat
        assert _wait_for(lambda: ctrl.mode is Mode.ESTOP)
        assert ctrl.heartbeat == deadline_cycles  # it did so while the loop was stuck
        robot.release.set()
        assert stopped.wait(10.0)
        assert "control loop stalled" in ctrl.snapshot().message
        assert robot.status is RobotStatus.ESTOP
    finally:
        robot.release.set()
        ctrl.shutdown()


def _wait_for(predicate, timeout_s: float = 10.0) -> bool:  # type: ignore[no-untyped-def]
    done = threading.Event()

    def poll() -> None:
        while not done.wait(0.01):
            if predicate():
                return

    t = threading.Thread(target=poll)
    t.start()
    t.join(timeout_s)
    done.set()
    return bool(predicate())

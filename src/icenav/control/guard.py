"""The robot behind one lock: an e-stop that acts at once and is never undone by a command or
a reset that was under way when it came.

Every call the control loop makes that can move the robot or lift a stop (a position
command, a reset) runs under :attr:`RobotGuard.lock` and first checks the mode machine. The
e-stop, from any thread:

1. stops the drives at once (``robot.estop()``, whatever the loop is doing);
2. puts the mode machine in ESTOP (no command is sent from then on: the check in step 1 of
   :meth:`RobotGuard.send` sees it);
3. takes the lock (so any robot call in flight has returned) and e-stops the robot again, so
   a command or a reset that raced with step 1 cannot leave the robot enabled.

When :meth:`RobotGuard.estop` returns, the robot is in ESTOP and nothing moves it until a
reset asked after the e-stop.
"""

from __future__ import annotations

import threading

import numpy as np

from icenav._typing import Array
from icenav.control.modes import ModeMachine
from icenav.devices.robot import RobotBackend, RobotStatus
from icenav.errors import IcenavError

__all__ = ["RobotGuard"]


class RobotGuard:
    """The robot, the mode machine and the lock that orders them (see the module docstring).

    Parameters
    ----------
    robot : RobotBackend
        The robot.
    machine : ModeMachine
        The controller's mode machine.
    lock_timeout_s : float
        How long an e-stop waits for a robot call in flight before it reports it (s); the
        drives were stopped in step 1 already.
    """

    def __init__(
        self, robot: RobotBackend, machine: ModeMachine, lock_timeout_s: float = 2.0
    ) -> None:
        self.robot = robot
        self.machine = machine
        self.lock = threading.RLock()
        self.lock_timeout_s = float(lock_timeout_s)

    def estop(self, cause: str, seq: int) -> str:
        """Emergency stop (any thread). Returns "" or what went wrong on the way (the mode
        is ESTOP in any case)."""
        problems = []
        try:
            self.robot.estop()
        except Exception as exc:  # a dead adapter must not keep the mode from ESTOP
            problems.append(f"robot.estop() raised {type(exc).__name__}: {exc}")
        self.machine.estop(cause, seq)
        if self.lock.acquire(timeout=self.lock_timeout_s):
            try:
                self.robot.estop()
            except Exception as exc:
                problems.append(f"robot.estop() raised {type(exc).__name__}: {exc}")
            finally:
                self.lock.release()
        else:
            problems.append(f"a robot call did not return within {self.lock_timeout_s:g} s")
        return "; ".join(dict.fromkeys(problems))

    def halt(self, cause: str) -> str:
        """FAULT with the robot quick-stopped (the loop's answer to an exception); returns ""
        or what went wrong stopping the robot."""
        self.machine.fault(cause)
        try:
            with self.lock:
                self.robot.estop()
        except Exception as exc:
            return f"robot.estop() raised {type(exc).__name__}: {exc}"
        return ""

    def send(self, q_motor: Array) -> bool:
        """Command ``q_motor`` unless the machine is halted; False when not sent because of
        a halt (the robot refused it because it is e-stopped or faulted). Other refusals of
        the robot (a joint limit, a step too large) are raised."""
        with self.lock:
            if self.machine.halted:
                return False
            try:
                self.robot.command_position(q_motor)
            except IcenavError:
                if self.robot.status in (RobotStatus.ESTOP, RobotStatus.FAULT):
                    return False  # the stop came first; the next read of the robot says why
                raise
            return True

    def hold(self) -> None:
        """Controlled stop: hold the current position (stays enabled)."""
        with self.lock:
            if not self.machine.halted:
                self.robot.stop()

    def reset(self, seq: int) -> tuple[str | None, Array | None]:
        """Reset FAULT / ESTOP for a reset asked at ``seq``: ``(None, q)`` when the robot is
        enabled again, holding ``q``; ``(reason, None)`` when refused. A robot that cannot be
        reset raises (its error names the drive)."""
        with self.lock:
            refused = self.machine.check(seq)
            if refused is not None:
                return refused, None
            try:
                self.robot.reset_fault()
                self.robot.enable()
            except IcenavError:
                # an e-stop from another thread stopped the robot between the two calls
                # (its step 1 takes no lock): the reset lost the race, it did not fail
                refused = self.machine.check(seq)
                if refused is None:
                    raise
                return refused, None
            q = np.array(self.robot.read_state().q, dtype=np.float64)
            refused = self.machine.reset(seq)
            if refused is not None:  # an e-stop came while the robot was reset
                self.robot.estop()
                return refused, None
            return None, q

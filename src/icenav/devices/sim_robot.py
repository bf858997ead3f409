"""A simulated robot: a :class:`~icenav.devices.robot.RobotBackend` around a catheter plant.

The motor drives are ideal position servos (the commanded motor state is reached within the
cycle); everything the catheter does with it is the plant's business. The plant is any
object with ``move(q_motor) -> tip2base`` and ``reset(q_motor=None)`` (:class:`Plant`):
the physics twin ``icenav.sim.CatheterPlant`` or :class:`IdealPlant` (the
constant-curvature model itself: an "ideal catheter" with no friction, slack or backlash).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._validation import JOINT_NAMES, JOINT_UNITS, check_joint_state
from icenav.devices.robot import TRANSITIONS, JointState, RobotStatus
from icenav.errors import (
    CommandStepError,
    DriveFaultError,
    EmergencyStopError,
    HardwareError,
    InvalidValueError,
)
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = ["CommandStepError", "IdealPlant", "Plant", "SimulatedRobot"]


@runtime_checkable
class Plant(Protocol):
    """What the simulated robot drives: motor joint state in, true tip pose out."""

    def move(self, q_motor: ArrayLike) -> NDArray[np.float64]:
        """Drive the knobs/roll/translation to ``q_motor`` (rad, rad, rad, mm); return the
        (4, 4) tip2base pose (mm) the catheter settles at."""
        ...

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        """Reset the plant's internal state (slack, wind-up, ...) at ``q_motor`` (or 0)."""
        ...


class IdealPlant:
    """The constant-curvature model as a plant: tip2base = forward(q_motor)."""

    def __init__(self, geometry: CatheterGeometry = DEFAULT_GEOMETRY) -> None:
        self.geometry = geometry
        self.q = np.zeros(4)

    def move(self, q_motor: ArrayLike) -> NDArray[np.float64]:
        """Pose at ``q_motor`` (4,) rad, rad, rad, mm; returns (4, 4) tip2base (mm)."""
        self.q = np.array(q_motor, np.float64)
        return forward(self.q, self.geometry, check=False)

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        """Nothing to reset in an ideal catheter except the position."""
        self.q = np.zeros(4) if q_motor is None else np.array(q_motor, np.float64)


class SimulatedRobot:
    """Simulated robot backend (implements :class:`icenav.devices.robot.RobotBackend`).

    Parameters
    ----------
    plant : Plant
        The simulated catheter.
    limits : ndarray, shape (4, 2), optional
        Motor joint limits (rad, rad, rad, mm); default: the plant's geometry's limits, or
        the default geometry's.
    max_step : array-like, shape (4,), optional
        Largest allowed change per command of each joint (rad, rad, rad, mm); default
        unlimited. A larger jump raises :class:`CommandStepError` (``on_excess="refuse"``)
        or is clipped to the limit and reported in ``message`` and ``excess_count``
        (``on_excess="clip"``).
    clock : callable, optional
        Returns the time (s); default ``time.monotonic``.
    """

    def __init__(
        self,
        plant: Plant,
        *,
        limits: ArrayLike | None = None,
        max_step: ArrayLike | None = None,
        on_excess: str = "refuse",
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.plant = plant
        if limits is None:
            geometry = getattr(plant, "geometry", DEFAULT_GEOMETRY)
            limits = geometry.joint_limits
        lim = np.array(limits, np.float64)
        if lim.shape != (4, 2) or np.any(lim[:, 0] >= lim[:, 1]):
            raise InvalidValueError(f"limits must be (4, 2) with lower < upper, got {lim!r}")
        self.limits = lim
        self.max_step = None if max_step is None else np.array(max_step, np.float64).reshape(4)
        if self.max_step is not None and np.any(self.max_step <= 0):
            raise InvalidValueError(f"max_step must be > 0 per joint, got {self.max_step}")
        if on_excess not in ("refuse", "clip"):
            raise InvalidValueError(f"on_excess must be 'refuse' or 'clip', got {on_excess!r}")
        self.on_excess = on_excess
        self._clock = clock if clock is not None else time.monotonic
        self._status = RobotStatus.DISABLED
        self._message = ""
        self._q = np.zeros(4)
        self.excess_count = 0
        """Number of commands clipped by ``max_step`` (``on_excess="clip"``)."""
        self.commands: list[NDArray[np.float64]] = []
        """Every accepted position command, in order (for tests and logs)."""
        self.record_commands = True
        """Set False to stop appending to ``commands`` (long runs)."""
        self.plant.reset(self._q)
        self.tip2base: NDArray[np.float64] = self.plant.move(self._q)
        """(4, 4) true tip pose reported by the plant after the latest command (mm)."""

    # --- state machine ------------------------------------------------------------------

    def _transition(self, event: str) -> None:
        nxt = TRANSITIONS.get((self._status, event))
        if nxt is None:
            raise HardwareError(
                f"{event} is not allowed in status {self._status.value}"
                + (f" ({self._message})" if self._message else "")
            )
        self._status = nxt

    @property
    def status(self) -> RobotStatus:
        """Current status."""
        return self._status

    def enable(self) -> None:
        """DISABLED -> ENABLED (hold the current position)."""
        self._transition("enable")

    def disable(self) -> None:
        """ENABLED -> DISABLED."""
        self._transition("disable")

    def home(self) -> None:
        """Move to q = 0 (allowed only when ENABLED) and reset the plant there."""
        self._require_enabled("home")
        self._q = np.zeros(4)
        self.plant.reset(self._q)
        self.tip2base = self.plant.move(self._q)

    def read_state(self) -> JointState:
        """The encoders: the last accepted motor command."""
        return JointState(self._q.copy(), float(self._clock()), self._status, self._message)

    def _require_enabled(self, what: str) -> None:
        if self._status is RobotStatus.ESTOP:
            raise EmergencyStopError(f"{what} refused: the robot is e-stopped; reset_fault() first")
        if self._status is RobotStatus.FAULT:
            raise DriveFaultError(f"{what} refused: drive fault ({self._message})")
        if self._status is not RobotStatus.ENABLED:
            raise HardwareError(f"{what} refused: status is {self._status.value}, not enabled")

    def command_position(self, q_motor: ArrayLike) -> None:
        """Set the position target (rad, rad, rad, mm); refused unless ENABLED.

        Raises JointLimitError beyond the limits, CommandStepError for a jump larger than
        ``max_step`` (``on_excess="refuse"``).
        """
        self._require_enabled("command_position")
        q = check_joint_state(q_motor, self.limits, name="q_motor")
        if q.shape != (4,):
            raise InvalidValueError(f"q_motor must have shape (4,), got {q.shape}")
        if self.max_step is not None:
            step = q - self._q
            over = np.abs(step) > self.max_step * (1 + 1e-12)
            if np.any(over):
                j = int(np.argmax(over))
                text = (
                    f"command jumps {JOINT_NAMES[j]} by {step[j]:.6g} {JOINT_UNITS[j]}, more "
                    f"than the max step {self.max_step[j]:.6g} {JOINT_UNITS[j]}"
                )
                if self.on_excess == "refuse":
                    raise CommandStepError(text)
                self.excess_count += 1
                self._message = "clipped: " + text
                q = self._q + np.clip(step, -self.max_step, self.max_step)
        self._q = np.array(q, np.float64)
        if self.record_commands:
            self.commands.append(self._q.copy())
        self.tip2base = self.plant.move(self._q)

    def stop(self) -> None:
        """Hold the current position (stays ENABLED)."""
        # Ideal servos: the last command is the current position, nothing is in flight.

    def estop(self) -> None:
        """Emergency stop (-> ESTOP)."""
        self._transition("estop")
        self._message = "emergency stop"

    def inject_fault(self, message: str) -> None:
        """Simulate a drive fault (-> FAULT) with ``message`` (tests)."""
        self._transition("fault")
        self._message = message

    def reset_fault(self) -> None:
        """Clear FAULT / ESTOP (-> DISABLED)."""
        self._transition("reset_fault")
        self._message = ""

    def close(self) -> None:
        """Release the robot (-> DISABLED when enabled)."""
        if self._status is RobotStatus.ENABLED:
            self._transition("disable")

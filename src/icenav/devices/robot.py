"""The robot backend protocol every backend (simulated, CANopen, ...) implements.

The controller owns time: it calls :meth:`RobotBackend.read_state` and
:meth:`RobotBackend.command_position` once per cycle. Joint vectors are *motor* joint states
``q = (phi1, phi2, phi3, d4)`` in (rad, rad, rad, mm).

State machine of a backend (transitions in one table, see ``TRANSITIONS``)::

    DISABLED --enable--> ENABLED --disable--> DISABLED
    any      --fault---> FAULT   --reset_fault--> DISABLED
    any      --estop---> ESTOP   --reset_fault--> DISABLED

Motion resumes only after an explicit ``reset_fault()`` and ``enable()``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["JointState", "RobotBackend", "RobotStatus", "TRANSITIONS"]


class RobotStatus(enum.Enum):
    """Status of a robot backend."""

    DISABLED = "disabled"
    """Powered but not holding or moving; commands are refused."""
    ENABLED = "enabled"
    """Holding position and following position commands."""
    FAULT = "fault"
    """A drive fault, lost heartbeat, following error, ...: all axes stopped."""
    ESTOP = "estop"
    """Emergency stop: all axes stopped at once."""


TRANSITIONS: dict[tuple[RobotStatus, str], RobotStatus] = {
    (RobotStatus.DISABLED, "enable"): RobotStatus.ENABLED,
    (RobotStatus.ENABLED, "enable"): RobotStatus.ENABLED,
    (RobotStatus.ENABLED, "disable"): RobotStatus.DISABLED,
    (RobotStatus.DISABLED, "disable"): RobotStatus.DISABLED,
    (RobotStatus.DISABLED, "fault"): RobotStatus.FAULT,
    (RobotStatus.ENABLED, "fault"): RobotStatus.FAULT,
    (RobotStatus.FAULT, "fault"): RobotStatus.FAULT,
    (RobotStatus.DISABLED, "estop"): RobotStatus.ESTOP,
    (RobotStatus.ENABLED, "estop"): RobotStatus.ESTOP,
    (RobotStatus.FAULT, "estop"): RobotStatus.ESTOP,
    (RobotStatus.ESTOP, "estop"): RobotStatus.ESTOP,
    (RobotStatus.FAULT, "reset_fault"): RobotStatus.DISABLED,
    (RobotStatus.ESTOP, "reset_fault"): RobotStatus.DISABLED,
    (RobotStatus.DISABLED, "reset_fault"): RobotStatus.DISABLED,
    (RobotStatus.ENABLED, "reset_fault"): RobotStatus.ENABLED,
}
"""(status, event) -> next status. A pair not in the table is a refused transition."""


@dataclass(frozen=True)
class JointState:
    """Measured joint state of the robot."""

    q: NDArray[np.float64]
    """(4,) motor joint positions (phi1 rad, phi2 rad, phi3 rad, d4 mm) from the encoders."""
    timestamp: float
    """Time of the reading (s, the backend's clock)."""
    status: RobotStatus
    """Backend status at the time of the reading."""
    message: str = ""
    """Human-readable fault or status text ("" when all is well)."""


@runtime_checkable
class RobotBackend(Protocol):
    """What the controller needs from a robot (simulated or real)."""

    @property
    def status(self) -> RobotStatus:
        """Current status."""
        ...

    def enable(self) -> None:
        """Power the axes and hold the current position (DISABLED -> ENABLED)."""
        ...

    def disable(self) -> None:
        """Stop and release the axes (ENABLED -> DISABLED)."""
        ...

    def home(self) -> None:
        """Run the homing procedure; afterwards q = 0 is the catheter's neutral state."""
        ...

    def read_state(self) -> JointState:
        """Read the encoders."""
        ...

    def command_position(self, q_motor: ArrayLike) -> None:
        """Set the position target (rad, rad, rad, mm); refused unless ENABLED."""
        ...

    def stop(self) -> None:
        """Controlled stop: hold the current position (stays ENABLED)."""
        ...

    def estop(self) -> None:
        """Emergency stop: all axes stop at once (-> ESTOP)."""
        ...

    def reset_fault(self) -> None:
        """Clear a FAULT or ESTOP (-> DISABLED); motion needs enable() afterwards."""
        ...

    def close(self) -> None:
        """Release the hardware (bus, threads)."""
        ...

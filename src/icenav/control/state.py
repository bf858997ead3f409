"""What the controller publishes and what it accepts: the contract between the control loop
and its adapters (console, OpenIGTLink bridge, scripts).

The controller (:mod:`icenav.control.controller`) owns time and state. Each cycle it may publish a
:class:`ControllerState` snapshot (immutable, safe to hand to another thread) to its
listeners; adapters send requests through the :class:`ControllerCommands` protocol, which
the controller executes at the start of its next cycle (so requests from several threads
never race with the loop).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.devices.robot import RobotStatus

__all__ = [
    "CalibrationKind",
    "ControllerCommands",
    "ControllerState",
    "ImageFrame",
    "Mode",
    "ViewSummary",
]

CalibrationKind = Literal["dense", "five_point", "dense+hysteresis"]


class Mode(enum.Enum):
    """Operating mode of the controller (transitions in
    ``icenav.control.controller.TRANSITIONS``)."""

    IDLE = "idle"
    """Holding position; no motion commanded."""
    KNOB = "knob"
    """Teleoperation: gamepad axes drive the knobs, roll and translation."""
    TIP = "tip"
    """Teleoperation: gamepad axes drive the tip in its own frame (tip_jog)."""
    GOTO_VIEW = "goto_view"
    """Automatic return to a saved view along the roadmap."""
    SPINNING = "spinning"
    """Automatic 360 deg image spin about the catheter axis."""
    CALIBRATING = "calibrating"
    """Automatic calibration raster (dense or 5-point)."""
    FAULT = "fault"
    """A fault stopped the robot; needs an explicit reset."""
    ESTOP = "estop"
    """Emergency stop; needs an explicit reset."""


@dataclass(frozen=True)
class ViewSummary:
    """A saved view as adapters list it."""

    name: str
    """Unique name."""
    q_motor: Array
    """(4,) motor joint state of the view (rad, rad, rad, mm)."""
    created_s: float
    """When it was saved (s since the epoch)."""
    has_image: bool = False
    """Whether a thumbnail / clip was saved with it."""


@dataclass(frozen=True)
class ImageFrame:
    """One ICE image."""

    pixels: NDArray[np.uint8]
    """(H, W) B-mode image, 0-255."""
    timestamp: float
    """Controller time of the frame (s)."""
    ijk2tip: Array = field(default_factory=lambda: np.eye(4))
    """(4, 4) pixel (i = column, j = row, k = 0) to tip frame (mm), to place it in 3-D."""


@dataclass(frozen=True)
class ControllerState:
    """Snapshot of the controller, published to listeners."""

    time: float
    """Controller time (s)."""
    cycle: int
    """Control cycle counter."""
    mode: Mode
    """Current mode."""
    robot_status: RobotStatus
    """Status of the robot backend."""
    q_motor: Array
    """(4,) measured motor joint state (rad, rad, rad, mm)."""
    q_model: Array
    """(4,) model joint state (the motor state mapped back through the compensation)."""
    tip2base_model: Array
    """(4, 4) tip pose predicted by the model (mm)."""
    tip2base_true: Array | None = None
    """(4, 4) true tip pose (digital twin only; None on hardware)."""
    backbone_model: Array | None = None
    """(n, 3) model shape of the bending section in the base frame (mm)."""
    backbone_true: Array | None = None
    """(n, 3) true shape from the twin (None on hardware)."""
    sensor2base: Array | None = None
    """(4, 4) EM-tracked sensor pose mapped into the base frame, None when MISSING."""
    tracker_status: str = "none"
    """Tracker status text (VALID, MISSING, ...; "none" without a tracker)."""
    message: str = ""
    """Latest operator-facing message (fault text, what just happened)."""
    progress: float | None = None
    """Progress of the automatic motion or calibration in [0, 1], None when there is none."""
    progress_label: str = ""
    """What the progress is of."""
    n_vertices: int = 0
    """Roadmap size (vertices)."""
    n_edges: int = 0
    """Roadmap size (edges)."""
    views: tuple[ViewSummary, ...] = ()
    """The view library."""
    compensation_enabled: bool = False
    """Whether the elasticity / hysteresis compensation is applied to teleoperation."""
    control_owner: str | None = None
    """Id of the client that holds control (None: free; "gamepad" wins over browsers)."""


class ControllerCommands(Protocol):
    """Requests an adapter may send; each returns at once and is executed by the loop.

    ``client`` identifies the requester (a browser session id, "gamepad", "igtl",
    "script"); motion requests from a client that does not hold control are refused with a
    message in the next state. Stop and e-stop are accepted from anyone.
    """

    def request_mode(self, mode: Mode, client: str = "script") -> None:
        """Switch between IDLE, KNOB and TIP (automatic modes start through their own calls)."""
        ...

    def jog(self, velocity: Array, frame: Literal["knob", "tip"], client: str = "script") -> None:
        """Hold a velocity for one watchdog period: (4,) joint velocity (rad/s, mm/s) in knob
        frame or (6,) tip twist (mm/s, rad/s); repeat to keep moving."""
        ...

    def save_view(self, name: str, client: str = "script") -> None:
        """Save the current state (and image) as a view."""
        ...

    def goto_view(self, name: str, client: str = "script") -> None:
        """Return to a saved view along the roadmap."""
        ...

    def delete_view(self, name: str, client: str = "script") -> None:
        """Delete a view."""
        ...

    def start_spin(self, client: str = "script") -> None:
        """Spin the image plane 360 deg about the catheter axis, tip held still."""
        ...

    def start_calibration(self, kind: CalibrationKind, client: str = "script") -> None:
        """Run a calibration raster and install the resulting compensation."""
        ...

    def set_compensation(self, enabled: bool, client: str = "script") -> None:
        """Apply (or not) the compensation to teleoperation and automatic motions."""
        ...

    def stop(self, client: str = "script") -> None:
        """Stop any automatic motion and hold position."""
        ...

    def estop(self, client: str = "script") -> None:
        """Emergency stop, from any mode."""
        ...

    def reset_fault(self, client: str = "script") -> None:
        """Leave FAULT / ESTOP after the cause is cleared (-> IDLE, robot re-enabled)."""
        ...

    def acquire_control(self, client: str) -> bool:
        """Take control for ``client`` (refused while another holds it; gamepad always wins)."""
        ...

    def release_control(self, client: str) -> None:
        """Give control back."""
        ...

    def snapshot(self) -> ControllerState:
        """The latest published state."""
        ...

    def latest_image(self) -> ImageFrame | None:
        """The latest ICE image, None before the first one (or without an imager)."""
        ...

    def view_image(self, name: str) -> ImageFrame | None:
        """The image saved with a view, if any."""
        ...

    def add_listener(self, callback: Callable[[ControllerState], None]) -> None:
        """Call ``callback`` with each published state (from the control thread: be quick)."""
        ...

"""What the controller publishes and what it accepts: the contract between the control loop
and its adapters (console, OpenIGTLink server, scripts).

The controller (:mod:`icenav.control.controller`) owns time and state. Each cycle it may publish a
:class:`ControllerState` snapshot (immutable, safe to hand to another thread) to its
listeners; adapters send commands (:mod:`icenav.control.commands`) through the
:class:`ControllerCommands` protocol, which the controller decides at the start of its next
cycle (so requests from several threads never race with the loop); E-STOP acts at once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav.control.commands import Command, Ticket
from icenav.control.modes import Mode
from icenav.devices.robot import RobotStatus

if TYPE_CHECKING:
    from icenav.control.calibration_runner import CalibrationPreview

__all__ = [
    "CalibrationKind",
    "ControllerCommands",
    "ControllerState",
    "ImageFrame",
    "KnobMap",
    "Mode",
    "ViewSummary",
]

CalibrationKind = Literal["dense", "five_point", "dense+hysteresis"]


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


class _Deferred:
    """A field of a frozen dataclass that may be given as a function of no arguments and is
    computed on first access (then kept): the loop publishes a state every cycle, but the
    drawing data in it (the backbones, 50 points each) is read by the console at its own
    rate, a few times per second at most. Given a value, it is that value."""

    def __set_name__(self, owner: type, name: str) -> None:
        self._slot = "_deferred_" + name

    def __get__(self, obj: object, owner: type | None = None) -> Array | None:
        if obj is None:
            return None  # the dataclass's default
        value = obj.__dict__[self._slot]
        if callable(value):
            value = value()
            obj.__dict__[self._slot] = value  # (two threads may both compute it: same value)
        return value

    def __set__(self, obj: object, value: Array | Callable[[], Array | None] | None) -> None:
        obj.__dict__[self._slot] = value


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
    backbone_model: _Deferred = _Deferred()
    """(n, 3) model shape of the bending section in the base frame (mm), or None; computed
    when first read (the publisher gives a function)."""
    backbone_true: _Deferred = _Deferred()
    """(n, 3) true shape from the twin (None on hardware); computed when first read."""
    sensor2base: Array | None = None
    """(4, 4) EM-tracked sensor pose mapped into the base frame, None when MISSING."""
    tracker_status: str = "none"
    """Tracker status text (VALID, MISSING, ...; "none" without a tracker)."""
    force_check: str = "off: no force channel"
    """Whether returns are force-checked (:mod:`icenav.recovery.force`): "off: no force
    channel", or "on" with the operator's readings recorded so far."""
    message: str = ""
    """Latest operator-facing message (fault text, what just happened)."""
    question: str = ""
    """A question the robot waits on the operator to answer (empty: none), shown for as long
    as it can be answered: a return that held because the tip-drift check cannot tell
    whether the patient moved (Eq. F6 of :mod:`icenav.recovery.drift`) and runs at a second
    press within :data:`~icenav.recovery.drift.CONFIRM_S`."""
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


class KnobMap(Protocol):
    """A compensation between model and motor joint states (the paper's F on the knobs; roll
    and translation pass through). :class:`icenav.compensation.elasticity.ElasticityMap` is
    one. A map with state (``icenav.compensation.tendon_map.TendonKnobMap``) also has
    ``observe(q_motor)``: the controller calls it with every command it sends."""

    def model_to_motor(self, q_model: ArrayLike, *, check: bool = True) -> Array:
        """Motor joint state(s) (..., 4) that realise the model joint state(s) (F)."""
        ...

    def motor_to_model(self, q_motor: ArrayLike, *, check: bool = True) -> Array:
        """Model joint state(s) (..., 4) that the motor joint state(s) realise (F^-1)."""
        ...


class ControllerCommands(Protocol):
    """What an adapter may ask of a controller.

    :meth:`submit` takes any command of :mod:`icenav.control.commands` and returns its
    :class:`~icenav.control.commands.Ticket`; the other request methods are thin calls that
    build a command from ``client`` (a browser session id, "gamepad", "igtl...", "script")
    and submit it. Authorization is the controller's (``icenav.control.authorization``):
    state-changing commands only from the client that holds control; Stop and E-STOP from
    anyone.
    """

    def submit(self, command: Command) -> Ticket:
        """Submit a command; its outcome comes through the ticket."""
        ...

    def request_mode(self, mode: Mode, client: str = "script") -> Ticket:
        """Switch between IDLE, KNOB and TIP (automatic modes start through their own calls)."""
        ...

    def jog(
        self, velocity: ArrayLike, frame: Literal["knob", "tip"], client: str = "script"
    ) -> Ticket:
        """Hold a velocity for one watchdog period: (4,) joint velocity (rad/s, mm/s) in knob
        frame or (6,) tip twist (mm/s, rad/s); repeat to keep moving."""
        ...

    def save_view(self, name: str, client: str = "script") -> Ticket:
        """Save the current state (and image) as a view."""
        ...

    def goto_view(self, name: str, client: str = "script") -> Ticket:
        """Return to a saved view along the roadmap."""
        ...

    def rename_view(self, name: str, new_name: str, client: str = "script") -> Ticket:
        """Rename a view."""
        ...

    def delete_view(self, name: str, client: str = "script") -> Ticket:
        """Delete a view."""
        ...

    def start_spin(self, client: str = "script") -> Ticket:
        """Spin the image plane 360 deg about the catheter axis, tip held still."""
        ...

    def start_calibration(self, kind: CalibrationKind, client: str = "script") -> Ticket:
        """Run a calibration procedure and install the resulting compensation."""
        ...

    def preview_calibration(self, kind: CalibrationKind) -> CalibrationPreview:
        """What a calibration would do and about how long it takes (for a confirmation)."""
        ...

    def set_compensation(self, enabled: bool, client: str = "script") -> Ticket:
        """Apply (or not) the compensation to teleoperation and automatic motions."""
        ...

    def stop(self, client: str = "script") -> Ticket:
        """Stop any automatic motion and hold position."""
        ...

    def estop(self, client: str = "script") -> Ticket:
        """Emergency stop, from any mode (acts at once)."""
        ...

    def reset_fault(self, client: str = "script") -> Ticket:
        """Leave FAULT / ESTOP after the cause is cleared (-> IDLE, robot re-enabled)."""
        ...

    def acquire_control(self, client: str) -> bool:
        """Take control for ``client`` (refused while another holds it; gamepad always wins)."""
        ...

    def release_control(self, client: str) -> None:
        """Give control back."""
        ...

    def disconnect(self, client: str) -> None:
        """``client`` is gone: release its control; what it started stops and holds."""
        ...

    def set_view_only(self, client: str, view_only: bool) -> None:
        """Mark ``client`` view only (Stop and E-STOP only), or lift it."""
        ...

    def note(self, text: str) -> None:
        """An event for the session's log (an adapter's alarm, ...)."""
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

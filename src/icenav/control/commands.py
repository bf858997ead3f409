"""Commands as data: the one set of requests the console, the gamepad, OpenIGTLink and Python
send to the controller, each with its :class:`Source`, and their outcomes.

::

    ticket = controller.submit(GoToView("apex", source=Source("igtl", "igtl-slicer")))
    ticket.result(timeout=1.0)    # CommandResult: ACCEPTED, or REFUSED with .reason
    ticket.final(timeout=60.0)    # CommandResult: DONE, FAILED (.reason) or REFUSED

Every command is decided by the control loop, in the order submitted (E-STOP acts at once
from the caller's thread, take / release control are decided at once too): it is
**accepted** or **refused** with a reason (not authorized, in ESTOP / FAULT, no such view,
...), and an accepted one later ends **done** or **failed** with a reason (a go to view that
an e-stop ended, a view that could not be written to disk, a calibration whose fit failed).
A command that completes within its cycle (a mode request, a saved-in-memory view, a stop) is
accepted and done in the same cycle. Each outcome is written to the session's event log
(a stream of jogs is logged when it starts and when its outcome changes, not at 100 Hz).

Validation happens where the command is made (``Jog([nan, 0, 0, 0], "knob")`` raises
:class:`~icenav.errors.InvalidValueError`); whether it may run is decided by the loop.
"""

from __future__ import annotations

import enum
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np

from icenav._typing import Array
from icenav.control.modes import Mode
from icenav.errors import CommandTimeoutError, InvalidValueError

__all__ = [
    "Calibrate",
    "Command",
    "CommandResult",
    "DeleteView",
    "Disconnect",
    "EStop",
    "Export",
    "GAMEPAD",
    "GoToView",
    "Jog",
    "Outcome",
    "RefineView",
    "ReleaseControl",
    "RenameView",
    "Reset",
    "SCRIPT",
    "SOURCE_KINDS",
    "SaveView",
    "SetCompensation",
    "SetMode",
    "Source",
    "Spin",
    "Stop",
    "TakeControl",
    "Ticket",
]

SourceKind = Literal["console", "gamepad", "igtl", "script"]
SOURCE_KINDS: tuple[str, ...] = ("console", "gamepad", "igtl", "script")
"""Where a command can come from."""
JOG_ABS_MAX = 1e3
"""Largest magnitude of a jog velocity component accepted (rad/s or mm/s)."""
_MAX_CLIENT_CHARS = 200


@dataclass(frozen=True)
class Source:
    """Who sent a command: the kind of adapter and the client's id within it (a browser
    session "browser-3", "gamepad", an OpenIGTLink peer, "script")."""

    kind: str
    """One of :data:`SOURCE_KINDS`."""
    client: str
    """The client's id: authorization compares it with the control holder's."""

    def __post_init__(self) -> None:
        if self.kind not in SOURCE_KINDS:
            raise InvalidValueError(
                f"a command source's kind must be one of {', '.join(SOURCE_KINDS)}, "
                f"got {self.kind!r}"
            )
        if not isinstance(self.client, str) or not 0 < len(self.client) <= _MAX_CLIENT_CHARS:
            raise InvalidValueError(
                f"a command source's client must be a string of 1-{_MAX_CLIENT_CHARS} "
                f"characters, got {self.client!r:.60}"
            )

    @classmethod
    def of(cls, client: str | Source) -> Source:
        """The source of a client named as the thin API names it: "gamepad", "browser-*"
        (the console), "igtl*" (OpenIGTLink), anything else a script."""
        if isinstance(client, Source):
            return client
        known = _SOURCES.get(client)
        if known is not None:
            return known
        if client == "gamepad":
            source = GAMEPAD
        elif client.startswith("browser"):
            source = cls("console", client)
        elif client.startswith("igtl"):
            source = cls("igtl", client)
        else:
            source = cls("script", client)
        if len(_SOURCES) < 1024:
            _SOURCES[client] = source
        return source


_SOURCES: dict[str, Source] = {}
"""Sources made by :meth:`Source.of`, by client name (a jog per cycle builds none)."""
SCRIPT = Source("script", "script")
"""The default source of a Python call."""
GAMEPAD = Source("gamepad", "gamepad")
"""The gamepad (one per controller)."""


@dataclass(frozen=True, eq=False)
class Command:
    """Base of every command (never sent itself)."""

    source: Source = field(default=SCRIPT, kw_only=True)
    """Who sent it."""

    name: ClassVar[str] = "command"
    """The command's name in the event log and on OpenIGTLink."""
    changes_state: ClassVar[bool] = True
    """Only the control holder may send it (False: anyone who sees the robot may)."""
    moves: ClassVar[bool] = False
    """It moves the robot (refused in FAULT / ESTOP)."""

    def describe(self) -> str:
        """Short text for the event log."""
        return self.name


def _name(value: object, what: str) -> str:
    if not isinstance(value, str):
        raise InvalidValueError(f"{what} must be a string, got {type(value).__name__}")
    return value


@dataclass(frozen=True, eq=False)
class Jog(Command):
    """Hold a velocity for one watchdog period (repeat to keep moving): a (4,) joint
    velocity (rad/s, rad/s, rad/s, mm/s) in the "knob" frame or a (6,) tip twist (vx, vy, vz
    mm/s, wx, wy, wz rad/s) in the "tip" frame."""

    velocity: Array
    frame: Literal["knob", "tip"]
    name: ClassVar[str] = "jog"
    moves: ClassVar[bool] = True

    def __post_init__(self) -> None:
        try:
            v = np.array(self.velocity, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidValueError(
                f"jog velocity must be numbers, got {self.velocity!r:.80}"
            ) from exc
        expected = 4 if self.frame == "knob" else 6
        if self.frame not in ("knob", "tip") or v.shape != (expected,):
            raise InvalidValueError(
                f"jog takes frame 'knob' with 4 velocities (rad/s, rad/s, rad/s, mm/s) or "
                f"'tip' with 6 (mm/s, rad/s); got frame {self.frame!r} and shape {v.shape}"
            )
        largest = float(np.max(np.abs(v)))  # one reduction: NaN and inf fail both tests
        if not math.isfinite(largest):
            raise InvalidValueError(f"jog velocity must be finite, got {v}")
        if largest > JOG_ABS_MAX:
            # commands are clipped to max_velocity anyway; this only keeps the arithmetic of
            # the tip-frame solve away from overflow (a gamepad gives at most a few units)
            raise InvalidValueError(
                f"jog velocity must be within +-{JOG_ABS_MAX:g} (rad/s or mm/s; the speed "
                f"limits clip it further), got {v}"
            )
        v.setflags(write=False)
        object.__setattr__(self, "velocity", v)

    def describe(self) -> str:
        return f"jog {self.frame}"


@dataclass(frozen=True, eq=False)
class SetMode(Command):
    """Switch between IDLE, KNOB and TIP (automatic modes start by their own commands)."""

    mode: Mode
    name: ClassVar[str] = "set_mode"
    moves: ClassVar[bool] = True

    def __post_init__(self) -> None:
        if not isinstance(self.mode, Mode):
            raise InvalidValueError(f"set_mode needs a Mode, got {self.mode!r}")

    def describe(self) -> str:
        return f"set_mode {self.mode.value}"


@dataclass(frozen=True, eq=False)
class _ViewCommand(Command):
    """A command about one saved view (its name checked where the command is made)."""

    view: str

    def __post_init__(self) -> None:
        _name(self.view, "a view name")

    def describe(self) -> str:
        return f"{self.name} {self.view!r:.80}"


@dataclass(frozen=True, eq=False)
class GoToView(_ViewCommand):
    """Return to a saved view along the roadmap."""

    name: ClassVar[str] = "go_to_view"
    moves: ClassVar[bool] = True


@dataclass(frozen=True, eq=False)
class SaveView(_ViewCommand):
    """Save the current state (and image) as a view; done once it is on disk."""

    name: ClassVar[str] = "save_view"


@dataclass(frozen=True, eq=False)
class RenameView(_ViewCommand):
    """Rename a saved view."""

    new_name: str
    name: ClassVar[str] = "rename_view"

    def __post_init__(self) -> None:
        super().__post_init__()
        _name(self.new_name, "a view's new name")

    def describe(self) -> str:
        return f"{super().describe()} -> {self.new_name!r:.80}"


@dataclass(frozen=True, eq=False)
class DeleteView(_ViewCommand):
    """Delete a saved view."""

    name: ClassVar[str] = "delete_view"


@dataclass(frozen=True, eq=False)
class RefineView(_ViewCommand):
    """Refine the view the robot returned to: the EM pose stage on the tip pose averaged
    over complete breaths / beats (needs a tracker and the view's EM pose saved with it)."""

    name: ClassVar[str] = "refine_view"
    moves: ClassVar[bool] = True


@dataclass(frozen=True, eq=False)
class Spin(Command):
    """Turn the image plane 360 deg about the catheter axis, tip held still."""

    name: ClassVar[str] = "spin"
    moves: ClassVar[bool] = True


@dataclass(frozen=True, eq=False)
class Calibrate(Command):
    """Run a calibration procedure (``icenav.calibration.procedures``: "dense",
    "five_point", "dense+hysteresis") as a bench procedure: the catheter is returned to
    where it started, its states are not recorded in the roadmap; the fit runs in the
    background and its compensation is installed when ready (then the command is done)."""

    kind: str
    name: ClassVar[str] = "calibrate"
    moves: ClassVar[bool] = True

    def __post_init__(self) -> None:
        from icenav.calibration.procedures import CALIBRATION_KINDS

        if self.kind not in CALIBRATION_KINDS:
            raise InvalidValueError(
                f"unknown calibration kind {self.kind!r}: use one of {', '.join(CALIBRATION_KINDS)}"
            )

    def describe(self) -> str:
        return f"calibrate {self.kind}"


@dataclass(frozen=True, eq=False)
class SetCompensation(Command):
    """Apply (or not) the compensation to teleoperation and automatic motions."""

    enabled: bool
    name: ClassVar[str] = "set_compensation"

    def describe(self) -> str:
        return f"set_compensation {'on' if self.enabled else 'off'}"


@dataclass(frozen=True, eq=False)
class Stop(Command):
    """Stop any automatic motion and jog, hold position (anyone may)."""

    name: ClassVar[str] = "stop"
    changes_state: ClassVar[bool] = False


@dataclass(frozen=True, eq=False)
class EStop(Command):
    """Emergency stop from any mode (anyone may; acts at once from the caller's thread)."""

    name: ClassVar[str] = "estop"
    changes_state: ClassVar[bool] = False


@dataclass(frozen=True, eq=False)
class Reset(Command):
    """Leave FAULT / ESTOP (-> IDLE, robot re-enabled, holding position)."""

    name: ClassVar[str] = "reset"


@dataclass(frozen=True, eq=False)
class TakeControl(Command):
    """Take control (refused while another client holds it; the gamepad always wins)."""

    name: ClassVar[str] = "take_control"
    changes_state: ClassVar[bool] = False


@dataclass(frozen=True, eq=False)
class ReleaseControl(Command):
    """Give control back."""

    name: ClassVar[str] = "release_control"
    changes_state: ClassVar[bool] = False


@dataclass(frozen=True, eq=False)
class Disconnect(Command):
    """The client is gone (a browser tab closed, the gamepad unplugged, a peer hung up):
    its control is released, its jog dropped, and any automatic motion it started stops and
    holds."""

    name: ClassVar[str] = "disconnect"
    changes_state: ClassVar[bool] = False


@dataclass(frozen=True, eq=False)
class Export(_ViewCommand):
    """Export a saved view (its image and pose) as a file. The controller authorizes it
    (holder only, the view exists with an image); the adapter that holds the export
    directory writes the file once the command is accepted."""

    name: ClassVar[str] = "export"


class Outcome(enum.Enum):
    """What became of a command."""

    ACCEPTED = "accepted"
    """The loop took it (it may run on: see DONE / FAILED)."""
    REFUSED = "refused"
    """Not run; ``reason`` says why (final)."""
    DONE = "done"
    """Finished as asked (final)."""
    FAILED = "failed"
    """Accepted, then ended otherwise; ``reason`` says why (final)."""


@dataclass(frozen=True, eq=False)
class CommandResult:
    """One outcome of one command."""

    seq: int
    """The command's sequence number (submission order)."""
    command: Command
    """The command."""
    outcome: Outcome
    """ACCEPTED, REFUSED, DONE or FAILED."""
    reason: str = ""
    """Why it was refused or failed; what was done ("" if nothing to add)."""
    time: float = math.nan
    """Controller time of the outcome (s)."""

    @property
    def ok(self) -> bool:
        """True for ACCEPTED and DONE."""
        return self.outcome in (Outcome.ACCEPTED, Outcome.DONE)


_TICKETS = threading.Condition()
"""One condition for every ticket (a jog makes one per cycle: no lock of its own to build;
the few waiters re-check their own ticket when woken)."""


class Ticket:
    """The receipt of a submitted command: wait for its decision or its end, or register a
    callback. Callbacks run on the thread that decided (the control loop, or the caller of
    ``estop`` / ``acquire_control``): they must be quick and must not block on the loop."""

    __slots__ = ("_decision", "_final", "_on_decided", "_on_final", "command", "seq")

    def __init__(self, seq: int, command: Command) -> None:
        self.seq = seq
        """Sequence number (submission order)."""
        self.command = command
        """The command."""
        self._decision: CommandResult | None = None
        self._final: CommandResult | None = None
        self._on_decided: list[Callable[[CommandResult], None]] | None = None
        self._on_final: list[Callable[[CommandResult], None]] | None = None

    def __repr__(self) -> str:
        final = self._final or self._decision
        state = "pending" if final is None else final.outcome.value
        who = self.command.source.client
        return f"Ticket(#{self.seq} {self.command.describe()} from {who}: {state})"

    @property
    def decided(self) -> bool:
        """True once accepted or refused."""
        return self._decision is not None

    @property
    def finished(self) -> bool:
        """True once refused, done or failed."""
        return self._final is not None

    def result(self, timeout: float | None = None) -> CommandResult:
        """Block until the loop decided (ACCEPTED or REFUSED) and return that result.

        Raises CommandTimeoutError after ``timeout`` s (None: wait for ever; note that a
        controller stepped by hand decides only when its ``step()`` runs)."""
        return self._wait(lambda: self._decision, timeout, "decided")

    def final(self, timeout: float | None = None) -> CommandResult:
        """Block until the command ended (REFUSED, DONE or FAILED) and return that result."""
        return self._wait(lambda: self._final, timeout, "finished")

    def _wait(
        self, get: Callable[[], CommandResult | None], timeout: float | None, what: str
    ) -> CommandResult:
        with _TICKETS:
            if not _TICKETS.wait_for(lambda: get() is not None, timeout):
                raise CommandTimeoutError(
                    f"command #{self.seq} ({self.command.describe()}) was not {what} within "
                    f"{timeout} s"
                )
            out = get()
        assert out is not None
        return out

    def add_callback(
        self, fn: Callable[[CommandResult], None], *, when: Literal["decided", "final"] = "final"
    ) -> None:
        """Call ``fn(result)`` when the command is decided or when it ends (at once if it
        already is)."""
        with _TICKETS:
            done = self._decision if when == "decided" else self._final
            if done is None:
                if when == "decided":
                    self._on_decided = [*(self._on_decided or ()), fn]
                else:
                    self._on_final = [*(self._on_final or ()), fn]
                return
        fn(done)

    def resolve(self, result: CommandResult) -> bool:
        """Record an outcome: the controller's side (an adapter never calls it); returns
        False if the ticket had ended already."""
        calls: list[tuple[Callable[[CommandResult], None], CommandResult]] = []
        with _TICKETS:
            if self._final is not None:
                return False
            if self._decision is None:
                decision = result
                if result.outcome not in (Outcome.ACCEPTED, Outcome.REFUSED):
                    decision = CommandResult(
                        result.seq, result.command, Outcome.ACCEPTED, "", result.time
                    )
                self._decision = decision
                if self._on_decided:
                    calls += [(fn, decision) for fn in self._on_decided]
                    self._on_decided = None
            if result.outcome is not Outcome.ACCEPTED:
                self._final = result
                if self._on_final:
                    calls += [(fn, result) for fn in self._on_final]
                    self._on_final = None
            _TICKETS.notify_all()
        for fn, r in calls:
            fn(r)
        return True

"""The controller's modes and the one table of the transitions between them.

:class:`ModeMachine` is the only writer of the mode. Every change goes through
:meth:`ModeMachine.go` with the way it happens (:class:`Via`), and the pair
``(mode, via)`` must be in :data:`TRANSITIONS`:

=================  ===========================================================================
via                 what it is
=================  ===========================================================================
``REQUEST``         an operator asks for IDLE, KNOB or TIP (a mode request, teleoperation input
                    that wakes the controller, operator input that ends an automatic motion)
``START``           an automatic task starts (go to view, spin, calibration)
``END``             the automatic task ended (done, failed, stopped) -> IDLE
``FAULT``           the robot or the cycle failed -> FAULT
``ESTOP``           an emergency stop, from any mode -> ESTOP
``RESET``           an operator's reset -> IDLE; the **only** way out of FAULT and ESTOP
=================  ===========================================================================

So ESTOP and FAULT are left only by a reset; a request that arrives there is refused with its
reason (and never applied later: it is not kept). An e-stop carries the sequence number of
the moment it happened; a reset asked *before* the latest e-stop is refused, so a reset that
was under way when someone pressed E-STOP can never clear that e-stop.

The machine is shared by the control thread and the threads that press E-STOP; every read
and write holds its lock, and nothing slow runs under it.
"""

from __future__ import annotations

import enum
import threading
from collections.abc import Callable
from dataclasses import dataclass

from icenav.errors import InvalidValueError

__all__ = [
    "AUTOMATIC",
    "HALTED",
    "Mode",
    "ModeChange",
    "ModeMachine",
    "TELEOP",
    "TRANSITIONS",
    "Via",
]


class Mode(enum.Enum):
    """Operating mode of the controller (transitions in :data:`TRANSITIONS`)."""

    IDLE = "idle"
    """Holding position; no motion commanded."""
    KNOB = "knob"
    """Teleoperation: gamepad axes drive the knobs, roll and translation."""
    TIP = "tip"
    """Teleoperation: gamepad axes drive the tip in its own frame (tip_jog)."""
    GOTO_VIEW = "goto_view"
    """Automatic return to a saved view along the roadmap (and its refinement)."""
    SPINNING = "spinning"
    """Automatic 360 deg image spin about the catheter axis."""
    CALIBRATING = "calibrating"
    """Automatic calibration procedure (a bench procedure)."""
    FAULT = "fault"
    """A fault stopped the robot; needs an explicit reset."""
    ESTOP = "estop"
    """Emergency stop; needs an explicit reset."""


class Via(enum.Enum):
    """How a mode change happens (the second key of :data:`TRANSITIONS`)."""

    REQUEST = "request"
    START = "start"
    END = "end"
    FAULT = "fault"
    ESTOP = "estop"
    RESET = "reset"


TELEOP = frozenset({Mode.IDLE, Mode.KNOB, Mode.TIP})
"""Modes an operator selects by request."""
AUTOMATIC = frozenset({Mode.GOTO_VIEW, Mode.SPINNING, Mode.CALIBRATING})
"""Modes of an automatic task."""
HALTED = frozenset({Mode.FAULT, Mode.ESTOP})
"""Modes left only by a reset."""

TRANSITIONS: dict[tuple[Mode, Via], frozenset[Mode]] = {
    **{(m, Via.REQUEST): TELEOP - {m} for m in TELEOP},
    **{(m, Via.REQUEST): TELEOP for m in AUTOMATIC},
    **{(m, Via.START): AUTOMATIC for m in TELEOP | AUTOMATIC},
    **{(m, Via.END): frozenset({Mode.IDLE}) for m in AUTOMATIC},
    **{(m, Via.FAULT): frozenset({Mode.FAULT}) for m in TELEOP | AUTOMATIC},
    **{(m, Via.ESTOP): frozenset({Mode.ESTOP}) for m in Mode},
    **{(m, Via.RESET): frozenset({Mode.IDLE}) for m in HALTED},
}
"""(mode, via) -> the modes it may go to. A pair not in the table is refused. Out of FAULT and
ESTOP there is only ``ESTOP`` (an e-stop during a fault) and ``RESET``."""


@dataclass(frozen=True)
class ModeChange:
    """One change of mode, as the machine reports it to its listener."""

    old: Mode
    """The mode before."""
    new: Mode
    """The mode after."""
    via: Via
    """How it happened."""
    cause: str
    """Why (the e-stop's or fault's text; the request's client; "" if nothing to say)."""


class ModeMachine:
    """The mode and its changes; the only writer of the mode (see the module docstring).

    Parameters
    ----------
    on_change : callable, optional
        Called with each :class:`ModeChange`, under the machine's lock (so it must be quick
        and must not call back into the machine): the controller queues it for its log.
    """

    def __init__(self, on_change: Callable[[ModeChange], None] | None = None) -> None:
        self._lock = threading.RLock()
        self._mode = Mode.IDLE
        self._cause = ""
        self._estop_seq = -1
        self._halts = 0
        self._on_change = on_change

    @property
    def mode(self) -> Mode:
        """The current mode."""
        return self._mode

    @property
    def halted(self) -> bool:
        """True in FAULT or ESTOP."""
        return self._mode in HALTED

    @property
    def cause(self) -> str:
        """Why the machine is in FAULT / ESTOP ("" otherwise)."""
        with self._lock:
            return self._cause if self._mode in HALTED else ""

    @property
    def halts(self) -> int:
        """How many times the machine went into FAULT or ESTOP (an epoch: a command
        computed before a halt is never sent after it)."""
        return self._halts

    @property
    def estop_seq(self) -> int:
        """Sequence number of the latest e-stop (-1: none yet)."""
        return self._estop_seq

    def go(self, to: Mode, via: Via, cause: str = "") -> str | None:
        """Change to ``to`` by ``via``; None when done (or already there), else the reason
        it is refused (the mode stays)."""
        if via in (Via.ESTOP, Via.FAULT, Via.RESET):
            raise InvalidValueError(f"use estop(), fault() or reset() for {via.value}, not go()")
        with self._lock:
            return self._change(to, via, cause)

    def _change(self, to: Mode, via: Via, cause: str) -> str | None:
        old = self._mode
        if to is old and via not in (Via.ESTOP, Via.FAULT):
            return None
        if to not in TRANSITIONS.get((old, via), frozenset()):
            if old in HALTED:
                return f"the controller is in {old.name}: reset first ({self._cause})"
            return f"cannot go from {old.value} to {to.value} by {via.value}"
        self._mode = to
        if to in HALTED:
            self._cause = cause
        if self._on_change is not None and to is not old:
            self._on_change(ModeChange(old, to, via, cause))
        return None

    def estop(self, cause: str, seq: int) -> None:
        """Emergency stop from any mode (the cause replaces the one shown)."""
        with self._lock:
            self._estop_seq = max(self._estop_seq, int(seq))
            self._halts += 1
            self._change(Mode.ESTOP, Via.ESTOP, cause)
            self._cause = cause

    def fault(self, cause: str) -> bool:
        """-> FAULT (from an operating mode; in ESTOP the e-stop stays in force, in FAULT the
        first cause stays). Returns whether the mode changed."""
        with self._lock:
            if self._mode in HALTED:
                return False
            self._halts += 1
            return self._change(Mode.FAULT, Via.FAULT, cause) is None

    def reset(self, seq: int, cause: str = "") -> str | None:
        """Leave FAULT / ESTOP -> IDLE for a reset asked at sequence number ``seq``; None
        when done, else why not (not halted; or an e-stop came after the reset was asked)."""
        with self._lock:
            if self._mode not in HALTED:
                return f"nothing to reset: the controller is in {self._mode.value}"
            if seq < self._estop_seq:
                return "an e-stop came after this reset was asked: the e-stop stays in force"
            refused = self._change(Mode.IDLE, Via.RESET, cause)
            if refused is None:
                self._cause = ""
            return refused

    def check(self, seq: int) -> str | None:
        """Why a reset asked at ``seq`` would be refused now (None: it would be accepted);
        the controller asks before it resets the robot."""
        with self._lock:
            if self._mode not in HALTED:
                return f"nothing to reset: the controller is in {self._mode.value}"
            if seq < self._estop_seq:
                return "an e-stop came after this reset was asked: the e-stop stays in force"
            return None

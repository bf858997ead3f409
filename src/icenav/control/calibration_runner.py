"""The controller side of a calibration: a procedure's visits, one at a time, inside the loop.

A :class:`~icenav.calibration.procedure.Procedure` (``make_procedure(kind)``) yields visits
(go to ``q_motor``, read the tracker ``n_average`` times, or pass through) and is sent back
what the tracker read. :class:`CalibrationRunner` is the task that drives it in the control
loop, so every move is under the controller's speed limits, Stop and E-STOP:

1. move to the visit at bounded speed (a :class:`~icenav.control.tasks.PathTask` from where
   the robot is);
2. when the visit reads the tracker: hold ``settle_s``, then ask the measurement (in a worker
   thread when the loop runs in real time: a real tracker blocks ``n_average / rate``), and
   hold until it comes; a MISSING reading is retried up to the visit's ``retries``;
3. send the pose (or None) to the procedure, which chooses the next visit;
4. when the procedure returns its recording, hand it to ``on_recording`` (the controller fits
   it in the background) and drive back to where the catheter was before the calibration.

:func:`preview` says what a calibration will do and about how long it takes, before it runs
(the console asks the operator to confirm with it): it drives the procedure with the model's
own tip poses as readings and adds up the moves at the runner's speeds.
:func:`calibration_document` is what the session stores of a finished calibration (its
calibration file's document, fitted model included), so that a reopened session installs it
again.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Generator
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from icenav._typing import Array
from icenav.calibration.procedure import CalibrationOutcome, Visit, VisitGenerator
from icenav.control.modes import Mode
from icenav.control.tasks import Done, PathTask, Running, TaskStatus
from icenav.errors import TrackerError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = [
    "CalibrationPreview",
    "CalibrationRunner",
    "RunnableProcedure",
    "calibration_document",
    "preview",
]


class RunnableProcedure(Protocol):
    """What the runner needs of a :class:`icenav.calibration.procedure.Procedure` (the same
    members, read-only, so that the frozen procedures of ``make_procedure`` match)."""

    @property
    def kind(self) -> str:
        """ "dense", "five_point" or "dense+hysteresis"."""
        ...

    @property
    def label(self) -> str:
        """What the operator reads."""
        ...

    def visits(self) -> VisitGenerator:
        """A new generator of the procedure's visits."""
        ...

    def fit(self, recording: Any) -> CalibrationOutcome:
        """The fit of what the visits recorded."""
        ...


class _Phase(enum.Enum):
    MOVING = "moving"
    SETTLING = "settling"
    MEASURING = "measuring"
    RETURNING = "returning"
    DONE = "done"


@dataclass(frozen=True)
class CalibrationPreview:
    """What a calibration will do, for the operator's confirmation."""

    kind: str
    """The procedure's kind."""
    label: str
    """The procedure's own description."""
    n_visits: int
    """States visited (an adaptive procedure's count is the one on the model)."""
    n_readings: int
    """Tracker readings among them."""
    duration_s: float
    """About how long it takes at the controller's speeds (s), the return included."""
    max_knob_rad: float
    """Largest knob angle it drives to (rad)."""

    def describe(self) -> str:
        """One paragraph for the confirmation dialog."""
        minutes = self.duration_s / 60.0
        took = f"{minutes:.0f} min" if minutes >= 1.5 else f"{self.duration_s:.0f} s"
        return (
            f"{self.label}: {self.n_visits} states, {self.n_readings} tracker readings, about "
            f"{took}. A bench procedure: the catheter bends up to "
            f"{math.degrees(self.max_knob_rad):.0f} deg on each knob at zero roll and "
            "translation, then returns to where it is now; these motions are not recorded "
            "in the roadmap. Stop or E-STOP end it at any time."
        )


def _move_time(q0: Array, q1: Array, v: Array, ramp_s: float) -> float:
    """Time of one PathTask move (s): the slowest joint at v, plus about one ramp."""
    d = float(np.max(np.abs(q1 - q0) / v))
    return d + (ramp_s if d > 0 else 0.0)


def preview(
    procedure: RunnableProcedure,
    q_start: Array,
    max_velocity: Array,
    *,
    settle_s: float,
    ramp_s: float,
    dt: float,
    speed_scale: float = 0.5,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CalibrationPreview:
    """Drive ``procedure`` on the model (each reading is ``forward(q)``) and add up what the
    runner would take: every move at ``speed_scale * max_velocity`` with its ramp, the
    settling and one cycle per reading, and the return to ``q_start``."""
    v = np.asarray(max_velocity, dtype=np.float64) * speed_scale
    q = np.asarray(q_start, dtype=np.float64)
    total = 0.0
    n = readings = 0
    knob = 0.0
    gen = procedure.visits()
    try:
        visit = next(gen)
        while True:
            total += _move_time(q, visit.q_motor, v, ramp_s)
            q = np.asarray(visit.q_motor)
            knob = max(knob, float(np.max(np.abs(q[:2]))))
            n += 1
            pose = None
            if visit.n_average > 0:
                readings += 1
                total += settle_s + dt
                pose = forward(q, geometry, check=False)
            visit = gen.send(pose)
    except StopIteration:
        pass
    total += _move_time(q, np.asarray(q_start, dtype=np.float64), v, ramp_s)
    return CalibrationPreview(procedure.kind, procedure.label, n, readings, total, knob)


class CalibrationRunner:
    """A calibration procedure as a controller task (see the module docstring).

    Parameters
    ----------
    procedure : RunnableProcedure
        What to visit.
    measure : callable
        ``measure(n_average) -> Future`` of the averaged tip2base (4, 4) or None (MISSING);
        the controller runs the tracker read in a worker (or inline when stepped by hand).
    on_recording : callable
        Called once with the procedure's recording when its last visit is done (the fit
        starts there); the runner then drives back to ``q_start``.
    q_start : array, shape (4,)
        Where the catheter is before the calibration (and is returned to).
    max_velocity : array, shape (4,)
        The controller's speed limits (rad/s, rad/s, rad/s, mm/s).
    settle_s, ramp_s : float
        Wait at each read state before reading (s); ramp of each move (s).
    n_expected : int
        Visits expected (from :func:`preview`), for the progress.
    """

    mode = Mode.CALIBRATING

    def __init__(
        self,
        procedure: RunnableProcedure,
        measure: Callable[[int], Future[Array | None]],
        on_recording: Callable[[Any], None],
        *,
        q_start: Array,
        max_velocity: Array,
        settle_s: float,
        ramp_s: float,
        n_expected: int,
    ) -> None:
        self.procedure = procedure
        self._measure = measure
        self._on_recording = on_recording
        self.q_start = np.array(q_start, dtype=np.float64)
        self._vmax = np.asarray(max_velocity, dtype=np.float64)
        self._settle_s = float(settle_s)
        self._ramp_s = float(ramp_s)
        self._n_expected = max(1, int(n_expected))
        self._gen: Generator[Visit, Array | None, Any] = procedure.visits()
        self._visit: Visit | None = None
        self._phase = _Phase.MOVING
        self._move: PathTask | None = None
        self._wait = 0.0
        self._misses = 0
        self._reading: Future[Array | None] | None = None
        self._done_visits = 0
        self.missing = 0
        """Visits whose readings stayed MISSING."""
        self._prefix = f"calibration ({procedure.kind}): {procedure.label}"
        self.label = self._prefix

    @property
    def progress(self) -> float:
        if self._phase in (_Phase.RETURNING, _Phase.DONE):
            return 1.0
        return min(0.99, self._done_visits / self._n_expected)

    def _next_visit(self, pose: Array | None) -> None:
        """Send ``pose`` (None for the first visit, a pass-through or MISSING) and take the
        next visit, or end the procedure and start the return."""
        try:
            self._visit = next(self._gen) if self._visit is None else self._gen.send(pose)
        except StopIteration as end:
            self._visit = None
            self._on_recording(end.value)
            self._phase = _Phase.RETURNING
            self._move = None
            self.label = f"{self._prefix}; returning to the start"
            return
        self._phase = _Phase.MOVING
        self._move = None
        self.label = f"{self._prefix}; {self._visit.phase}"

    def step(self, q_measured: Array, dt: float) -> TaskStatus:
        if self._phase is _Phase.MOVING and self._visit is None:
            self._next_visit(None)
        if self._phase is _Phase.RETURNING:
            if self._move is None:
                self._move = self._path(q_measured, self.q_start)
            status = self._move.step(q_measured, dt)
            if isinstance(status, Running):
                return status
            self._phase = _Phase.DONE
            missing = f", {self.missing} not tracked" if self.missing else ""
            return Done(f"{self._prefix}: back at the start{missing}; fitting")
        if self._phase is _Phase.DONE:
            return Done()
        visit = self._visit
        assert visit is not None
        if self._phase is _Phase.MOVING:
            if self._move is None:
                self._move = self._path(q_measured, visit.q_motor)
            status = self._move.step(q_measured, dt)
            if isinstance(status, Running):
                return status
            if visit.n_average == 0:
                self._done_visits += 1
                self._next_visit(None)
                return Running(visit.q_motor)
            self._phase = _Phase.SETTLING
            self._wait = 0.0
            self._misses = 0
        if self._phase is _Phase.SETTLING:
            self._wait += dt
            if self._wait >= self._settle_s:
                self._phase = _Phase.MEASURING
                self._reading = self._measure(visit.n_average)
            return Running(visit.q_motor)
        return self._measuring(visit)

    def _measuring(self, visit: Visit) -> TaskStatus:
        reading = self._reading
        assert reading is not None
        if not reading.done():
            return Running(visit.q_motor)  # a real tracker is still averaging: hold
        try:
            pose = reading.result()
        except TrackerError:  # a dropped reading: as MISSING (other errors end in FAULT)
            pose = None
        if pose is not None:
            p = np.asarray(pose, dtype=np.float64)
            pose = p if p.shape == (4, 4) and np.all(np.isfinite(p)) else None
        if pose is None and self._misses < visit.retries:
            self._misses += 1
            self._reading = self._measure(visit.n_average)
            return Running(visit.q_motor)
        self.missing += pose is None
        self._done_visits += 1
        self._next_visit(pose)
        return Running(visit.q_motor)

    def _path(self, q_from: Array, q_to: Array) -> PathTask:
        return PathTask(
            np.vstack([q_from, q_to]),
            self._vmax,
            mode=Mode.CALIBRATING,
            label=self.label,
            ramp_s=self._ramp_s,
        )


def calibration_document(outcome: CalibrationOutcome) -> dict[str, Any] | None:
    """The calibration-file document (:class:`icenav.calibration.files.CalibrationFile`,
    version 3: the samples, the kind and the fitted model) of a finished calibration, for
    the session (``icenav export-calibration`` writes it out with the session's
    registration); None for a kind a calibration file does not hold (the registration,
    which the session stores apart). Some 0.1-0.5 s for ``dense+hysteresis``: call it off the
    control loop."""
    from icenav.calibration.files import CalibrationFile
    from icenav.calibration.model_files import MODEL_KINDS

    if outcome.kind not in MODEL_KINDS:
        return None
    return CalibrationFile.from_outcome(outcome).to_dict()

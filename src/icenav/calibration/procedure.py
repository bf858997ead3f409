"""A calibration procedure: the one description of a calibration that every runner drives.

A procedure is a *generator of visits*: it yields :class:`Visit` (go to this motor state,
then read the tracker ``n_average`` times, or pass through when 0) and is sent back what the
tracker read there (the averaged ``tip2base`` (4, 4) -- or, for a visit in the ``tracker``
frame, the averaged ``sensor2tracker`` that the registration itself needs -- or None when it
stayed MISSING through the visit's retries). A fixed motion (the dense raster, the
hysteresis sweeps, the circles) never looks at what it is sent; an adaptive one (the
paper's 5-point calibration, which searches the knobs until the tip reaches each target)
chooses its next visit from it. When the generator returns, its value is the
:class:`~icenav.calibration.plans.Recording` of every visit, and :meth:`Procedure.fit` turns
it into a :class:`CalibrationOutcome`.

Two runners drive the same generator, so the console, the command line and the
evaluations run the same algorithm:

- :func:`run_procedure` on a robot (or the twin's ``move``) and a tracker
  (:class:`icenav.devices.tracker.TrackerBackend`), synchronously;
- the controller's calibration runner (:mod:`icenav.control`), one visit at a time inside
  the control loop, under its speed limits, stop and e-stop.

::

    procedure = make_procedure("dense", geometry=g)         # icenav.calibration.procedures
    outcome = procedure.fit(run_procedure(procedure, move, tracker))
    print(outcome.quality.describe())
    outcome.knob_map                                           # the controller's compensation
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.errors import ConfigurationError, ShapeError

__all__ = [
    "CalibrationOutcome",
    "FitQuality",
    "Procedure",
    "Visit",
    "VisitGenerator",
    "VISIT_FRAMES",
    "run_procedure",
    "run_visits",
]

VISIT_FRAMES = ("base", "tracker")
"""What a visit reads: ``base`` the tip pose in the robot base frame (``measure_tip2base``),
``tracker`` the sensor pose in the tracker frame (``measure_sensor2tracker``; the registration
procedure, which estimates the base frame, reads this)."""


@dataclass(frozen=True, eq=False)
class Visit:
    """One state of a calibration: go there, then read the tracker (or pass through)."""

    q_motor: Array
    """(4,) motor joint state to go to (rad, rad, rad, mm)."""
    n_average: int
    """Tracker samples to average once there; 0: pass through without reading."""
    retries: int
    """MISSING samples tolerated before the visit is recorded as not measured."""
    phase: str
    """What this visit belongs to (``dense raster``, ``five-point search``, ...), for
    progress reports and for the fits."""
    frame: str = "base"
    """What to read there (:data:`VISIT_FRAMES`): ``base`` (tip2base, the default) or
    ``tracker`` (sensor2tracker)."""

    def __post_init__(self) -> None:
        q = check_finite(self.q_motor, "q_motor", "rad, rad, rad, mm")
        if q.shape != (4,):
            raise ShapeError(f"a visit's q_motor must have shape (4,), got {q.shape}")
        q.setflags(write=False)
        object.__setattr__(self, "q_motor", q)
        if int(self.n_average) < 0 or int(self.retries) < 0:
            raise ConfigurationError(
                f"n_average and retries must be >= 0, got {self.n_average} and {self.retries}"
            )
        if self.frame not in VISIT_FRAMES:
            raise ConfigurationError(
                f"a visit's frame must be one of {VISIT_FRAMES}, got {self.frame!r}"
            )


VisitGenerator = Generator[Visit, "Array | None", Any]
"""Yields visits, is sent the averaged tip2base (4, 4) read at each (None: MISSING or not
read), returns the :class:`~icenav.calibration.plans.Recording` of every visit."""


@dataclass(frozen=True)
class FitQuality:
    """How well a calibration's model explains its own measurements (shown to the operator
    at the end of a calibration)."""

    n_used: int
    """Tracked samples the fit used."""
    n_missing: int
    """Visits the tracker did not see (MISSING through the retries)."""
    rms_mm: float
    """RMS tip position residual of the fitted model on the samples (mm)."""
    max_mm: float
    """Largest tip position residual (mm)."""
    rms_deg: float
    """RMS tip orientation residual (deg)."""
    n_left_out: int = 0
    """Tracked samples the residual leaves out (see ``left_out``)."""
    left_out: str = ""
    """Why they are left out (empty when none is)."""
    max_deg: float = math.nan
    """Largest tip orientation residual (deg); NaN when the fit has no orientation."""

    def describe(self) -> str:
        """What the operator reads at the end of a calibration: samples used / not tracked /
        left out and why, then the residuals in mm and deg."""
        parts = [f"{self.n_used} samples used"]
        if self.n_missing:
            parts.append(f"{self.n_missing} not tracked (sensor MISSING)")
        if self.n_left_out:
            parts.append(f"{self.n_left_out} left out ({self.left_out})")
        text = ", ".join(parts) + f"; residual {self.rms_mm:.2f} mm RMS (max {self.max_mm:.2f} mm)"
        if math.isfinite(self.rms_deg):
            text += f", {self.rms_deg:.2f} deg RMS"
            if math.isfinite(self.max_deg):
                text += f" (max {self.max_deg:.2f} deg)"
        return text


@dataclass(frozen=True, eq=False)
class CalibrationOutcome:
    """What a calibration produced."""

    kind: str
    """The procedure's kind ("dense", "five_point", "dense+hysteresis", "registration")."""
    knob_map: Any
    """The compensation the controller installs: ``model_to_motor`` / ``motor_to_model``
    (:class:`icenav.control.controller.KnobMap`), and ``observe(q_motor)`` when it keeps
    state; None for the registration."""
    calibration_set: Any
    """The tracked samples behind it (:class:`icenav.compensation.elasticity.CalibrationSet`),
    for the session and for calibration files; None for the registration."""
    quality: FitQuality
    """Fit quality, for the operator."""
    details: Any = None
    """Kind-specific results (:class:`icenav.calibration.catheter.CatheterCalibration` for
    dense+hysteresis, the :class:`icenav.devices.registration.Registration` for the
    registration, the map's build report for dense and five_point)."""


@runtime_checkable
class Procedure(Protocol):
    """A calibration: its visits (a generator) and the fit of what they measured."""

    @property
    def kind(self) -> str:
        """The kind: "dense", "five_point", "dense+hysteresis" or "registration"."""
        ...

    @property
    def label(self) -> str:
        """What the operator reads ("Dense grid: 361 points")."""
        ...

    def visits(self) -> VisitGenerator:
        """A new generator of this procedure's visits (see the module docstring)."""
        ...

    def fit(self, recording: Any) -> CalibrationOutcome:
        """Fit the calibration from the recording the visits returned."""
        ...


def run_procedure(
    procedure: Procedure,
    move: Callable[[Array], object],
    tracker: Any,
    *,
    progress: Callable[[int, Visit], None] | None = None,
) -> Any:
    """Drive ``procedure`` synchronously and return its recording (``procedure.fit`` it).

    Parameters
    ----------
    move : callable
        ``move(q_motor (4,))``: go there and return once the catheter has settled.
    tracker : TrackerBackend or callable
        A tracker (:class:`icenav.devices.tracker.TrackerBackend`; a visit in the ``base``
        frame reads ``measure_tip2base(n_average)``, one in the ``tracker`` frame
        ``measure_sensor2tracker(n_average)``), or a callable ``measure(n_average) ->
        tip2base (4, 4) | None`` (``base`` visits only). A reading that is None (MISSING)
        is retried up to the visit's ``retries``.
    progress : callable, optional
        ``progress(i, visit)`` after each visit (i counts from 1).
    """
    return run_visits(procedure.visits(), move, tracker, progress=progress)


def _reader(tracker: Any, frame: str) -> Callable[[int], Any]:
    name = "measure_tip2base" if frame == "base" else "measure_sensor2tracker"
    method = getattr(tracker, name, None)
    if callable(method):
        return method
    if frame == "base" and callable(tracker):
        return tracker
    raise ConfigurationError(
        f"a visit in the {frame!r} frame needs a tracker with {name}(n_average), got "
        f"{type(tracker).__name__}"
    )


def run_visits(
    visits: VisitGenerator,
    move: Callable[[Array], object],
    tracker: Any,
    *,
    progress: Callable[[int, Visit], None] | None = None,
) -> Any:
    """Drive a visit generator (:meth:`Procedure.visits`, or
    :func:`icenav.calibration.procedures.plan_visits` of a plan) as :func:`run_procedure`
    does, and return what it returns."""
    i = 0
    try:
        visit = next(visits)
        while True:
            move(visit.q_motor)
            pose: Array | None = None
            if visit.n_average > 0:
                read = _reader(tracker, visit.frame)
                for _ in range(visit.retries + 1):
                    pose = read(visit.n_average)
                    if pose is not None:
                        pose = _check_pose(pose)
                        break
            i += 1
            if progress is not None:
                progress(i, visit)
            visit = visits.send(pose)
    except StopIteration as done:
        return done.value


def _check_pose(pose: ArrayLike) -> Array:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (4, 4) or not np.all(np.isfinite(p)):
        raise ShapeError(f"a tracker reading must be a finite (4, 4) pose, got shape {p.shape}")
    return p

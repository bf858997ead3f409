"""A calibration procedure: the one description of a calibration that every runner drives.

A procedure is a *generator of visits*: it yields :class:`Visit` (go to this motor state,
then read the tracker ``n_average`` times, or pass through when 0) and is sent back what the
tracker read there (the averaged ``tip2base`` (4, 4), or None when it stayed MISSING through
the visit's retries). A fixed motion (the dense raster, the hysteresis sweeps, the circles)
never looks at what it is sent; an adaptive one (the paper's 5-point calibration, which
searches the knobs until the tip reaches each target) chooses its next visit from it. When
the generator returns, its value is the :class:`~icenav.calibration.plans.Recording` of
every visit, and :meth:`Procedure.fit` turns it into a :class:`CalibrationOutcome`.

Two runners drive the same generator, so the console, the command line and the
evaluations run the same algorithm:

- :func:`run_procedure` on a robot (or the twin's ``move``) and a tracker, synchronously;
- the controller's calibration runner (:mod:`icenav.control`), one visit at a time inside
  the control loop, under its speed limits, stop and e-stop.

::

    procedure = make_procedure("dense", geometry=g)         # icenav.calibration.procedures
    outcome = procedure.fit(run_procedure(procedure, move, tracker))
    outcome.knob_map                                           # the controller's compensation
"""

from __future__ import annotations

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
    "run_procedure",
]


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

    def describe(self) -> str:
        """One line for the operator."""
        missing = f", {self.n_missing} not tracked" if self.n_missing else ""
        return (
            f"{self.n_used} samples{missing}; residual {self.rms_mm:.2f} mm RMS "
            f"(max {self.max_mm:.2f} mm), {self.rms_deg:.2f} deg RMS"
        )


@dataclass(frozen=True, eq=False)
class CalibrationOutcome:
    """What a calibration produced."""

    kind: str
    """The procedure's kind ("dense", "five_point", "dense+hysteresis")."""
    knob_map: Any
    """The compensation the controller installs: ``model_to_motor`` / ``motor_to_model``
    (:class:`icenav.control.controller.KnobMap`), and ``observe(q_motor)`` when it keeps
    state."""
    calibration_set: Any
    """The tracked samples behind it (:class:`icenav.compensation.elasticity.CalibrationSet`),
    for the session and for calibration files."""
    quality: FitQuality
    """Fit quality, for the operator."""
    details: Any = None
    """Kind-specific results (e.g. :class:`icenav.calibration.catheter.CatheterCalibration`)."""


@runtime_checkable
class Procedure(Protocol):
    """A calibration: its visits (a generator) and the fit of what they measured."""

    kind: str
    """"dense", "five_point" or "dense+hysteresis"."""
    label: str
    """What the operator reads ("Dense grid: 361 points")."""

    def visits(self) -> VisitGenerator:
        """A new generator of this procedure's visits (see the module docstring)."""
        ...

    def fit(self, recording: Any) -> CalibrationOutcome:
        """Fit the calibration from the recording the visits returned."""
        ...


def run_procedure(
    procedure: Procedure,
    move: Callable[[Array], object],
    measure: Callable[[int], Array | None],
    *,
    progress: Callable[[int, Visit], None] | None = None,
) -> Any:
    """Drive ``procedure`` synchronously and return its recording.

    Parameters
    ----------
    move : callable
        ``move(q_motor (4,))``: go there and return once the catheter has settled.
    measure : callable
        ``measure(n_average) -> tip2base (4, 4) | None``: one tracker reading averaged over
        ``n_average`` samples (None when MISSING); retried by this runner up to the visit's
        ``retries``.
    progress : callable, optional
        ``progress(i, visit)`` after each visit (i counts from 1).
    """
    gen = procedure.visits()
    i = 0
    try:
        visit = next(gen)
        while True:
            move(visit.q_motor)
            pose: Array | None = None
            if visit.n_average > 0:
                for _ in range(visit.retries + 1):
                    pose = measure(visit.n_average)
                    if pose is not None:
                        pose = _check_pose(pose)
                        break
            i += 1
            if progress is not None:
                progress(i, visit)
            visit = gen.send(pose)
    except StopIteration as done:
        return done.value


def _check_pose(pose: ArrayLike) -> Array:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (4, 4) or not np.all(np.isfinite(p)):
        raise ShapeError(f"a tracker reading must be a finite (4, 4) pose, got shape {p.shape}")
    return p

"""Motion plans and what they recorded: the fixed part of every calibration.

A :class:`MotionPlan` says where to go (motor joint states in order) and how many tracker
samples to average at each state (0: pass through); a :class:`Recording` is what the tracker
read there (NaN where it stayed MISSING). A plan runs as the visits of a calibration
procedure (:func:`icenav.calibration.procedures.plan_visits`) through the one runner of
:mod:`icenav.calibration.procedure` (synchronously on a robot or the twin) or the
controller's calibration runner (inside the control loop); the fits read recordings.

Plans of the paper (Sec. IV-A, "Model calibration"): :func:`raster_grid`, the dense raster over
+-90 deg at 10 deg steps (19 x 19 = 361 knob pairs; the paper says 360), serpentine so the
knobs never jump; :func:`five_point_targets`, the five targets the 5-point search aims at
(:class:`icenav.calibration.procedures.FivePointProcedure`). Ours: the hysteresis sweeps
(:mod:`icenav.calibration.hysteresis`), the knob circles (:mod:`icenav.calibration.transmission`)
and the roll circles (:mod:`icenav.calibration.tracker_bias`).

Unmeasured states are skipped by :func:`calibration_set_from` with a :class:`SkippedSample`
record (also logged as a warning on the ``icenav.calibration.plans`` logger).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.elasticity import CalibrationSet
from icenav.errors import ConfigurationError, InvalidValueError, ShapeError, TrackerError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = [
    "CalibrationRun",
    "MotionPlan",
    "Recording",
    "SkippedSample",
    "calibration_set_from",
    "five_point_targets",
    "raster_grid",
]

log = logging.getLogger("icenav.calibration.plans")


@dataclass(frozen=True)
class SkippedSample:
    """A sample that could not be measured (the warning record)."""

    q_motor: Array
    """(4,) motor joint state (rad, rad, rad, mm)."""
    attempts: int
    """How many measurements were tried."""
    reason: str
    """Why it was skipped."""


@dataclass(frozen=True)
class CalibrationRun:
    """Result of a calibration procedure."""

    calibration: CalibrationSet
    """The measured samples."""
    skipped: tuple[SkippedSample, ...]
    """Samples skipped after retries (empty when all went well)."""
    n_moves: int
    """Robot moves made (including search moves)."""


def _check_counts(retries: int, n_average: int) -> None:
    if int(retries) < 0:
        raise ConfigurationError(f"retries must be >= 0, got {retries}")
    if int(n_average) < 1:
        raise ConfigurationError(f"n_average must be >= 1, got {n_average}")


# --- motion plans ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MotionPlan:
    """A fixed calibration motion: the motor joint states to visit in order and how many
    tracker samples to average at each, once the robot has arrived there."""

    q_motor: Array
    """(n, 4) motor joint states (rad, rad, rad, mm), visited in order."""
    n_average: NDArray[np.int64]
    """(n,) tracker samples averaged at each state; 0: pass through without reading."""
    retries: NDArray[np.int64]
    """(n,) MISSING samples tolerated at each state before it is recorded as not measured."""
    segments: tuple[tuple[int, int, str], ...]
    """(start, stop, phase): consecutive index ranges covering the plan, named for progress
    reports and for the fits (``sweep phi1``, ``knob circles``, ...)."""

    def __post_init__(self) -> None:
        q = check_finite(self.q_motor, "q_motor")
        if q.ndim != 2 or q.shape[1] != 4:
            raise ShapeError(f"a plan's q_motor must have shape (n, 4), got {q.shape}")
        n = q.shape[0]
        counts = []
        for name in ("n_average", "retries"):
            v = np.asarray(getattr(self, name))
            if v.shape != (n,) or not np.issubdtype(v.dtype, np.integer) or np.any(v < 0):
                raise ConfigurationError(
                    f"a plan's {name} must be {n} integers >= 0, got {v.dtype} {v.shape}"
                )
            counts.append(v.astype(np.int64))
        stop = 0
        for start, end, phase in self.segments:
            if start != stop or end < start or not isinstance(phase, str):
                raise ConfigurationError(
                    f"plan segments must be consecutive (start, stop, name) ranges, got "
                    f"{self.segments}"
                )
            stop = end
        if stop != n:
            raise ConfigurationError(f"plan segments cover {stop} of {n} states")
        for a in (q, *counts):
            a.setflags(write=False)
        object.__setattr__(self, "q_motor", q)
        object.__setattr__(self, "n_average", counts[0])
        object.__setattr__(self, "retries", counts[1])

    @classmethod
    def make(
        cls, q_motor: ArrayLike, phase: str, n_average: ArrayLike = 1, retries: ArrayLike = 10
    ) -> MotionPlan:
        """One segment named ``phase``; ``n_average`` and ``retries`` scalars or (n,)."""
        q = check_finite(q_motor, "q_motor")
        if q.ndim != 2 or q.shape[1] != 4:
            raise ShapeError(f"q_motor must have shape (n, 4), got {q.shape}")
        n = q.shape[0]
        return cls(
            q_motor=q,
            n_average=np.broadcast_to(np.asarray(n_average, dtype=np.int64), (n,)).copy(),
            retries=np.broadcast_to(np.asarray(retries, dtype=np.int64), (n,)).copy(),
            segments=((0, n, phase),),
        )

    @classmethod
    def concat(cls, plans: Sequence[MotionPlan]) -> MotionPlan:
        """The plans one after the other (their segments kept, shifted)."""
        if not plans:
            raise ConfigurationError("concat needs at least one plan")
        segments: list[tuple[int, int, str]] = []
        offset = 0
        for p in plans:
            segments += [(a + offset, b + offset, name) for a, b, name in p.segments]
            offset += p.n
        return cls(
            q_motor=np.vstack([p.q_motor for p in plans]),
            n_average=np.concatenate([p.n_average for p in plans]),
            retries=np.concatenate([p.retries for p in plans]),
            segments=tuple(segments),
        )

    @property
    def n(self) -> int:
        """Number of states."""
        return int(self.q_motor.shape[0])

    def phase_at(self, i: int) -> str:
        """The name of the segment that state ``i`` belongs to."""
        for a, b, name in self.segments:
            if a <= i < b:
                return name
        raise InvalidValueError(f"state {i} is not in a plan of {self.n}")

    def segment(self, phase: str) -> slice:
        """Index range of the (first) segment named ``phase``."""
        for a, b, name in self.segments:
            if name == phase:
                return slice(a, b)
        raise InvalidValueError(
            f"no segment {phase!r} in the plan ({[s[2] for s in self.segments]})"
        )


@dataclass(frozen=True, eq=False)
class Recording:
    """What a :class:`MotionPlan` measured."""

    plan: MotionPlan
    """The plan that was executed."""
    tip2base: Array
    """(n, 4, 4) tracked tip pose at each state, averaged (mm, base frame); NaN where the
    plan did not read the tracker or it stayed MISSING through the retries."""
    attempts: NDArray[np.int64]
    """(n,) tracker readings made at each state."""

    def __post_init__(self) -> None:
        n = self.plan.n
        t = np.asarray(self.tip2base, dtype=np.float64)
        if t.shape != (n, 4, 4):
            raise ShapeError(f"a recording of {n} states needs tip2base (n, 4, 4), got {t.shape}")
        a = np.asarray(self.attempts, dtype=np.int64)
        if a.shape != (n,):
            raise ShapeError(f"a recording of {n} states needs attempts (n,), got {a.shape}")
        t.setflags(write=False)
        a.setflags(write=False)
        object.__setattr__(self, "tip2base", t)
        object.__setattr__(self, "attempts", a)

    @property
    def measured(self) -> NDArray[np.bool_]:
        """(n,) states with a tracked pose."""
        return np.all(np.isfinite(self.tip2base.reshape(self.plan.n, -1)), axis=1)

    def part(self, phase: str) -> tuple[Array, Array]:
        """Motor states (m, 4) and poses (m, 4, 4) (NaN: not measured) of a segment."""
        sl = self.plan.segment(phase)
        return self.plan.q_motor[sl], self.tip2base[sl]


def raster_grid(step: float = math.radians(10.0), limit: float = math.radians(90.0)) -> Array:
    """Serpentine raster of knob pairs over [-limit, limit]^2 (rad), as (n, 4) joint states.

    phi1 steps slowly; phi2 sweeps up, then down on the next line, so consecutive samples
    are always neighbours. 10 deg over +-90 deg gives 19 x 19 = 361 samples.
    """
    if not (0.0 < step <= limit <= math.pi):
        raise ConfigurationError(
            f"need 0 < step <= limit <= pi rad, got step={step} rad, limit={limit} rad"
        )
    n = int(round(2.0 * limit / step))
    if abs(n * step - 2.0 * limit) > 1e-9:
        raise ConfigurationError(
            f"2 * limit must be a multiple of step: limit={math.degrees(limit):.3f} deg, "
            f"step={math.degrees(step):.3f} deg"
        )
    ax = np.linspace(-limit, limit, n + 1)
    rows = []
    for i, a in enumerate(ax):
        line = ax if i % 2 == 0 else ax[::-1]
        for b in line:
            rows.append((a, b, 0.0, 0.0))
    return np.array(rows)


def calibration_set_from(
    recording: Recording,
    phase: str | None = None,
    *,
    catheter_id: str = "",
    vessel: str = "straight",
) -> CalibrationRun:
    """The measured states of a recording (or of its segment ``phase``) as a calibration set
    named after the segment; unmeasured states that the plan read are skipped (logged)."""
    plan = recording.plan
    sl = slice(0, plan.n) if phase is None else plan.segment(phase)
    method = phase if phase is not None else plan.segments[0][2] if plan.segments else "points"
    q = plan.q_motor[sl]
    kept_q: list[Array] = []
    kept_t: list[Array] = []
    skipped: list[SkippedSample] = []
    for i, (qi, pose, k, attempts) in enumerate(
        zip(q, recording.tip2base[sl], plan.n_average[sl], recording.attempts[sl], strict=True)
    ):
        if k == 0:
            continue
        if not np.all(np.isfinite(pose)):
            rec = SkippedSample(q_motor=qi.copy(), attempts=int(attempts), reason="tracker MISSING")
            log.warning(
                "calibration sample %d at q=%s skipped: tracker MISSING after %d attempts",
                i,
                np.round(np.degrees(qi[:3]), 2).tolist(),
                attempts,
            )
            skipped.append(rec)
        else:
            kept_q.append(qi.copy())
            kept_t.append(np.array(pose))
    if len(kept_q) < 3:
        raise TrackerError(
            f"only {len(kept_q)} of {q.shape[0]} calibration samples were measured; "
            "check the tracker (sensor in the field volume, cable)"
        )
    cal = CalibrationSet(
        q_motor=np.array(kept_q),
        tip2base=np.array(kept_t),
        catheter_id=catheter_id,
        vessel=vessel,
        method=method,
    )
    return CalibrationRun(calibration=cal, skipped=tuple(skipped), n_moves=q.shape[0])


def five_point_targets(geometry: CatheterGeometry = DEFAULT_GEOMETRY) -> tuple[Array, Array]:
    """The simplified calibration's targets.

    Returns
    -------
    knobs : ndarray, shape (5, 2)
        Model knob pairs (rad): centre, +-limit AP (phi1), +-limit RL (phi2).
    xy : ndarray, shape (5, 2)
        Model tip (x, y) for them in the base frame (mm): y = 0 for the AP bends, x = 0 for
        the RL bends.
    """
    lim = geometry.knob_limit
    knobs = np.array([[0.0, 0.0], [lim, 0.0], [-lim, 0.0], [0.0, lim], [0.0, -lim]])
    q = np.zeros((5, 4))
    q[:, :2] = knobs
    return knobs, forward(q, geometry)[:, :2, 3]

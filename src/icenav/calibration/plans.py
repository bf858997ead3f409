"""Calibration procedures: drive the robot, read the tracker, return calibration data.

They talk to the robot and the tracker only through small interfaces, so the same code
runs on the digital twin today and on the hardware later:

- the robot: a :class:`~icenav.devices.robot.RobotBackend` (``command_position`` then a
  ``settle`` callable that returns when the axes have arrived), or any callable
  ``move(q_motor)`` (e.g. ``CatheterPlant.move``);
- the tracker: any object with ``measure_tip2base() -> (4, 4) ndarray or None`` (the tip
  pose in the base frame, after the tracker-to-base registration; ``None`` when the sensor
  is MISSING).

Procedures (paper Sec. IV-A, "Model scenarios" and "Model calibration"):

- :func:`calibrate_dense`: the raster over +-90 deg at 10 deg steps (19 x 19 = 361 knob
  pairs; the paper says 360), in serpentine order so the knobs never jump.
- :func:`calibrate_five_point`: the simplified calibration: the centre, the 90 deg bends in
  the anterior-posterior plane with the tip in y = 0 and in the right-left plane with
  x = 0. The paper jogs the knobs until the tip is there; here a damped Gauss-Newton
  search with the tracker finds the *motor* knobs that put the real tip at the model's
  (x, y) for those bends (z ignored, as the paper does, because of the arc constraint).
- :func:`calibrate_points`: any list of knob pairs (N-point subsets, 9, 13, ...).
- :func:`identify_hysteresis`: short up/down sweeps of each knob and of the roll, fitted
  with :func:`icenav.compensation.hysteresis.identify`.

Every fixed motion is a :class:`MotionPlan` (where to go, how many tracker samples to average
there) executed by :func:`execute_plan` into a :class:`Recording`, and fitted separately
(:func:`hysteresis_plan` and :func:`fit_hysteresis`; the knob circles and roll circles of
:mod:`icenav.compensation.transmission` and :mod:`icenav.compensation.tracker_bias` likewise). So
the same plans run
here synchronously (the bench, the twin) and inside the controller's loop as a task
(:class:`icenav.control.controller.PlanTask`), whose fits run the same code. The 5-point search is
adaptive (each move depends on the last reading) and stays a procedure.

Missing samples are retried, then skipped with a :class:`SkippedSample` record (also logged
as a warning on the ``icenav.calibration.plans`` logger). Progress goes to a callback.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state
from icenav.compensation.elasticity import CalibrationSet
from icenav.compensation.hysteresis import (
    HysteresisCompensator,
    HysteresisFit,
    identify,
    sweep_path,
)
from icenav.devices.robot import RobotBackend
from icenav.errors import ConfigurationError, InvalidValueError, ShapeError, TrackerError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.geometry.kinematics import inverse as kin_inverse

__all__ = [
    "CalibrationRun",
    "HysteresisIdentification",
    "HysteresisPlan",
    "MotionPlan",
    "Mover",
    "Progress",
    "Recording",
    "SkippedSample",
    "TipTracker",
    "as_mover",
    "calibrate_dense",
    "calibrate_five_point",
    "calibrate_points",
    "calibration_set_from",
    "execute_plan",
    "fit_hysteresis",
    "five_point_targets",
    "hysteresis_plan",
    "identify_hysteresis",
    "raster_grid",
]

log = logging.getLogger("icenav.calibration.plans")

Mover = Callable[[Array], object]
"""``move(q_motor)``: command the motor joint state (rad, rad, rad, mm) and return once
there (the return value is ignored)."""


@runtime_checkable
class TipTracker(Protocol):
    """What calibration needs from a tracker."""

    def measure_tip2base(self) -> NDArray[np.float64] | None:
        """Tip pose (4, 4) in the base frame (mm), or None when the sensor is MISSING."""
        ...


@dataclass(frozen=True)
class Progress:
    """A progress report, sent to the ``progress`` callback after each sample."""

    done: int
    """Samples finished (measured or skipped)."""
    total: int
    """Samples planned."""
    q_motor: Array
    """(4,) motor joint state of the sample just finished."""
    phase: str
    """What is running (``dense-raster``, ``five-point``, ``sweep phi1``, ...)."""


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


ProgressFn = Callable[[Progress], None]


def as_mover(robot: RobotBackend | Mover, settle: Callable[[], None] | None = None) -> Mover:
    """A ``move(q_motor)`` callable for a robot backend or a plain callable.

    For a :class:`RobotBackend`, ``move`` calls ``command_position(q)`` and then
    ``settle()`` (which must return when the axes have arrived, e.g. by polling
    ``read_state``); without ``settle`` a backend is refused, because a calibration must
    not read the tracker while the catheter still moves.
    """
    if isinstance(robot, RobotBackend):
        if settle is None:
            raise ConfigurationError(
                "a RobotBackend needs a settle() callable that returns once the axes have "
                "arrived (calibration must not read the tracker while the catheter moves)"
            )
        backend = robot
        wait = settle

        def move(q: Array) -> None:
            backend.command_position(q)
            wait()

        return move
    if callable(robot):
        return robot
    raise ConfigurationError(
        f"robot must be a RobotBackend or a callable move(q_motor), got {type(robot).__name__}"
    )


def _measure(tracker: TipTracker, retries: int, n_average: int) -> tuple[Array | None, int]:
    """Average of n_average valid tip poses (retrying MISSING), and the attempts made."""
    poses: list[Array] = []
    attempts = 0
    misses = 0
    while len(poses) < n_average:
        attempts += 1
        t = tracker.measure_tip2base()
        if t is None:
            misses += 1
            if misses > retries:
                return None, attempts
            continue
        arr = np.asarray(t, dtype=np.float64)
        if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
            raise TrackerError(f"tracker returned a bad pose (shape {arr.shape} or non-finite)")
        poses.append(arr)
    return _average_poses(np.asarray(poses)), attempts


def _average_poses(poses: Array) -> Array:
    """Mean of poses (n, 4, 4): mean position, rotation projected from the mean matrix (one
    pose: itself)."""
    if poses.shape[0] == 1:
        return np.array(poses[0])
    out = np.eye(4)
    out[:3, 3] = poses[:, :3, 3].mean(axis=0)
    m = poses[:, :3, :3].mean(axis=0)
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    out[:3, :3] = r
    return out


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


def execute_plan(
    robot: RobotBackend | Mover,
    tracker: TipTracker,
    plan: MotionPlan,
    *,
    settle: Callable[[], None] | None = None,
    progress: ProgressFn | None = None,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> Recording:
    """Drive ``plan`` state by state and read the tracker where it says (averaging its
    ``n_average`` samples, retrying MISSING ones up to its ``retries``); progress after each
    state. The controller runs the same plans as a task
    (:class:`icenav.control.controller.PlanTask`).
    """
    if not isinstance(plan, MotionPlan):
        raise ConfigurationError(f"plan must be a MotionPlan, got {type(plan).__name__}")
    check_joint_state(plan.q_motor, geometry.joint_limits, name="plan q_motor")
    move = as_mover(robot, settle)
    poses = np.full((plan.n, 4, 4), np.nan)
    attempts = np.zeros(plan.n, dtype=np.int64)
    for i, q in enumerate(plan.q_motor):
        move(q)
        k = int(plan.n_average[i])
        if k > 0:
            pose, attempts[i] = _measure(tracker, int(plan.retries[i]), k)
            if pose is not None:
                poses[i] = pose
        if progress is not None:
            progress(Progress(done=i + 1, total=plan.n, q_motor=q.copy(), phase=plan.phase_at(i)))
    return Recording(plan=plan, tip2base=poses, attempts=attempts)


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


def calibrate_points(
    robot: RobotBackend | Mover,
    tracker: TipTracker,
    q_points: ArrayLike,
    *,
    settle: Callable[[], None] | None = None,
    retries: int = 10,
    n_average: int = 1,
    progress: ProgressFn | None = None,
    catheter_id: str = "",
    vessel: str = "straight",
    method: str = "points",
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CalibrationRun:
    """Move to each motor joint state (n, 4) in order and record the tracked tip pose."""
    _check_counts(retries, n_average)
    q = check_joint_state(q_points, geometry.joint_limits, name="q_points")
    if q.ndim != 2:
        raise ConfigurationError(f"q_points must have shape (n, 4), got {q.shape}")
    plan = MotionPlan.make(q, method, n_average=n_average, retries=retries)
    return calibration_set_from(
        execute_plan(robot, tracker, plan, settle=settle, progress=progress, geometry=geometry),
        catheter_id=catheter_id,
        vessel=vessel,
    )


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


def calibrate_dense(
    robot: RobotBackend | Mover,
    tracker: TipTracker,
    *,
    step: float = math.radians(10.0),
    limit: float | None = None,
    **kwargs: Any,
) -> CalibrationRun:
    """The paper's dense raster (19 x 19 knob pairs at 10 deg over +-90 deg, serpentine).

    ``kwargs`` go to :func:`calibrate_points` (settle, retries, n_average, progress,
    catheter_id, vessel, geometry).
    """
    g = kwargs.get("geometry", DEFAULT_GEOMETRY)
    lim = g.knob_limit if limit is None else float(limit)
    kwargs.setdefault("method", "dense-raster")
    return calibrate_points(robot, tracker, raster_grid(step, lim), **kwargs)


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


def calibrate_five_point(
    robot: RobotBackend | Mover,
    tracker: TipTracker,
    *,
    settle: Callable[[], None] | None = None,
    tol_mm: float = 1.0,
    max_iterations: int = 8,
    fd_step: float = math.radians(4.0),
    retries: int = 10,
    n_average: int = 1,
    progress: ProgressFn | None = None,
    catheter_id: str = "",
    vessel: str = "straight",
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CalibrationRun:
    """The simplified 5-point calibration, searching the motor knobs with the tracker.

    For each target of :func:`five_point_targets` a damped Gauss-Newton search (finite
    differences of ``fd_step`` measured on the catheter, steps clipped to the knob limits)
    finds the motor knob pair whose real tip (x, y) is within ``tol_mm`` of the model's, or
    the closest one within the limits; that pair and its tracked pose are the sample.
    The centre target starts at (0, 0) and needs no search unless the tip is off by more
    than ``tol_mm``.
    """
    _check_counts(retries, n_average)
    move = as_mover(robot, settle)
    lim = geometry.knob_limit
    knobs, xy = five_point_targets(geometry)
    kept_q: list[Array] = []
    kept_t: list[Array] = []
    skipped: list[SkippedSample] = []
    n_moves = 0

    def measure_at(k: Array) -> Array | None:
        nonlocal n_moves
        q = np.array([k[0], k[1], 0.0, 0.0])
        move(q)
        n_moves += 1
        pose, _ = _measure(tracker, retries, n_average)
        return pose

    for i in range(5):
        target = xy[i]
        k = knobs[i].copy()
        best_k, best_pose, best_err = None, None, math.inf
        for _ in range(max_iterations):
            pose = measure_at(k)
            if pose is None:
                break
            e = pose[:2, 3] - target
            err = float(np.linalg.norm(e))
            if err < best_err:
                best_k, best_pose, best_err = k.copy(), pose, err
            if err <= tol_mm:
                break
            jac = np.empty((2, 2))
            ok = True
            for j in range(2):
                h = fd_step if k[j] + fd_step <= lim else -fd_step
                kh = k.copy()
                kh[j] += h
                ph = measure_at(kh)
                if ph is None:
                    ok = False
                    break
                jac[:, j] = (ph[:2, 3] - pose[:2, 3]) / h
            if not ok:
                break
            step = -np.linalg.solve(jac.T @ jac + 1e-2 * np.eye(2), jac.T @ e)
            max_step = math.radians(20.0)
            norm = float(np.linalg.norm(step))
            if norm > max_step:
                step *= max_step / norm
            k_new = np.clip(k + step, -lim, lim)
            if np.allclose(k_new, k, atol=1e-6):
                break
            k = k_new
        if best_k is None or best_pose is None:
            q_rec = np.array([k[0], k[1], 0.0, 0.0])
            skipped.append(
                SkippedSample(
                    q_motor=q_rec, attempts=retries + 1, reason="tracker MISSING during the search"
                )
            )
            log.warning("five-point target %d skipped: tracker MISSING", i)
        else:
            if best_err > tol_mm:
                log.info("five-point target %d: closest tip %.2f mm from the target", i, best_err)
            # record the best pair with a fresh measurement taken there
            pose = measure_at(best_k)
            kept_q.append(np.array([best_k[0], best_k[1], 0.0, 0.0]))
            kept_t.append(best_pose if pose is None else pose)
        if progress is not None:
            progress(
                Progress(
                    done=i + 1,
                    total=5,
                    q_motor=np.array([k[0], k[1], 0.0, 0.0]),
                    phase="five-point",
                )
            )
    move(np.zeros(4))
    n_moves += 1
    if len(kept_q) < 3:
        raise TrackerError(f"only {len(kept_q)} of 5 calibration points could be measured")
    cal = CalibrationSet(
        q_motor=np.array(kept_q),
        tip2base=np.array(kept_t),
        catheter_id=catheter_id,
        vessel=vessel,
        method="five-point",
    )
    return CalibrationRun(calibration=cal, skipped=tuple(skipped), n_moves=n_moves)


# --- hysteresis identification -----------------------------------------------------------


@dataclass(frozen=True)
class HysteresisIdentification:
    """Result of :func:`identify_hysteresis`."""

    compensator: HysteresisCompensator
    """Compensator with the identified models (phi1, phi2, phi3; d4 passes through)."""
    fits: tuple[HysteresisFit, ...]
    """The fits of phi1, phi2 and phi3."""
    n_moves: int
    """Robot moves made."""


def _observe_sweep(
    x: Array, poses: Array, joint: int, base: Array, geometry: CatheterGeometry
) -> tuple[Array, Array]:
    """Observed output of a sweep of ``joint`` (values ``x`` (m,), tracked poses (m, 4, 4),
    NaN where missing) from ``base``: the bend in the knob's plane (knobs); for the roll,
    the azimuth of the tip about the base z axis when bent, else phi3 of the model inverse
    kinematics (rad). Also returns the image frame's roll (phi3 of the model inverse
    kinematics; NaN for the knobs)."""
    y = np.full(x.size, np.nan)
    y_frame = np.full(x.size, np.nan)
    valid = np.flatnonzero(np.all(np.isfinite(poses.reshape(x.size, -1)), axis=1))
    if valid.size == 0:
        return y, y_frame
    t = poses[valid]
    qm = kin_inverse(t, geometry, check=False)
    if joint == 2:
        y_frame[valid] = np.unwrap(qm[:, 2])  # the roll of the model for the image frame
        if math.hypot(base[0], base[1]) > 0.1:
            # bent: the azimuth of the tip about the base axis turns with the base roll only
            y[valid] = np.unwrap(np.arctan2(t[:, 1, 3], t[:, 0, 3]))
        else:
            y = y_frame.copy()
        return y, y_frame
    k2 = qm[:, :2]
    # principal direction of the tip's bend during the sweep
    _, _, vt = np.linalg.svd(k2 - k2.mean(axis=0), full_matrices=False)
    d = vt[0]
    if d[joint] < 0:
        d = -d
    y[valid] = k2 @ d
    return y, y_frame


@dataclass(frozen=True, eq=False)
class HysteresisPlan:
    """The sweeps of :func:`identify_hysteresis` as a :class:`MotionPlan`, with what the fit
    needs to read them."""

    plan: MotionPlan
    """Segments ``sweep phi1``, ``sweep phi1, phi2 bent``, ``sweep phi2``, ``sweep phi3``,
    ``sweep phi3, phi1 bent``, ``bend check`` (those of the joints asked for), the moves
    between them unread."""
    sweep: Array
    """(m,) joint values of one sweep (rad): 0 -> +A -> -A -> +A -> 0 of the knobs."""
    roll_sweep: Array
    """(m',) the same for the roll."""
    joints: tuple[int, ...]
    """Joints swept (0, 1, 2: phi1, phi2, phi3)."""
    bend: float
    """Knob angle of the bent sweeps (rad; 0: none)."""


def hysteresis_plan(
    *,
    amplitude: float = math.radians(60.0),
    step: float = math.radians(1.5),
    roll_amplitude: float = math.radians(60.0),
    roll_bend: float = math.radians(50.0),
    joints: Sequence[int] = (0, 1, 2),
    retries: int = 10,
) -> HysteresisPlan:
    """The sweeps: each joint of ``joints`` 0 -> +A -> -A -> +A -> 0 with the others at 0,
    one tracker sample per step; phi1 again with phi2 at ``roll_bend``, phi3 again with phi1
    at ``roll_bend`` and then a 5-sample reading of the bend there (0: no bent sweeps). The
    robot starts and ends at zeros (unread moves)."""
    _check_counts(retries, 1)
    js = tuple(int(j) for j in joints)
    for j in js:
        if j not in (0, 1, 2):
            raise ConfigurationError(f"joints must be among 0, 1, 2 (phi1..phi3), got {j}")
    sweep = sweep_path(amplitude, step)
    roll_sweep = sweep_path(roll_amplitude, step)
    zero = np.zeros((1, 4))
    parts: list[MotionPlan] = []

    def swept(path: Array, joint: int, base: Array, phase: str) -> MotionPlan:
        q = np.tile(base, (path.size, 1))
        q[:, joint] = path
        return MotionPlan.make(q, phase, n_average=1, retries=retries)

    def unread(q: Array, phase: str) -> MotionPlan:
        return MotionPlan.make(np.atleast_2d(q), phase, n_average=0, retries=0)

    for j in js:
        path = roll_sweep if j == 2 else sweep
        parts += [unread(zero, "to zero"), swept(path, j, np.zeros(4), f"sweep phi{j + 1}")]
        if j == 0 and roll_bend > 0.0:
            base = np.array([0.0, roll_bend, 0.0, 0.0])
            parts += [unread(base, "to zero"), swept(path, 0, base, "sweep phi1, phi2 bent")]
        if j == 2 and roll_bend > 0.0:
            base = np.array([roll_bend, 0.0, 0.0, 0.0])
            parts += [
                unread(base, "to zero"),
                swept(path, 2, base, "sweep phi3, phi1 bent"),
                MotionPlan.make(base[None, :], "bend check", n_average=5, retries=retries),
            ]
    parts.append(unread(zero, "to zero"))
    return HysteresisPlan(
        plan=MotionPlan.concat(parts),
        sweep=sweep,
        roll_sweep=roll_sweep,
        joints=js,
        bend=float(roll_bend),
    )


def fit_hysteresis(
    hplan: HysteresisPlan,
    recording: Recording,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> HysteresisIdentification:
    """Fit the models of :func:`identify_hysteresis` to the recorded sweeps of ``hplan``."""
    if recording.plan is not hplan.plan and recording.plan.segments != hplan.plan.segments:
        raise ConfigurationError("the recording is not of this hysteresis plan")
    models: list[Any] = [None, None, None, None]
    fits: list[HysteresisFit] = []
    per_bend = 0.0
    knob_per_bend = 0.0
    twist_per_bend = 0.0
    bend = hplan.bend

    def observed(phase: str, joint: int) -> tuple[Array, Array, Array]:
        q, poses = recording.part(phase)
        x = q[:, joint].copy()
        y, y_frame = _observe_sweep(x, poses, joint, q[0], geometry)
        return x, y, y_frame

    for j in hplan.joints:
        roll = j == 2
        x, y, _ = observed(f"sweep phi{j + 1}", j)
        fit = identify(
            x, y, cubic=not roll, with_dead_zone=not roll, max_slope=0.0 if roll else 0.2
        )
        models[j] = fit.model
        fits.append(fit)
        if j == 0 and bend > 0.0:
            # the same sweep with the other knob bent: the play grows with the other bend
            x, y, _ = observed("sweep phi1, phi2 bent", 0)
            bent_fit = identify(x, y, cubic=True, with_dead_zone=True)
            mean_abs = float(np.mean(np.abs(x)))
            w_bent = bent_fit.model.backlash + bent_fit.model.backlash_slope * mean_abs
            w_straight = fit.model.backlash + fit.model.backlash_slope * mean_abs
            knob_per_bend = min(max(0.0, (w_bent - w_straight) / bend), 0.5)
        if roll and bend > 0.0:
            x, y, y_frame = observed("sweep phi3, phi1 bent", 2)
            wide = math.radians(30.0)
            bent = identify(x, y, cubic=False, with_dead_zone=False, max_slope=0.0, max_width=wide)
            frame = identify(
                x, y_frame, cubic=False, with_dead_zone=False, max_slope=0.0, max_width=wide
            )
            # the true bend during that sweep, from the tracked poses
            _, check = recording.part("bend check")
            pose = check[0]
            true_bend = (
                bend
                if not np.all(np.isfinite(pose))
                else math.acos(max(-1.0, min(1.0, float(pose[2, 2]))))
            )
            per_bend = min(max(0.0, (bent.model.backlash - fit.model.backlash) / true_bend), 0.5)
            # the image frame lags further than the base: the distal twist play
            twist_per_bend = min(
                max(0.0, (frame.model.backlash - bent.model.backlash) / true_bend), 0.5
            )
    return HysteresisIdentification(
        compensator=HysteresisCompensator(
            models,
            roll_play_per_bend=per_bend,
            knob_play_per_bend=knob_per_bend,
            twist_play_per_bend=twist_per_bend,
        ),
        fits=tuple(fits),
        n_moves=hplan.plan.n,
    )


def identify_hysteresis(
    robot: RobotBackend | Mover,
    tracker: TipTracker,
    *,
    settle: Callable[[], None] | None = None,
    amplitude: float = math.radians(60.0),
    step: float = math.radians(1.5),
    roll_amplitude: float = math.radians(60.0),
    roll_bend: float = math.radians(50.0),
    joints: Sequence[int] = (0, 1, 2),
    retries: int = 10,
    progress: ProgressFn | None = None,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> HysteresisIdentification:
    """Identify backlash and dead-zone of the knobs (and the roll's play) by sweeps:
    :func:`hysteresis_plan` executed (:func:`execute_plan`) and fitted (:func:`fit_hysteresis`).

    Each joint in ``joints`` is swept 0 -> +A -> -A -> +A -> 0 with the others at 0, and
    :func:`icenav.compensation.hysteresis.identify` fits the model to the tracked response (knobs:
    the
    bend in the knob's plane from the model inverse kinematics, odd-cubic static map;
    roll: the tip roll, linear map, no dead-zone). The roll is swept a second time with the
    AP knob at ``roll_bend`` (0 to skip): the growth of its play with the tracked bend
    angle gives the compensator's ``roll_play_per_bend`` (rad per rad of true bend), and the
    extra lag of the image frame (model roll of the tracked orientation) over the base (the
    tip's azimuth) its ``twist_play_per_bend``; and the
    AP knob a second time with the RL knob at ``roll_bend``: the growth of its mean play
    gives ``knob_play_per_bend`` (the other pair's bend adds sheath friction).
    """
    hplan = hysteresis_plan(
        amplitude=amplitude,
        step=step,
        roll_amplitude=roll_amplitude,
        roll_bend=roll_bend,
        joints=joints,
        retries=retries,
    )
    rec = execute_plan(
        robot, tracker, hplan.plan, settle=settle, progress=progress, geometry=geometry
    )
    return fit_hysteresis(hplan, rec, geometry)

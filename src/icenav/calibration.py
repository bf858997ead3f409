"""Calibration procedures: drive the robot, read the tracker, return calibration data.

They talk to the robot and the tracker only through small interfaces, so the same code
runs on the digital twin today and on the hardware later:

- the robot: a :class:`~icenav.hw.base.RobotBackend` (``command_position`` then a
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
  with :func:`icenav.hysteresis.identify`.

Missing samples are retried, then skipped with a :class:`SkippedSample` record (also logged
as a warning on the ``icenav.calibration`` logger). Progress goes to a callback.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav.compensation import CalibrationSet
from icenav.errors import ConfigurationError, TrackerError
from icenav.hw.base import RobotBackend
from icenav.hysteresis import HysteresisCompensator, HysteresisFit, identify, sweep_path
from icenav.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.kinematics import inverse as kin_inverse
from icenav.validation import check_joint_state

__all__ = [
    "CalibrationRun",
    "HysteresisIdentification",
    "Mover",
    "Progress",
    "SkippedSample",
    "TipTracker",
    "as_mover",
    "calibrate_dense",
    "calibrate_five_point",
    "calibrate_points",
    "five_point_targets",
    "identify_hysteresis",
    "raster_grid",
]

Array = NDArray[np.float64]
log = logging.getLogger("icenav.calibration")

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
    """Mean of poses (n, 4, 4): mean position, rotation projected from the mean matrix."""
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
    move = as_mover(robot, settle)
    kept_q: list[Array] = []
    kept_t: list[Array] = []
    skipped: list[SkippedSample] = []
    for i, qi in enumerate(q):
        move(qi)
        pose, attempts = _measure(tracker, retries, n_average)
        if pose is None:
            rec = SkippedSample(q_motor=qi.copy(), attempts=attempts, reason="tracker MISSING")
            log.warning(
                "calibration sample %d at q=%s skipped: tracker MISSING after %d attempts",
                i,
                np.round(np.degrees(qi[:3]), 2).tolist(),
                attempts,
            )
            skipped.append(rec)
        else:
            kept_q.append(qi.copy())
            kept_t.append(pose)
        if progress is not None:
            progress(Progress(done=i + 1, total=q.shape[0], q_motor=qi.copy(), phase=method))
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


def _sweep(
    move: Mover,
    tracker: TipTracker,
    path: Array,
    joint: int,
    base: Array,
    retries: int,
    progress: ProgressFn | None,
    geometry: CatheterGeometry,
    both: bool = False,
) -> Any:
    """Sweep one joint along ``path`` from ``base``; observed output per sample (NaN when
    missing): the bend in the knob's plane (knobs); for the roll, phi3 of the model inverse
    kinematics when straight, the azimuth of the tip about the base z axis when bent (rad)."""
    poses: list[Array | None] = []
    for i, x in enumerate(path):
        q = base.copy()
        q[joint] = x
        move(q)
        pose, _ = _measure(tracker, retries, 1)
        poses.append(pose)
        if progress is not None:
            progress(Progress(done=i + 1, total=path.size, q_motor=q, phase=f"sweep joint {joint}"))
    y = np.full(path.size, np.nan)
    valid = [i for i, p in enumerate(poses) if p is not None]
    if not valid:
        return path, y
    t = np.array([poses[i] for i in valid])
    qm = kin_inverse(t, geometry, check=False)
    if joint == 2:
        y_frame = np.full(path.size, np.nan)
        y_frame[valid] = np.unwrap(qm[:, 2])  # the roll of the model for the image frame
        if math.hypot(base[0], base[1]) > 0.1:
            # bent: the azimuth of the tip about the base axis turns with the base roll only
            y[valid] = np.unwrap(np.arctan2(t[:, 1, 3], t[:, 0, 3]))
        else:
            y = y_frame
        return (path, y, y_frame) if both else (path, y)
    k2 = qm[:, :2]
    # principal direction of the tip's bend during the sweep
    _, _, vt = np.linalg.svd(k2 - k2.mean(axis=0), full_matrices=False)
    d = vt[0]
    if d[joint] < 0:
        d = -d
    y[valid] = k2 @ d
    return path, y


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
    """Identify backlash and dead-zone of the knobs (and the roll's play) by sweeps.

    Each joint in ``joints`` is swept 0 -> +A -> -A -> +A -> 0 with the others at 0, and
    :func:`icenav.hysteresis.identify` fits the model to the tracked response (knobs: the
    bend in the knob's plane from the model inverse kinematics, odd-cubic static map;
    roll: the tip roll, linear map, no dead-zone). The roll is swept a second time with the
    AP knob at ``roll_bend`` (0 to skip): the growth of its play with the tracked bend
    angle gives the compensator's ``roll_play_per_bend`` (rad per rad of true bend), and the
    extra lag of the image frame (model roll of the tracked orientation) over the base (the
    tip's azimuth) its ``twist_play_per_bend``; and the
    AP knob a second time with the RL knob at ``roll_bend``: the growth of its mean play
    gives ``knob_play_per_bend`` (the other pair's bend adds sheath friction).
    """
    move = as_mover(robot, settle)
    models: list[Any] = [None, None, None, None]
    fits: list[HysteresisFit] = []
    n_moves = 0
    per_bend = 0.0
    knob_per_bend = 0.0
    twist_per_bend = 0.0
    for j in joints:
        if j not in (0, 1, 2):
            raise ConfigurationError(f"joints must be among 0, 1, 2 (phi1..phi3), got {j}")
        amp = roll_amplitude if j == 2 else amplitude
        path = sweep_path(amp, step)
        move(np.zeros(4))
        x, y = _sweep(move, tracker, path, j, np.zeros(4), retries, progress, geometry)
        n_moves += path.size + 1
        roll = j == 2
        fit = identify(
            x, y, cubic=not roll, with_dead_zone=not roll, max_slope=0.0 if roll else 0.2
        )
        models[j] = fit.model
        fits.append(fit)
        if j == 0 and roll_bend > 0.0:
            # the same sweep with the other knob bent: the play grows with the other bend
            base = np.array([0.0, roll_bend, 0.0, 0.0])
            move(base)
            x, y = _sweep(move, tracker, path, j, base, retries, progress, geometry)
            n_moves += path.size + 1
            bent_fit = identify(x, y, cubic=True, with_dead_zone=True)
            mean_abs = float(np.mean(np.abs(x)))
            w_bent = bent_fit.model.backlash + bent_fit.model.backlash_slope * mean_abs
            w_straight = fit.model.backlash + fit.model.backlash_slope * mean_abs
            knob_per_bend = max(0.0, (w_bent - w_straight) / roll_bend)
            knob_per_bend = min(knob_per_bend, 0.5)
        if roll and roll_bend > 0.0:
            base = np.array([roll_bend, 0.0, 0.0, 0.0])
            move(base)
            x, y, y_frame = _sweep(
                move, tracker, path, j, base, retries, progress, geometry, both=True
            )
            n_moves += path.size + 1
            wide = math.radians(30.0)
            bent = identify(x, y, cubic=False, with_dead_zone=False, max_slope=0.0, max_width=wide)
            frame = identify(
                x, y_frame, cubic=False, with_dead_zone=False, max_slope=0.0, max_width=wide
            )
            # the true bend during that sweep, from the tracked poses
            move(base)
            pose, _ = _measure(tracker, retries, 5)
            true_bend = (
                roll_bend if pose is None else math.acos(max(-1.0, min(1.0, float(pose[2, 2]))))
            )
            per_bend = max(0.0, (bent.model.backlash - fit.model.backlash) / true_bend)
            per_bend = min(per_bend, 0.5)
            # the image frame lags further than the base: the distal twist play
            twist_per_bend = max(0.0, (frame.model.backlash - bent.model.backlash) / true_bend)
            twist_per_bend = min(twist_per_bend, 0.5)
    move(np.zeros(4))
    return HysteresisIdentification(
        compensator=HysteresisCompensator(
            models,
            roll_play_per_bend=per_bend,
            knob_play_per_bend=knob_per_bend,
            twist_play_per_bend=twist_per_bend,
        ),
        fits=tuple(fits),
        n_moves=n_moves + 1,
    )

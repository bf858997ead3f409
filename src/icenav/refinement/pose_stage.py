"""EM pose stage of the view refinement: servo the motors until the averaged EM-measured tip
pose matches the pose saved with the view (beyond the paper).

Before the image search, :class:`PoseStageTask` (blocking: :func:`pose_stage`) servoes the
motors until the EM-measured tip pose, averaged over 64 samples, matches the EM pose saved
with the view (the tracker's field distortion is the same at the same place, so this is
nearly the true pose error). Damped least squares on the 6-D body error with the model's
body Jacobian, small bounded steps, iterated on the measured error; hysteresis aware:
roll and translation are re-approached from their engaged side through their whole play
(the twin's roll plus distal twist play is about 2 x 10 deg), the knobs (tendon play of
10-16 deg) are never reversed and creep up on their target. It removes the play offsets a
roadmap return cannot reproduce (measured on the twin: 0.5 mm / 1.8 deg -> about 0.1 mm /
0.1 deg). :class:`GatedBeatImager` gates beats on ECG *and* respiration
(:class:`RespiratoryMonitor`, e.g. :class:`PhantomRespiration`: a bellows-like signal, not
the catheter pose), so that the image stage and the similarity measurement compare frames
at the saved beat's respiratory state.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state, check_positive
from icenav.devices.robot import RobotBackend
from icenav.devices.tracker import TrackerBackend
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.se3 import body_pose_error
from icenav.refinement._secant import held_dls, secant_update
from icenav.refinement._stepper import _MeasurePose, _Move, _Stepper, _WaitExpiration
from icenav.refinement.image_search import _DEG, NeighbourhoodError, _four, drive_task

__all__ = [
    "PoseMeasurement",
    "PoseSensor",
    "PoseStageConfig",
    "PoseStageResult",
    "PoseStageStatus",
    "PoseStageTask",
    "pose_error",
    "pose_stage",
]


PoseSensor = TrackerBackend
"""Source of the measured tip pose: the one tracker protocol (only its
``measure_tip2base(n_average)`` is used here)."""


def pose_error(target: ArrayLike, measured: ArrayLike) -> Array:
    """Body-frame pose error of ``target`` relative to ``measured``, shape (6,).

    ``(dx, dy, dz)`` (mm) and a rotation vector ``(rx, ry, rz)`` (rad), both in the measured
    tip frame: the twist that carries the measured frame onto the target
    (``log(measured^-1 target)``, small-angle exact for the rotation).
    """
    t = np.asarray(target, np.float64)
    m = np.asarray(measured, np.float64)
    if t.shape != (4, 4) or m.shape != (4, 4):
        raise ShapeError(f"poses must have shape (4, 4), got {t.shape} and {m.shape}")
    return body_pose_error(t, m, 1.0)


@dataclass(frozen=True)
class PoseStageConfig:
    """Settings of the EM pose stage (per joint: phi1, phi2, phi3 rad, d4 mm)."""

    radius: tuple[float, float, float, float] = (5 * _DEG, 5 * _DEG, 30 * _DEG, 3.0)
    """Half-width of the box around the view's motor state that no set-point leaves (rad,
    rad, rad, mm). The roll is wide: its torsional play (roll plus distal twist, up to about
    10 deg half-width on the twin) must be crossed to re-approach it; inside the play the
    handle turns without turning the tip."""
    max_step: tuple[float, float, float, float] = (1.0 * _DEG, 1.0 * _DEG, 2.0 * _DEG, 0.5)
    """Largest change of the servo target per iteration (rad, rad, rad, mm)."""
    backoff: tuple[float, float, float, float] = (0.0, 0.0, 25.0 * _DEG, 1.5)
    """Re-approach distance (rad, rad, rad, mm): a joint that must move against its engaged
    direction first goes this far beyond its target and comes back in the engaged
    direction, so its play ends taken up the way it was when the view was saved (more
    than the full dead band of that joint's transmission: about 2 x 10 deg of roll plus
    distal twist and 2 x 0.6 mm of translation on the twin). 0: the joint is never moved
    against its engaged direction (the knobs by default: their tendon play needs 10-16 deg
    of knob travel to cross on the twin, a large bending excursion; the roadmap's approach
    already reproduces it), the step is solved with that joint held instead."""
    n_average: int = 64
    """EM samples averaged per pose measurement (jitter falls as 1 / sqrt(n))."""
    sample_rate_hz: float = 80.0
    """EM sample rate (Hz): a measurement holds the catheter for ``n_average / rate``."""
    tolerance_mm: float = 0.2
    """Stop when the measured position error is below this (mm) ..."""
    tolerance_rad: float = 0.1 * _DEG
    """... and the measured orientation error below this (rad)."""
    rotation_weight_mm_per_rad: float = 25.0
    """Weight of rotation against translation in the least-squares step (mm per rad):
    1 deg counts as 0.44 mm."""
    damping: float = 0.3
    """Damping of the least-squares step (weighted units, mm)."""
    max_iterations: int = 10
    """Budget of servo steps (pose measurements beyond the first)."""
    max_duration_s: float = 30.0
    """Budget of controller time (s)."""
    one_sided_gain: float = 0.6
    """Fraction of the least-squares step taken by joints that are never reversed (backoff
    0): they creep up on the target from their engaged side, since an overshoot could not be
    taken back."""
    min_decrease_mm: float = 0.03
    """A step is kept when it lowers the measured weighted error (mm; rotations times
    ``rotation_weight_mm_per_rad``) below the best so far by this much (about the averaged
    EM noise); otherwise the next step starts again from the best state at half the gain."""
    min_gain: float = 0.2
    """Stop (status STALLED, at the best state) when the step gain has been halved below
    this."""
    reapproach_first: bool = True
    """When the first measurement is off, re-approach the current motor state along the
    engaged directions (joints with a backoff) before any servo step: resets their plays the
    way they were taken up at saving."""
    max_velocity: tuple[float, float, float, float] = (
        10.0 * _DEG,
        10.0 * _DEG,
        20.0 * _DEG,
        3.0,
    )
    """Joint speed of the stage's moves (rad/s, rad/s, rad/s, mm/s)."""
    settle_s: float = 0.05
    """Hold after a move before a measurement (s)."""
    hold_s: float | None = None
    """Whole hold before a measurement (s); None: ``settle_s + n_average / sample_rate_hz``.
    With a cycle-averaged sensor (:class:`icenav.refinement.cycle_pose.CycleAveragedPose`)
    at least its window, so every sample it averages was taken after the move."""
    step_from_last: bool = False
    """Each correction starts from the last commanded state with the last measured error
    (integral action: a step the shaft's stiction swallowed is added to by the next, not
    retried from the best state at half the gain), and the stage does not go back to the
    best state at the end (that would be one more stick-slip move); with the cycle-averaged
    estimator."""
    revisit_best: bool = False
    """With ``step_from_last``: when a correction landed worse than the best measured state
    by more than ``min_decrease_mm``, the next move re-approaches the best state's command
    (every engaged joint from its engaged side) instead of stepping from the worse one, and
    the stage ends there (measured again) rather than at a worse state: a new draw of the
    shaft's lost motion around a command known to be good, where going back to the start
    is a draw around the open-loop return."""
    approach_always: bool = False
    """Every correction re-approaches every engaged joint that has a backoff from its
    engaged side (not only those whose step reverses): the play and the shaft's lost
    motion are taken up the same way at every measured state, as by the return."""
    undo_margin_mm: float = 0.0
    """``undo_if_worse`` goes back only when the last measurement is worse than the first by
    more than this (weighted mm): a difference within the estimator's own scatter is no
    evidence, and going back is itself a new draw of the shaft's lost motion."""
    undo_if_worse: bool = True
    """At the end, if the last measurement is worse than the first (the stage made it
    worse), go back to the start state (re-approached) and stop there: never farther from
    the saved pose than it started, as far as the estimator can tell."""
    end_at_best: bool = False
    """With ``step_from_last``: the stage ends at its best measured state, the start
    included. When the last measurement is worse than the best by more than
    ``min_decrease_mm``, the best command is re-approached and measured again; every
    correction starts only when it, its measurement and this way back fit in the time
    budget. It replaces ``undo_if_worse`` (going back to the start is the case where the
    start was the best), which only ever compared with the first measurement."""
    verify: bool = False
    """A measurement within the dead band is accepted only when a second, independent
    window at the same command (no move) is within it too (when the time allows): one
    window's estimate can be lucky, and a shaft that slips while the catheter is held moves
    the tip after it; otherwise the corrections go on from the second measurement."""
    arrive_at_expiration: bool = False
    """Every move of the stage makes its last leg at end-expiration (the task's
    ``expiration`` gate, e.g. :class:`icenav.refinement.cycle_pose.ExpirationGate`; ignored
    without one): the shaft's last slip, after which its end stays stuck to the breathing
    vessel wall, then happens at the same respiratory level at every arrival, so the
    translation's lost motion no longer depends on the breathing phase the move ended at."""
    release_translation_mm: float = 0.0
    """A correction whose translation step exceeds this (mm; 0: off) re-approaches every
    engaged joint with a backoff (``approach_always``): the roll's backoff sweep slips the
    shaft many times (roll and translation share one friction budget), which releases the
    translation's stiction; a smaller step keeps the roll (each approach is a new draw)."""
    secant_weight: float = 0.0
    """With ``step_from_last``: after every correction the step's Jacobian is updated from
    the measured move (Broyden, this weight in [0, 1]; 0: the model's Jacobian at every
    step), so the next step is aimed by the response measured at the view."""
    stop_unpaid: bool = False
    """With ``step_from_last``: a correction that did not lower the measured error below the
    best by ``min_decrease_mm`` is the last (status STALLED; ends at the best state)."""
    expiration_wait_s: float = 4.5
    """Longest wait for end-expiration before a last leg (s; about one breath): the leg goes
    anyway after it. The time budget counts it for every planned move."""

    def __post_init__(self) -> None:
        unit = "(rad, rad, rad, mm)"
        if self.hold_s is not None:
            check_positive(self.hold_s, "hold_s", "s")
        for name in ("radius", "max_step"):
            object.__setattr__(self, name, _four(getattr(self, name), name, unit))
        back = tuple(float(x) for x in self.backoff)
        if len(back) != 4 or not all(math.isfinite(x) and x >= 0 for x in back):
            raise ConfigurationError(f"backoff needs 4 finite values >= 0 {unit}, got {back}")
        object.__setattr__(self, "backoff", back)
        object.__setattr__(
            self, "max_velocity", _four(self.max_velocity, "max_velocity", "(rad/s, ..., mm/s)")
        )
        for j in range(4):
            if self.max_step[j] > self.radius[j]:
                raise ConfigurationError(
                    f"max_step[{j}] = {self.max_step[j]:.4g} exceeds radius[{j}] = "
                    f"{self.radius[j]:.4g} {unit}"
                )
        for name in ("n_average", "max_iterations"):
            n = getattr(self, name)
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                raise ConfigurationError(f"{name} must be an int >= 1, got {n!r}")
        check_positive(self.sample_rate_hz, "sample_rate_hz", "Hz")
        check_positive(self.expiration_wait_s, "expiration_wait_s", "s")
        if not 0.0 <= self.secant_weight <= 1.0:
            raise ConfigurationError(f"secant_weight must be in [0, 1], got {self.secant_weight}")
        if not (math.isfinite(self.undo_margin_mm) and self.undo_margin_mm >= 0.0):
            raise ConfigurationError(f"undo_margin_mm must be >= 0 mm, got {self.undo_margin_mm}")
        check_positive(self.tolerance_mm, "tolerance_mm", "mm")
        check_positive(self.tolerance_rad, "tolerance_rad", "rad")
        check_positive(self.rotation_weight_mm_per_rad, "rotation_weight_mm_per_rad", "mm/rad")
        check_positive(self.max_duration_s, "max_duration_s", "s")
        if not (math.isfinite(self.min_decrease_mm) and self.min_decrease_mm >= 0):
            raise ConfigurationError(
                f"min_decrease_mm must be finite and >= 0 mm, got {self.min_decrease_mm}"
            )
        if not 0.0 < self.one_sided_gain <= 1.0:
            raise ConfigurationError(f"one_sided_gain must be in (0, 1], got {self.one_sided_gain}")
        if not 0.0 < self.min_gain <= 1.0:
            raise ConfigurationError(f"min_gain must be in (0, 1], got {self.min_gain}")
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise ConfigurationError(f"damping must be finite and >= 0 (mm), got {self.damping}")
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise ConfigurationError(f"settle_s must be finite and >= 0 s, got {self.settle_s}")


class PoseStageStatus(enum.Enum):
    """State of a pose stage: running, or why it ended."""

    AT_VIEW = "at_view"
    """The first measurement was already within tolerance: nothing moved."""
    CONVERGED = "converged"
    """The measured error fell within tolerance."""
    BUDGET = "budget"
    """``max_iterations`` servo steps were used; ended at the best measured state."""
    TIMEOUT = "timeout"
    """``max_duration_s`` of controller time passed; ended at the best measured state."""
    STALLED = "stalled"
    """Steps stopped paying (the measured error no longer falls beyond the noise); ended at
    the best measured state."""
    NO_POSE = "no_pose"
    """The tracker gave no valid pose twice in a row; ended where it was."""
    ABORTED = "aborted"
    """``abort()`` returned True; the robot holds where it was."""
    RUNNING = "running"
    """Not finished yet."""


@dataclass(frozen=True)
class PoseMeasurement:
    """One averaged EM measurement of the pose stage."""

    q: Array
    """(4,) commanded motor state (rad, rad, rad, mm)."""
    error: Array
    """(6,) body pose error of the saved pose relative to the measured one
    (:func:`pose_error`; mm, rad)."""
    t_s: float
    """Controller time since the start of the stage (s)."""

    @property
    def position_mm(self) -> float:
        """Measured position error (mm)."""
        return float(np.linalg.norm(self.error[:3]))

    @property
    def rotation_rad(self) -> float:
        """Measured orientation error (rad)."""
        return float(np.linalg.norm(self.error[3:]))


@dataclass(frozen=True)
class PoseStageResult:
    """Outcome of a pose stage."""

    q_start: Array
    """(4,) motor state at the start (rad, rad, rad, mm)."""
    q_final: Array
    """(4,) motor state at the end."""
    measurements: tuple[PoseMeasurement, ...]
    """Every EM measurement in order (the first is the start)."""
    final: PoseMeasurement | None
    """The measurement at ``q_final`` after the last move (None if none was possible)."""
    status: PoseStageStatus
    """Why it ended."""
    duration_s: float
    """Controller time used (s)."""
    n_commands: int
    """Set-points sent."""
    max_offset: Array
    """(4,) largest |set-point - q_view| per joint over the run (rad, rad, rad, mm)."""
    undone: bool = False
    """The stage ended worse than it started and went back to the start state."""
    revisits: int = 0
    """Re-approaches of the best measured state (``revisit_best``)."""


class PoseStageTask:
    """EM pose stage as a controller task: servo the motors until the averaged EM-measured
    tip pose matches the one saved with the view.

    After a roadmap return the motors stand exactly at the saved state but the
    transmission's play (knob tendons, roll, the distal twist, translation) may sit in
    another state than at saving, so the tip is off by a fraction of a millimetre or a
    degree or two. The EM tracker's field distortion is the same at the same place, so the
    measured pose against the *measured* saved pose is nearly the true error; averaging
    ``n_average`` samples removes most of the jitter.

    Each iteration: measure (hold ``n_average / rate``); stop if within tolerance; otherwise
    a damped least-squares step of the 6-D body error with the model's body Jacobian
    (:func:`icenav.geometry.kinematics.jacobian` at the commanded state; rotations weighted by
    ``rotation_weight_mm_per_rad``)::

        dq = (J^T W J + lambda^2 I)^-1 J^T W e,      W = diag(1, 1, 1, w^2, w^2, w^2)

    bounded per joint by ``max_step``. Hysteresis aware: each joint has an *engaged*
    direction (the view's arrival direction, else the direction it last moved); a joint
    whose step goes against it is moved ``backoff`` beyond its target and brought back in
    the engaged direction, so the output follows the command without a dead band and the
    play ends as at saving. With ``reapproach_first`` the first off measurement triggers
    such a re-approach of the current state before any step. The stage iterates on the
    measured error (never trusting one step), keeps the best measured state and ends
    there (re-approached, measured again) if the last one is worse. With
    ``step_from_last`` (the cycle-averaged estimator, where every move is a new draw of the
    shaft's lost motion) the steps are integral, no correction starts that cannot be
    measured within ``max_duration_s``, ``revisit_best`` goes back to the best measured
    command after a worse draw, and ``undo_margin_mm`` keeps it from going back to the start
    on a difference within the estimator's scatter.

    Safety: every set-point stays in the box ``q_view +- radius``
    (:class:`NeighbourhoodError` otherwise); bounded speed, iterations and controller time;
    abortable between any two control cycles.

    Parameters
    ----------
    q_view : array-like, shape (4,)
        Motor state of the saved view, the centre of the box (rad, rad, rad, mm).
    saved_tip2base : array-like, shape (4, 4)
        The EM-measured tip pose saved with the view (averaged; mm, base frame).
    sensor : PoseSensor
        The EM tracker.
    q_start : array-like, shape (4,), optional
        Where the robot is now (default ``q_view``); must lie in the box.
    arrival_direction : 4 ints in (-1, 0, 1)
        The view's arrival direction per joint.
    start_direction : 4 ints in (-1, 0, 1), optional
        The direction each joint moved last before the stage (the end of the return; default
        ``arrival_direction``): the engaged direction of joints without an arrival direction.
    config : PoseStageConfig
    abort : callable, optional
        Polled every cycle; True ends the stage at once (status ABORTED).
    expiration : callable, optional
        True at end-expiration (``config.arrive_at_expiration``; polled every cycle while
        a last leg waits for it); None: legs go at once.
    """

    label = "pose stage (EM)"

    def __init__(
        self,
        q_view: ArrayLike,
        saved_tip2base: ArrayLike,
        sensor: PoseSensor,
        *,
        q_start: ArrayLike | None = None,
        arrival_direction: Sequence[int] = (0, 0, 0, 0),
        start_direction: Sequence[int] | None = None,
        config: PoseStageConfig | None = None,
        abort: Callable[[], bool] | None = None,
        expiration: Callable[[], bool] | None = None,
    ) -> None:
        self.config = cfg = config if config is not None else PoseStageConfig()
        self._expiration = expiration if cfg.arrive_at_expiration else None
        self._wait_left = -1.0
        self.waited_s = 0.0
        """Controller time spent waiting for end-expiration (s)."""
        self.q_view = np.array(check_joint_state(q_view, name="q_view"), np.float64)
        if self.q_view.shape != (4,):
            raise ShapeError(f"q_view must have shape (4,), got {self.q_view.shape}")
        q0 = self.q_view if q_start is None else check_joint_state(q_start, name="q_start")
        self.q_start = np.array(q0, np.float64).reshape(4)
        saved = np.asarray(check_finite(saved_tip2base, "saved_tip2base"), np.float64)
        if saved.shape != (4, 4):
            raise ShapeError(f"saved_tip2base must have shape (4, 4), got {saved.shape}")
        self.saved = saved
        radius = np.array(cfg.radius)
        off = np.abs(self.q_start - self.q_view)
        if np.any(off > radius * (1 + 1e-9)):
            j = int(np.argmax(off / radius))
            raise NeighbourhoodError(
                f"the start state is {off[j]:.4g} from the view on joint {j}, outside the "
                f"pose stage radius {radius[j]:.4g} (rad, rad, rad, mm)"
            )
        direction = tuple(int(d) for d in arrival_direction)
        if len(direction) != 4 or any(d not in (-1, 0, 1) for d in direction):
            raise ConfigurationError(
                f"arrival_direction must be 4 values in (-1, 0, 1), got {arrival_direction!r}"
            )
        self.direction = np.array(direction, np.float64)
        self.sensor = sensor
        self._run = _Stepper(self.q_view, self.q_start, radius, np.array(cfg.max_velocity), abort)
        start_dir = direction if start_direction is None else tuple(int(d) for d in start_direction)
        if len(start_dir) != 4 or any(d not in (-1, 0, 1) for d in start_dir):
            raise ConfigurationError(
                f"start_direction must be 4 values in (-1, 0, 1), got {start_direction!r}"
            )
        self._engaged_dir = np.where(
            self.direction != 0, self.direction, np.array(start_dir, np.float64)
        )
        self._run.last_dir = np.array(start_dir, np.float64)
        w = cfg.rotation_weight_mm_per_rad
        self._w = np.array([1.0, 1.0, 1.0, w, w, w])
        self._hold_s = (
            cfg.settle_s + cfg.n_average / cfg.sample_rate_hz if cfg.hold_s is None else cfg.hold_s
        )
        self._gen = self._servo()
        self._gen_done = False
        self._measuring = False
        self._hold_left = 0.0
        self._status = PoseStageStatus.RUNNING
        self._meas: list[PoseMeasurement] = []
        self._final: PoseMeasurement | None = None
        self._best_q = self.q_start.copy()
        self._undone = False
        self._revisits = 0
        self._jac: Array | None = None

    # --- the servo (a generator of requests) ----------------------------------------------
    def _engaged(self) -> Array:
        """Per joint: the arrival direction, else the direction it moved last before the
        stage (fixed for the stage, so every approach takes the play up the same way and
        the best state can be re-approached exactly); 0: a free joint."""
        return self._engaged_dir

    def _approach(self, target: Array, *, force: bool = False) -> list[Array]:
        """Targets that reach ``target`` with every engaged joint moving in its engaged
        direction at the end (``force``: re-approach every engaged joint)."""
        d = self._engaged()
        back = np.array(self.config.backoff)
        # a joint without a backoff is never moved against its engaged direction: held
        hold = (back == 0) & (d != 0) & ((target - self._run.cmd) * d < 0)
        target = np.where(hold, self._run.cmd, target)
        delta = target - self._run.cmd
        need = (d != 0) & ((delta * d < 0) | force) & (back > 0)
        if not np.any(need):
            return [target]
        pre = np.where(need, target - d * np.array(self.config.backoff), target)
        return [np.clip(pre, self._run.lo, self._run.hi), target]

    def _legs(self, moves: list[Array]) -> Generator[_Move | _WaitExpiration, None, None]:
        """``moves`` as requests, the last leg after end-expiration when gated."""
        for i, t in enumerate(moves):
            if i == len(moves) - 1 and self._expiration is not None:
                yield _WaitExpiration()
            yield _Move(t)

    def _step(self, q: Array, e: Array, gain: float = 1.0) -> Array:
        from icenav.geometry.kinematics import jacobian

        cfg = self.config
        jac = jacobian(q, check=False) if self._jac is None else self._jac
        # joints without a backoff never move against their engaged direction: held
        no_reverse = (np.array(cfg.backoff) == 0) & (self._engaged() != 0)
        dq = held_dls(self._w[:, None] * jac, self._w * e, cfg.damping, no_reverse, self._engaged())
        lim = np.array(cfg.max_step)
        # joints that cannot come back approach their target from one side: short steps
        dq = np.where(no_reverse, cfg.one_sided_gain * dq, dq)
        out: Array = np.clip(q + gain * np.clip(dq, -lim, lim), self._run.lo, self._run.hi)
        return out

    def _learn(self, before: PoseMeasurement, after: PoseMeasurement) -> None:
        """Update the step's Jacobian from a measured correction (``secant_weight``)."""
        from icenav.geometry.kinematics import jacobian

        cfg = self.config
        if cfg.secant_weight <= 0.0:
            return
        jac = jacobian(before.q, check=False) if self._jac is None else self._jac
        dq = after.q - before.q
        scale = np.array(cfg.max_step)
        self._jac = secant_update(jac, dq, before.error - after.error, scale, cfg.secant_weight)

    def _cost(self, m: PoseMeasurement) -> float:
        return float(np.linalg.norm(self._w * m.error))

    def _time_for(self, moves: list[Array], *, reserve: bool = True) -> bool:
        """Whether ``moves`` (at the stage's speed) and a measurement after them fit in the
        controller time left, keeping (``reserve``, with ``undo_if_worse``) the time to go
        back to the start and measure there; with ``step_from_last`` (else always True)."""
        cfg = self.config
        if not cfg.step_from_last:
            return True
        vel = np.array(cfg.max_velocity)

        def travel(q: Array, targets: list[Array]) -> float:
            t = 0.0
            for target in targets:
                t += float(np.max(np.abs(target - q) / vel)) + 0.1
                q = target
            return t

        wait = cfg.expiration_wait_s if self._expiration is not None else 0.0
        need = travel(self._run.cmd, moves) + self._hold_s + (wait if moves else 0.0)
        if reserve and (cfg.undo_if_worse or cfg.end_at_best):
            end = moves[-1] if moves else self._run.cmd
            back = self._best_q if cfg.end_at_best else self.q_start
            need += travel(end, [end - self._engaged() * np.array(cfg.backoff), back])
            need += self._hold_s + wait
        return self._run.elapsed + need <= cfg.max_duration_s

    def _worse_than_best(self, m: PoseMeasurement, best: PoseMeasurement) -> bool:
        return self._cost(m) > self._cost(best) + self.config.min_decrease_mm

    def _within(self, m: PoseMeasurement) -> bool:
        cfg = self.config
        return m.position_mm <= cfg.tolerance_mm and m.rotation_rad <= cfg.tolerance_rad

    def _servo(
        self,
    ) -> Generator[_Move | _MeasurePose | _WaitExpiration, PoseMeasurement | None, None]:
        cfg = self.config
        m = yield _MeasurePose()
        if m is None:
            m = yield _MeasurePose()
            if m is None:
                self._status = PoseStageStatus.NO_POSE
                return
        self._final = m
        if self._within(m):
            if not (cfg.verify and self._time_for([], reserve=False)):
                self._status = PoseStageStatus.AT_VIEW
                return
            m = yield _MeasurePose()  # an independent window at the same command
            if m is None:
                self._status = PoseStageStatus.NO_POSE
                return
            self._final = m
            if self._within(m):
                self._status = PoseStageStatus.AT_VIEW
                return
        first = m
        best = m
        self._best_q = m.q.copy()
        q = self._run.cmd.copy()
        if cfg.reapproach_first and np.any(self._engaged() != 0):
            yield from self._legs(self._approach(q, force=True))
            m = yield _MeasurePose()
            if m is None:
                self._status = PoseStageStatus.NO_POSE
                return
            # the start's play state is left for good: the re-approached state is the base
            self._final = m
            best, self._best_q = m, m.q.copy()
        iterations = 0
        gain = 1.0
        while not self._within(m):
            if iterations >= cfg.max_iterations:
                self._status = PoseStageStatus.BUDGET
                break
            if gain < cfg.min_gain:
                self._status = PoseStageStatus.STALLED
                break
            iterations += 1
            revisit = False
            if cfg.step_from_last:
                if cfg.revisit_best and self._worse_than_best(m, best):
                    revisit = True
                    moves = self._approach(best.q.copy(), force=True)
                    self._revisits += 1
                else:
                    target = self._step(self._run.cmd.copy(), m.error)
                    axial = abs(target[3] - self._run.cmd[3])
                    release = 0.0 < cfg.release_translation_mm < axial
                    moves = self._approach(target, force=cfg.approach_always or release)
            else:
                target = self._step(best.q.copy(), best.error, gain)
                moves = self._approach(target, force=not np.array_equal(self._run.cmd, best.q))
            if not self._time_for(moves):
                # a move it could not measure before the time budget ends would leave the
                # robot at an unmeasured new draw: stay at the last measured state
                self._status = PoseStageStatus.BUDGET
                break
            yield from self._legs(moves)
            m2 = yield _MeasurePose()
            if m2 is None:
                self._status = PoseStageStatus.NO_POSE
                return
            if cfg.step_from_last and not revisit:
                self._learn(m, m2)
            m = m2
            self._final = m
            paid = self._cost(m) < self._cost(best) - cfg.min_decrease_mm
            if paid or (cfg.step_from_last and revisit):
                # (a revisit is a new draw at the best command: its measurement replaces
                # the old one, which was the luckier of the two)
                best, self._best_q = m, m.q.copy()
            elif not cfg.step_from_last:
                gain *= 0.5  # the step did not pay: a shorter one from the best state
            elif cfg.stop_unpaid and not self._within(m):
                self._status = PoseStageStatus.STALLED
                break
            if cfg.verify and self._within(m) and self._time_for([], reserve=False):
                m2 = yield _MeasurePose()  # accept only what a second window confirms
                if m2 is None:
                    self._status = PoseStageStatus.NO_POSE
                    return
                m = m2
                self._final = m
                if np.array_equal(m.q, best.q):
                    best = m  # the newer window at the best command replaces the older
        else:
            self._status = PoseStageStatus.CONVERGED
            return
        end_moves = self._approach(best.q.copy(), force=True)
        if (
            cfg.step_from_last
            and (cfg.revisit_best or cfg.end_at_best)
            and self._worse_than_best(m, best)
            and self._time_for(end_moves, reserve=not cfg.end_at_best)
        ):
            # the last draw is worse than a measured one: end at the best command instead
            # (the start's, when no correction did better: the stage undoes itself)
            self._revisits += 1
            self._undone = bool(np.array_equal(best.q, self.q_start))
            yield from self._legs(end_moves)
            m5 = yield _MeasurePose()
            if m5 is not None:
                self._final = m5
        if (
            not cfg.step_from_last
            and self._cost(m) > self._cost(best)
            and not np.array_equal(self._run.cmd, best.q)
        ):
            yield from self._legs(self._approach(best.q, force=True))
            m3 = yield _MeasurePose()
            if m3 is not None:
                self._final = m3
        last = self._final
        if cfg.end_at_best:
            return
        if (
            cfg.undo_if_worse
            and last is not None
            and self._cost(last) > self._cost(first) + cfg.undo_margin_mm
            and not np.array_equal(self._run.cmd, self.q_start)
        ):
            # worse than at the start, as the same estimator tells: back to the start state
            self._undone = True
            yield from self._legs(self._approach(self.q_start, force=True))
            m4 = yield _MeasurePose()
            if m4 is not None:
                self._final = m4

    # --- the controller interface ---------------------------------------------------------
    @property
    def status(self) -> PoseStageStatus:
        """Running, or why it ended."""
        return self._status

    @property
    def progress(self) -> float:
        """Fraction of the iteration budget used, in [0, 1] (1 when finished)."""
        if self._gen_done and not self._run.queue:
            return 1.0
        return min(1.0, max(0, len(self._meas) - 1) / (self.config.max_iterations + 2))

    def _measure(self) -> PoseMeasurement | None:
        pose = self.sensor.measure_tip2base(n_average=self.config.n_average)
        if pose is None:
            return None
        m = PoseMeasurement(
            self._run.cmd.copy(), pose_error(self.saved, np.asarray(pose)), self._run.elapsed
        )
        self._meas.append(m)
        return m

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """The next motor set-point (4,), or None when the stage has ended."""
        check_positive(dt, "dt", "s")
        run = self._run
        if self._status == PoseStageStatus.ABORTED:
            return None
        if run.abort is not None and run.abort():
            self._status = PoseStageStatus.ABORTED
            self._gen.close()
            self._gen_done = True
            run.queue = []
            return None
        if self._gen_done and not run.queue:
            return None
        run.elapsed += dt
        if self._status == PoseStageStatus.RUNNING and run.elapsed > self.config.max_duration_s:
            self._status = PoseStageStatus.TIMEOUT
            self._gen.close()
            self._gen_done = True
            self._measuring = False
            self._wait_left = -1.0
            run.queue = []
            if not np.array_equal(run.cmd, self._best_q):
                run.queue_moves(self._approach(self._best_q, force=True), dt)
        while True:
            if run.queue:
                return run.send(run.queue.pop(0))
            if self._gen_done:
                return None
            value: PoseMeasurement | None = None
            if self._wait_left >= 0.0:
                gate = self._expiration
                if gate is not None and self._wait_left > 0.0 and not gate():
                    self._wait_left = max(0.0, self._wait_left - dt)
                    self.waited_s += dt
                    return run.cmd.copy()
                self._wait_left = -1.0
            elif self._measuring:
                if self._hold_left > 0:
                    self._hold_left -= dt
                    return run.cmd.copy()
                value = self._measure()
                self._measuring = False
            try:
                req = self._gen.send(value)
            except StopIteration:
                self._gen_done = True
                return None
            if isinstance(req, _MeasurePose):
                self._measuring = True
                self._hold_left = self._hold_s
            elif isinstance(req, _WaitExpiration):
                self._wait_left = self.config.expiration_wait_s
            else:
                run.queue_moves([req.q], dt)

    def result(self) -> PoseStageResult:
        """The outcome so far (final once :meth:`next_command` returned None)."""
        run = self._run
        return PoseStageResult(
            q_start=self.q_start.copy(),
            q_final=run.cmd.copy(),
            measurements=tuple(self._meas),
            final=self._final,
            status=self._status,
            duration_s=run.elapsed,
            n_commands=run.n_cmd,
            max_offset=run.max_off.copy(),
            undone=self._undone,
            revisits=self._revisits,
        )


def pose_stage(
    robot: RobotBackend,
    q_view: ArrayLike,
    saved_tip2base: ArrayLike,
    sensor: PoseSensor,
    *,
    arrival_direction: Sequence[int] = (0, 0, 0, 0),
    start_direction: Sequence[int] | None = None,
    config: PoseStageConfig | None = None,
    abort: Callable[[], bool] | None = None,
    expiration: Callable[[], bool] | None = None,
    dt: float = 0.01,
    sleep: Callable[[float], None] | None = None,
    on_command: Callable[[Array], object] | None = None,
    max_cycles: int = 1_000_000,
) -> PoseStageResult:
    """Run a :class:`PoseStageTask` on ``robot`` to its end (blocking); arguments as for
    :func:`refine` and :class:`PoseStageTask`."""
    check_positive(dt, "dt", "s")
    q0 = np.asarray(robot.read_state().q, np.float64)
    task = PoseStageTask(
        q_view,
        saved_tip2base,
        sensor,
        q_start=q0,
        arrival_direction=arrival_direction,
        start_direction=start_direction,
        config=config,
        abort=abort,
        expiration=expiration,
    )
    drive_task(robot, task, dt, sleep=sleep, on_command=on_command, max_cycles=max_cycles)
    return task.result()

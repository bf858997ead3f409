"""Executing a planned joint path on a robot backend within velocity/acceleration/jerk limits.

Trajectory generator: **ruckig** (the ``ruckig`` pip package), used *state-to-state only*,
online, one control cycle at a time. Each cycle the target is a "carrot" point that slides
along the planned path and is kept at most ``lookahead`` (metric units) ahead of the
commanded state; ruckig computes the next commanded state towards it (target at rest)
within the per-joint velocity, acceleration and jerk limits. Why ruckig and not toppra:

* Jerk limits (toppra handles velocity and acceleration only), and an *online* generator:
  pausing, aborting (a smooth stop within the limits) and resuming are just a change of
  target in the next cycle, with no re-planning of the whole path.
* Paths from the roadmap are polylines with corners; toppra would need a spline through
  the vertices, which may leave the epsilon-tube around the recorded states. The carrot
  keeps every commanded state close to the polyline instead (tested: within epsilon).

NEVER use ruckig's intermediate waypoints (``InputParameter.intermediate_positions``): the
pip version of ruckig computes those by sending the trajectory to a remote cloud service,
and no patient data may leave the machine. Only state-to-state calls are made here.

The executor never sleeps by itself: the controller's loop calls :meth:`PathExecutor.step`
once per control cycle (or :meth:`PathExecutor.run` with an injected ``sleep``).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig

from icenav._validation import check_joint_state, check_positive
from icenav.devices.robot import RobotBackend
from icenav.errors import ConfigurationError, HardwareError, MotionAborted, PlanningError
from icenav.recovery.roadmap import RoadmapMetric

__all__ = [
    "ExecutionStatus",
    "MotionLimits",
    "PathExecutor",
    "execute_path",
]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class MotionLimits:
    """Per-joint limits of automatic motion (phi1, phi2, phi3 in rad-based units, d4 in mm)."""

    max_velocity: tuple[float, float, float, float] = (0.35, 0.35, 0.35, 5.0)
    """Largest joint speed (rad/s, rad/s, rad/s, mm/s)."""
    max_acceleration: tuple[float, float, float, float] = (1.5, 1.5, 1.5, 20.0)
    """Largest joint acceleration (rad/s^2, rad/s^2, rad/s^2, mm/s^2)."""
    max_jerk: tuple[float, float, float, float] = (15.0, 15.0, 15.0, 200.0)
    """Largest joint jerk (rad/s^3, rad/s^3, rad/s^3, mm/s^3)."""

    def __post_init__(self) -> None:
        for name, unit in (
            ("max_velocity", "(rad/s, rad/s, rad/s, mm/s)"),
            ("max_acceleration", "(rad/s^2, rad/s^2, rad/s^2, mm/s^2)"),
            ("max_jerk", "(rad/s^3, rad/s^3, rad/s^3, mm/s^3)"),
        ):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 4:
                raise ConfigurationError(f"{name} needs 4 values {unit}, got {values}")
            for v in values:
                check_positive(v, name, unit)
            object.__setattr__(self, name, values)


class ExecutionStatus(enum.Enum):
    """State of a :class:`PathExecutor`."""

    RUNNING = "running"
    """Following the path."""
    PAUSING = "pausing"
    """Slowing down (within the limits) to a pause."""
    PAUSED = "paused"
    """Holding still; :meth:`PathExecutor.resume` continues."""
    ABORTING = "aborting"
    """Slowing down (within the limits) after an abort; no resume."""
    ABORTED = "aborted"
    """Stopped after an abort (terminal)."""
    STOPPED = "stopped"
    """Stopped at once by :meth:`PathExecutor.stop` (terminal)."""
    DONE = "done"
    """Reached the end of the path exactly (terminal)."""
    FAULTED = "faulted"
    """The backend refused a command (terminal; the error was raised)."""


_TERMINAL = {
    ExecutionStatus.ABORTED,
    ExecutionStatus.STOPPED,
    ExecutionStatus.DONE,
    ExecutionStatus.FAULTED,
}


class PathExecutor:
    """Follow a motor joint path on a backend, one control cycle per :meth:`step`.

    Parameters
    ----------
    backend : RobotBackend
        The robot, ENABLED and standing at ``path[0]`` (within ``epsilon``).
    path : array-like, shape (n, 4)
        Motor states (rad, rad, rad, mm) from :meth:`icenav.recovery.roadmap.Roadmap.plan`.
    limits : MotionLimits
        Per-joint velocity, acceleration and jerk limits.
    dt : float
        Control period (s).
    metric : RoadmapMetric
        The roadmap's metric (to measure distances to the path).
    epsilon : float
        The roadmap's epsilon (metric units): no commanded step may exceed it, and the
        carrot's lookahead defaults to ``epsilon / 4``.
    abort : callable, optional
        Polled every cycle; returning True aborts (e.g. "the operator touched an input").
    progress : callable, optional
        Called every cycle with the fraction of the path done, in [0, 1].
    """

    def __init__(
        self,
        backend: RobotBackend,
        path: ArrayLike,
        *,
        limits: MotionLimits | None = None,
        dt: float = 0.01,
        metric: RoadmapMetric | None = None,
        epsilon: float = 1.0,
        lookahead: float | None = None,
        abort: Callable[[], bool] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> None:
        p = check_joint_state(path, name="path")
        if p.ndim != 2 or len(p) < 1:
            raise PlanningError(f"path must have shape (n, 4) with n >= 1, got {p.shape}")
        self.backend = backend
        self.limits = limits if limits is not None else MotionLimits()
        self.dt = check_positive(dt, "dt", "s")
        self.metric = metric if metric is not None else RoadmapMetric()
        self.epsilon = check_positive(epsilon, "epsilon", "metric units")
        self.lookahead = (
            self.epsilon / 4 if lookahead is None else check_positive(lookahead, "lookahead", "")
        )
        if self.lookahead > self.epsilon / 2:
            raise ConfigurationError(
                f"lookahead must be <= epsilon / 2 = {self.epsilon / 2:g} metric units, "
                f"got {self.lookahead:g}"
            )
        scale = self.metric.scale
        step_metric = float(np.linalg.norm(np.array(self.limits.max_velocity) * scale)) * self.dt
        if step_metric > self.epsilon:
            raise ConfigurationError(
                f"max_velocity * dt allows a step of {step_metric:.3g} metric units per cycle, "
                f"more than epsilon = {self.epsilon:g}: lower the velocity limits or dt"
            )
        self._abort_poll = abort
        self._progress = progress
        self._path = p
        self._x = p * scale
        seg = np.linalg.norm(np.diff(self._x, axis=0), axis=1)
        self._s = np.concatenate([[0.0], np.cumsum(seg)])
        self._total = float(self._s[-1])
        state = backend.read_state()
        q0 = np.asarray(state.q, np.float64)
        gap = float(self.metric.distance(q0, p[0]))
        if gap > self.epsilon:
            raise PlanningError(
                f"the robot is {gap:.3g} metric units from the start of the path, more than "
                f"epsilon = {self.epsilon:g}"
            )
        self._otg = Ruckig(4, self.dt)  # online, state-to-state only (see module docstring)
        self._inp = InputParameter(4)
        self._out = OutputParameter(4)
        self._inp.current_position = q0.tolist()
        self._inp.current_velocity = [0.0] * 4
        self._inp.current_acceleration = [0.0] * 4
        self._inp.max_velocity = list(self.limits.max_velocity)
        self._inp.max_acceleration = list(self.limits.max_acceleration)
        self._inp.max_jerk = list(self.limits.max_jerk)
        self._cmd = q0.copy()
        self._carrot_s = 0.0
        self._done_s = 0.0
        self._status = ExecutionStatus.RUNNING
        self.cycles = 0
        """Number of control cycles run."""

    # --- public control ---------------------------------------------------------------

    @property
    def status(self) -> ExecutionStatus:
        """Current state."""
        return self._status

    @property
    def fraction_done(self) -> float:
        """Progress along the path, in [0, 1]."""
        if self._status is ExecutionStatus.DONE or self._total == 0.0:
            return 1.0 if self._status is ExecutionStatus.DONE else 0.0
        return min(1.0, self._done_s / self._total)

    @property
    def commanded(self) -> Array:
        """(4,) the latest commanded motor state."""
        return self._cmd.copy()

    def pause(self) -> None:
        """Slow down within the limits and hold (resume() continues)."""
        if self._status is ExecutionStatus.RUNNING:
            self._status = ExecutionStatus.PAUSING
            self._brake()

    def resume(self) -> None:
        """Continue after a pause."""
        if self._status in (ExecutionStatus.PAUSING, ExecutionStatus.PAUSED):
            self._inp.control_interface = ControlInterface.Position
            self._status = ExecutionStatus.RUNNING

    def abort(self) -> None:
        """Slow down within the limits and end (ABORTED)."""
        if self._status not in _TERMINAL:
            self._status = ExecutionStatus.ABORTING
            self._brake()

    def stop(self) -> None:
        """Stop at once: the backend holds its position; no further commands (STOPPED)."""
        if self._status not in _TERMINAL:
            self._status = ExecutionStatus.STOPPED
            self.backend.stop()

    # --- the control cycle --------------------------------------------------------------

    def _brake(self) -> None:
        self._inp.control_interface = ControlInterface.Velocity
        self._inp.target_velocity = [0.0] * 4
        self._inp.target_acceleration = [0.0] * 4

    def _point_at(self, s: float) -> Array:
        i = int(np.searchsorted(self._s, s, side="right")) - 1
        i = min(max(i, 0), len(self._path) - 2)
        if len(self._path) == 1:
            return self._x[0]
        s0, s1 = self._s[i], self._s[i + 1]
        t = 0.0 if s1 <= s0 else min(1.0, max(0.0, (s - s0) / (s1 - s0)))
        return self._x[i] + t * (self._x[i + 1] - self._x[i])

    def step(self) -> ExecutionStatus:
        """Run one control cycle: poll abort, compute and send the next command."""
        st = self._status
        if st in _TERMINAL:
            return st
        if (
            st is not ExecutionStatus.ABORTING
            and self._abort_poll is not None
            and self._abort_poll()
        ):
            self.abort()  # any operator input, also while pausing or paused
            st = self._status
        if st is ExecutionStatus.PAUSED:
            self._report()
            return st
        scale = self.metric.scale
        if st is ExecutionStatus.RUNNING:
            x_cmd = self._cmd * scale
            step = self.lookahead / 4
            while self._carrot_s < self._total:
                d = float(np.linalg.norm(self._point_at(self._carrot_s) - x_cmd))
                if d >= self.lookahead:
                    break
                self._carrot_s = min(self._total, self._carrot_s + step)
            carrot = self._point_at(self._carrot_s) / scale
            if self._carrot_s >= self._total:
                carrot = self._path[-1]
            self._inp.target_position = carrot.tolist()
            self._inp.target_velocity = [0.0] * 4
            self._inp.target_acceleration = [0.0] * 4
            d_c = float(np.linalg.norm(carrot * scale - x_cmd))
            self._done_s = max(self._done_s, self._carrot_s - d_c)
        result = self._otg.update(self._inp, self._out)
        if result not in (Result.Working, Result.Finished):
            raise HardwareError(f"ruckig failed ({result}) at commanded state {self._cmd}")
        new = np.array(self._out.new_position, np.float64)
        self._out.pass_to_input(self._inp)
        finished = result == Result.Finished
        if st is ExecutionStatus.RUNNING and finished and self._carrot_s >= self._total:
            new = self._path[-1].copy()  # land exactly on the view's state
        self._send(new)
        self.cycles += 1
        if st is ExecutionStatus.RUNNING and finished and self._carrot_s >= self._total:
            self._status = ExecutionStatus.DONE
        elif st is ExecutionStatus.PAUSING and finished:
            self._status = ExecutionStatus.PAUSED
        elif st is ExecutionStatus.ABORTING and finished:
            self._status = ExecutionStatus.ABORTED
        self._report()
        return self._status

    def _send(self, q: Array) -> None:
        try:
            self.backend.command_position(q)
        except HardwareError:
            self._status = ExecutionStatus.FAULTED
            raise
        self._cmd = q

    def _report(self) -> None:
        if self._progress is not None:
            self._progress(self.fraction_done)

    def run(
        self, *, max_cycles: int = 10_000_000, sleep: Callable[[float], None] | None = None
    ) -> ExecutionStatus:
        """Call :meth:`step` until the motion ends (DONE, ABORTED, STOPPED).

        ``sleep`` (e.g. ``time.sleep``) is called with ``dt`` after each cycle for real-time
        use; tests pass none. A PAUSED executor keeps holding (returns after ``max_cycles``).
        """
        for _ in range(max_cycles):
            st = self.step()
            if st in _TERMINAL:
                return st
            if sleep is not None:
                sleep(self.dt)
        return self._status


def execute_path(backend: RobotBackend, path: ArrayLike, **kwargs: object) -> int:
    """Run a :class:`PathExecutor` to the end; return the number of cycles.

    Raises
    ------
    MotionAborted
        The motion was aborted or stopped before reaching the end of the path.
    """
    ex = PathExecutor(backend, path, **kwargs)  # type: ignore[arg-type]
    status = ex.run()
    if status is not ExecutionStatus.DONE:
        raise MotionAborted(
            f"motion {status.value} at {100 * ex.fraction_done:.1f} % of the path "
            f"(commanded state {ex.commanded.tolist()})"
        )
    return ex.cycles

"""Automatic motions behind one protocol: each cycle a task returns a status *value*.

:class:`Task` ``.step(q_measured, dt)`` returns :class:`Running` (the next motor set-point),
:class:`Done` or :class:`Failed` (with the reason); the controller never guesses an outcome
from ``None`` or from attributes a task may or may not have. Here:

- :class:`PathTask`: follow a motor-space polyline at bounded speed (a go to view); with a
  force channel and the operator's recorded forces, it stops when the contact force
  exceeds them by a margin (:mod:`icenav.recovery.force`);
- :class:`PlanningTask`: a go to view on a large roadmap: hold while a worker computes the
  shortest-path tree, then plan and follow the path;
- :class:`MotionAdapter`: any motion generator with ``next_command(q, dt) -> q | None`` (the
  spin of :mod:`icenav.control.spin`, the refinement stages of :mod:`icenav.refinement`) as a
  task, with the rule that says whether its end was a success;
- :func:`refinement_task`: the closed-loop refinement of a returned view as a go-to-view task.

The calibration procedure's task is :class:`icenav.control.calibration_runner.CalibrationRunner`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from icenav._typing import Array
from icenav.control.modes import Mode
from icenav.errors import IcenavError, InvalidValueError
from icenav.recovery.drift import (
    CONFIRM_S,
    DEFAULT_DRIFT_MM,
    DRIFT_WINDOW_S,
    Phases,
    RestReference,
    cannot_tell,
)
from icenav.recovery.force import (
    DEFAULT_MARGIN_FRACTION,
    DEFAULT_MARGIN_N,
    ForceCheck,
    ForceRecord,
    ForceSensor,
    PathForces,
    TipForceMap,
    TipIndex,
    force_limit,
)
from icenav.recovery.roadmap import Roadmap
from icenav.recovery.views import View

if TYPE_CHECKING:  # imported on use: the refinement loads scipy.ndimage and the imaging
    from icenav.control.config import ControllerConfig
    from icenav.refinement.image_search import RefinementTask
    from icenav.refinement.pose_stage import PoseStageTask
    from icenav.refinement.task import ViewRefinementTask

__all__ = [
    "Done",
    "Failed",
    "MotionAdapter",
    "MotionGenerator",
    "PathTask",
    "PlanningTask",
    "Running",
    "Task",
    "TaskStatus",
    "goto_view_task",
    "refinement_task",
]


@dataclass(frozen=True, eq=False)
class Running:
    """The task goes on: command ``q``."""

    q: Array
    """(4,) next motor set-point (rad, rad, rad, mm)."""


@dataclass(frozen=True)
class Done:
    """The task finished as asked."""

    message: str = ""
    """What the operator reads ("" : "<label>: done")."""


@dataclass(frozen=True)
class Failed:
    """The task ended without doing what it was asked; the robot holds."""

    reason: str
    """Why, for the operator."""


TaskStatus = Running | Done | Failed
"""What :meth:`Task.step` returns."""


class Task(Protocol):
    """An automatic motion, stepped by the controller once per cycle."""

    @property
    def mode(self) -> Mode:
        """The mode the controller is in while it runs (GOTO_VIEW, SPINNING, CALIBRATING)."""
        ...

    @property
    def label(self) -> str:
        """What it is, for the operator ("go to view 'aortic'", "spin 360", ...)."""
        ...

    @property
    def progress(self) -> float:
        """Fraction done, in [0, 1]."""
        ...

    def step(self, q_measured: Array, dt: float) -> TaskStatus:
        """One cycle: the next set-point, or the end."""
        ...


@dataclass(eq=False)
class PathTask:
    """Follow a motor-space path exactly through its vertices at bounded joint speed.

    Each segment's duration is the slowest joint's ``|dq| / (speed_scale * v_max)``; the
    path time is run with a trapezoidal rate (ramping up over ``ramp_s`` and down to a stop
    at the end), so accelerations stay bounded. The commanded state never leaves the
    travelled polyline, which is what view recovery promises.
    """

    path: Array
    """(n, 4) motor states to pass through (rad, rad, rad, mm); path[0] ~ the current state."""
    max_velocity: Array
    """(4,) speed limit (rad/s, rad/s, rad/s, mm/s)."""
    mode: Mode = Mode.GOTO_VIEW
    label: str = "path"
    speed_scale: float = 0.5
    """Fraction of the speed limit used."""
    ramp_s: float = 0.3
    """Time to reach full speed from rest, and to stop (s): bounds the acceleration to
    about speed / ramp_s (a trapezoidal profile in path time)."""
    force_sensor: ForceSensor | None = None
    """The robot's contact-force channel; None: no force check."""
    force_profile: Array | None = None
    """(n,) contact force (N) the operator's trace produced at each path state
    (:meth:`icenav.recovery.force.ForceMap.profile`); None: no force check."""
    force_margin_n: float = DEFAULT_MARGIN_N
    """Absolute margin of the force check, Eq. (F1) of :mod:`icenav.recovery.force` (N)."""
    force_margin_fraction: float = DEFAULT_MARGIN_FRACTION
    """Relative margin of the force check (fraction of the recorded force)."""
    force_hold_s: float = 0.0
    """Time the force must stay above its limit before the path stops, Eq. (F4) (s); 0: the
    first cycle above stops (Eq. F1 alone, as the evaluations' bench checks); the controller
    passes ``ControllerConfig.force_hold_s``
    (:data:`~icenav.recovery.force.DEFAULT_HOLD_S`)."""
    force_path: PathForces | None = None
    """The recorded forces along the path found as the task goes (the controller's way:
    no whole-path lookup on the control thread), instead of :attr:`force_profile`."""
    tip_index: Future[Any] | None = None
    """The index of the operator's tip readings being built off the loop
    (:meth:`icenav.recovery.force.TipForceMap.index`): the task holds at the path's start
    until it is ready, then uses it as :attr:`tip_forces` (F1 alone if it failed)."""
    tip_forces: TipForceMap | TipIndex | None = None
    """The operator's forces keyed by the measured tip pose (Eq. F2 of
    :mod:`icenav.recovery.force`): where the tip is now within its radius of where the
    operator had it, the larger of that reference and the motor state's is checked; None:
    the motor state's only (Eq. F1)."""
    tip_pose: Callable[[], Array | None] | None = None
    """The measured tip pose now ((4, 4) mm, base frame; None when unknown), for
    :attr:`tip_forces`."""
    rest_tip: Array | RestReference | None = None
    """Where the tracked tip was when the operator last moved the motors: the reference of
    :attr:`icenav.recovery.force.ForceRecord.rest` or a (3,) position (mm). The path holds at
    its first state for :data:`~icenav.recovery.drift.DRIFT_WINDOW_S` and stops when the tip
    has since moved more than :attr:`drift_limit_mm` (Eq. F5 of
    :mod:`icenav.recovery.drift`); None: no such check (and no hold)."""
    signals: Callable[[float], Phases] | None = None
    """The respiratory signal and the cardiac phase at a time (s; each None without its
    channel), for Eq. (F5)'s phase match; None: its instantaneous form."""
    clock: Callable[[], float] | None = None
    """The loop's time (s), for :attr:`signals` and the reference's age."""
    drift_limit_mm: float = DEFAULT_DRIFT_MM
    """Eq. (F5)'s limit (mm)."""
    failure: str | None = field(default=None, init=False)
    """Why the task stopped early (the force check), None while it has not."""
    drift_unchecked: bool = field(default=False, init=False)
    """Whether the operator confirmed this return where the tip-drift check could not tell
    (Eq. F6): it runs under the force check alone."""
    _check: ForceCheck = field(init=False, repr=False)
    _cum_time: Array = field(init=False, repr=False)
    _t: float = field(default=0.0, init=False, repr=False)
    _elapsed: float = field(default=0.0, init=False, repr=False)
    _held_s: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        p = np.asarray(self.path, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 4 or len(p) < 1:
            raise InvalidValueError(f"path must have shape (n >= 1, 4), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise InvalidValueError("path must be finite (rad, rad, rad, mm)")
        self.path = p
        v = np.asarray(self.max_velocity, dtype=np.float64) * self.speed_scale
        if v.shape != (4,) or not np.all(v > 0):
            raise InvalidValueError(
                f"max_velocity * speed_scale must be 4 values > 0 (rad/s, mm/s), got {v}"
            )
        if self.force_profile is not None:
            fp = np.asarray(self.force_profile, dtype=np.float64)
            if fp.shape != (len(p),) or not np.all(np.isfinite(fp)):
                raise InvalidValueError(
                    f"force_profile must be {len(p)} finite forces (N), got shape {fp.shape}"
                )
            self.force_profile = fp
        names = ("force_margin_n", "force_margin_fraction", "force_hold_s", "drift_limit_mm")
        for name in names:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InvalidValueError(f"{name} must be finite and >= 0, got {value}")
        if self.rest_tip is not None and not isinstance(self.rest_tip, RestReference):
            rest = np.asarray(self.rest_tip, dtype=np.float64).reshape(-1)
            if rest.shape != (3,) or not np.all(np.isfinite(rest)):
                raise InvalidValueError(f"rest_tip must be 3 finite mm, got {self.rest_tip}")
            self.rest_tip = RestReference(0.0, rest)
        self._check = ForceCheck(self.force_margin_n, self.force_margin_fraction,
                                 self.force_hold_s)  # fmt: skip
        seg = np.abs(np.diff(p, axis=0)) / v if len(p) > 1 else np.zeros((0, 4))
        durations = seg.max(axis=1) if len(seg) else np.zeros(0)
        self._cum_time = np.concatenate([[0.0], np.cumsum(durations)])

    @property
    def duration(self) -> float:
        """Total time of the path at full rate (s)."""
        return float(self._cum_time[-1])

    @property
    def progress(self) -> float:
        return 1.0 if self.duration == 0 else min(1.0, self._t / self.duration)

    @property
    def path_index(self) -> int:
        """Index of the path state the last set-point left (0 .. n - 1)."""
        i = int(np.searchsorted(self._cum_time, self._t, side="right")) - 1
        return min(max(i, 0), len(self.path) - 1)

    def step(self, q_measured: Array, dt: float) -> TaskStatus:
        """The next point of the path, or Done at its end."""
        if self.failure is not None:
            return Failed(self.failure)
        if self._t >= self.duration:
            return Done()
        if self.tip_index is not None:
            if not self.tip_index.done():
                return Running(self.path[0].copy())  # the index is built: hold at the start
            if self.tip_index.exception() is None:
                self.tip_forces = self.tip_index.result()
            self.tip_index = None
        if self._held_s < DRIFT_WINDOW_S and self.rest_tip is not None and self.tip_pose:
            stop = self._drift_check()  # Eq. (F5), holding at the start
            if stop is not None:
                return stop
            self._held_s += dt
            return Running(self.path[0].copy())
        if self.force_sensor is not None and (
            self.force_profile is not None or self.force_path is not None
        ):
            stop = self._force_check(dt)
            if stop is not None:
                return stop
        # path-time rate r in (0, 1]: ramps up over ramp_s, and down to stop at the end
        # (r <= sqrt(2 * remaining / ramp_s)); never 0, so the task always finishes
        self._elapsed += dt
        remaining = self.duration - self._t
        rate = min(1.0, self._elapsed / self.ramp_s, math.sqrt(2.0 * remaining / self.ramp_s))
        self._t = min(self.duration, self._t + dt * max(rate, 0.02))
        i = int(np.searchsorted(self._cum_time, self._t, side="right")) - 1
        i = min(max(i, 0), len(self.path) - 2)
        t0, t1 = self._cum_time[i], self._cum_time[i + 1]
        s = 1.0 if t1 <= t0 else (self._t - t0) / (t1 - t0)
        return Running(np.asarray(self.path[i] + s * (self.path[i + 1] - self.path[i])))

    def _drift_check(self) -> Failed | None:
        """Eqs. (F5, F6) before the path moves: Failed when the tracked tip has moved more
        than the limit since the operator last moved the motors; where the still tip itself
        strays that far (Eq. F6), Failed once with a question instead, and the operator's
        second press runs the return under the force limit alone."""
        tip = self.tip_pose() if self.tip_pose is not None else None
        rest = self.rest_tip
        if tip is None or not isinstance(rest, RestReference) or self.drift_unchecked:
            return None
        now = self.clock() if self.clock is not None else None
        phases = (None, None) if self.signals is None or now is None else self.signals(now)
        drift = rest.drift(tip, *phases, t=now)
        if drift <= self.drift_limit_mm:
            return None
        resolution = rest.resolution_mm()
        if cannot_tell(resolution, self.drift_limit_mm):  # Eq. (F6)
            if rest.confirmed(now):
                self.drift_unchecked = True
                rest.answered()
                return None
            rest.ask(now)
            self.failure = (
                f"{self.label}: holds before it starts: the tip-drift check cannot tell here "
                f"whether the patient has moved: the tracked tip is {drift:.1f} mm from where "
                f"you left it (limit {self.drift_limit_mm:.1f} mm), but with the motors still "
                f"it strays {resolution:.1f} mm by itself here (the beat and the breath move "
                "a wall it touches). Look at the image: if the patient has not moved, press "
                f"again within {CONFIRM_S:.0f} s to return with the force check alone; else "
                "drive to the view by hand"
            )
            return Failed(self.failure)
        spread = rest.spread_mm()
        at_rest = (
            f"; at rest the tip strayed up to {spread:.1f} mm from its mean with the beat and "
            "the breath: if the patient did not move, move the catheter a little and go again"
            if spread > 0.5 * self.drift_limit_mm
            else ""
        )
        self.failure = (
            f"{self.label}: stopped as it started: the tracked tip moved {drift:.1f} mm with "
            f"the motors still since the operator last moved them (limit "
            f"{self.drift_limit_mm:.1f} mm{at_rest}; "
            "has the patient moved? the roadmap's states may no longer give the views); "
            "the robot holds"
        )
        return Failed(self.failure)

    def _force_check(self, dt: float) -> Failed | None:
        """Eqs. (F1, F2, F4) at the state last commanded: Failed (and the path stops) when
        the force read has stayed above what the operator's trace produced there plus the
        margin for the hold time."""
        sensor, profile = self.force_sensor, self.force_profile
        if sensor is None or (profile is None and self.force_path is None):
            return None
        f = sensor.contact_force_n()
        if f is None:
            return None
        i = self.path_index
        if profile is not None:
            recorded: float | None = force_limit(
                profile, i, self.force_margin_n, self.force_margin_fraction
            )[0]
        else:
            recorded = self.force_path.recorded(i)  # type: ignore[union-attr]
        if (
            recorded is not None
            and f > self._check.limit(recorded)
            and (self.tip_forces is not None and self.tip_pose is not None)
        ):  # Eq. (F2): the larger reference where the tip is near the operator's
            at_tip = self.tip_forces.reference(self.tip_pose())
            if at_tip is not None and at_tip > recorded:
                recorded = at_tip
        stop = self._check.update(f, recorded, dt)  # Eq. (F4); None: no force recorded near
        if stop is None:
            return None
        tip = self.tip_pose() if self.tip_pose is not None else None
        where = "" if tip is None else " (tip at {:.1f}, {:.1f}, {:.1f} mm)".format(*tip[:3, 3])
        self.failure = (
            f"{self.label}: stopped at path state {i} of {len(self.path) - 1}{where}: "
            f"contact force {stop.force_n:.2f} N exceeds the {stop.recorded_n:.2f} N the "
            f"operator's trace produced there by more than the margin for {stop.held_s:.2f} s "
            f"(limit "
            f"{stop.limit_n:.2f} N: + {self.force_margin_n:.2f} N "
            f"+ {100 * self.force_margin_fraction:.0f} %; has the patient moved?); "
            "the robot holds"
        )
        return Failed(self.failure)

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """As :meth:`step`, for a caller that drives the path itself (the evaluations): the
        next set-point, or None at the end (or when it stopped: see :attr:`failure`)."""
        status = self.step(q_measured, dt)
        return status.q if isinstance(status, Running) else None


def goto_view_task(
    path: Array,
    config: ControllerConfig,
    *,
    label: str,
    force_sensor: ForceSensor | None,
    forces: ForceRecord,
    roadmap: Roadmap,
    tip_pose: Callable[[], Array | None] | None,
    tip_index: Callable[[], Future[Any] | None] | None = None,
    signals: Callable[[float], Phases] | None = None,
    clock: Callable[[], float] | None = None,
) -> PathTask:
    """The "go to view" path task with the product's force check (Eqs. F1, F2, F4 of
    :mod:`icenav.recovery.force`, the margins and hold of ``config``), checked only with a
    force channel and a recorded trace, and the tip-drift check (Eq. F5, the drift limit of
    ``config``), with a tracker that saw where the operator left the tip: one definition
    for the controller and the evaluations (``icenav eval recovery``), so Table II measures
    what the product does.

    ``path`` (n, 4) motor states; ``forces`` the operator's record (per vertex, per tip pose,
    the rest tip); ``tip_pose`` the tracked tip now ((4, 4) mm or None); ``tip_index`` starts
    the index of the operator's tip readings (on a worker in the controller) and returns its
    future, None when there are none (without it the index is built here, on first use);
    ``signals`` the respiratory signal and the cardiac phase at a time of ``clock``, for Eq.
    (F5)'s phase match (None: its instantaneous form)."""
    checked = force_sensor is not None and forces.forces.n_recorded > 0
    index = tip_index() if checked and tip_index is not None else None
    tips = forces.tips if checked and tip_index is None and forces.tips.n_samples else None
    return PathTask(
        path,
        np.asarray(config.max_velocity),
        mode=Mode.GOTO_VIEW,
        label=label,
        force_sensor=force_sensor if checked else None,
        force_path=PathForces(forces.forces, roadmap, path) if checked else None,
        force_margin_n=config.force_margin_n,
        force_margin_fraction=config.force_margin_fraction,
        tip_index=index,
        tip_forces=tips,
        tip_pose=tip_pose,
        force_hold_s=config.force_hold_s,
        # Eq. (F5) needs the tracker only, not a force channel
        rest_tip=forces.rest if tip_pose is not None else None,
        drift_limit_mm=config.force_drift_mm,
        signals=signals,
        clock=clock,
    )


class PlanningTask:
    """Go to a view on a large roadmap: hold while a worker computes the shortest-path tree
    to the view (on a snapshot of the graph), then plan from where the robot is and follow
    the path (a :class:`PathTask`).

    Parameters
    ----------
    view : View
        The goal.
    tree : Future
        The worker's job: the shortest-path tree to the view (``Roadmap.tree_job``).
    roadmap : Roadmap
        The controller's roadmap (planned on the control thread, after installation).
    hold : array, shape (4,)
        The set-point held while planning (the current command).
    make_path : callable
        ``make_path(path (n, 4)) -> PathTask``.
    install : callable
        Installs the finished tree into the roadmap (once: the controller's job does the
        same when the task is gone before).
    """

    mode = Mode.GOTO_VIEW

    def __init__(
        self,
        view: View,
        tree: Future[Any],
        roadmap: Roadmap,
        hold: Array,
        make_path: Callable[[Array], PathTask],
        install: Callable[[], None],
    ) -> None:
        self.label = f"go to view {view.name!r}"
        self._install = install
        self._view = view
        self._tree = tree
        self._roadmap = roadmap
        self._hold = np.array(hold, dtype=np.float64)
        self._make_path = make_path
        self._path: PathTask | None = None

    @property
    def progress(self) -> float:
        return 0.0 if self._path is None else self._path.progress

    def step(self, q_measured: Array, dt: float) -> TaskStatus:
        if self._path is None:
            if not self._tree.done():
                return Running(self._hold)  # planning: hold position
            exc = self._tree.exception()
            if exc is not None:
                return Failed(f"cannot go to {self._view.name!r}: planning failed: {exc}")
            self._install()
            try:
                path = self._roadmap.plan(q_measured, self._view, approach=True)
            except IcenavError as err:
                return Failed(f"cannot go to {self._view.name!r}: {err}")
            self._path = self._make_path(path)
        return self._path.step(q_measured, dt)


class MotionGenerator(Protocol):
    """What :class:`MotionAdapter` drives: a set-point per cycle until None."""

    @property
    def label(self) -> str:
        """What it is, for the operator (may change as it goes)."""
        ...

    @property
    def progress(self) -> float:
        """Fraction done, in [0, 1]."""
        ...

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """The next motor set-point (4,), or None at its end."""
        ...


class MotionAdapter:
    """A motion generator (``next_command(q, dt) -> q | None``) as a task.

    Parameters
    ----------
    inner : MotionGenerator
        The generator (a :class:`icenav.control.spin.SpinTask`, a refinement stage, ...).
    mode : Mode
        The controller's mode while it runs.
    verdict : callable, optional
        Called once the generator returned None: None if it did what it was asked, else the
        reason it did not (the task then ends Failed). Default: done.
    """

    def __init__(
        self,
        inner: MotionGenerator,
        mode: Mode,
        *,
        verdict: Callable[[], str | None] | None = None,
    ) -> None:
        self.inner = inner
        self.mode = mode
        self._verdict = verdict

    @property
    def label(self) -> str:
        return self.inner.label

    @property
    def progress(self) -> float:
        return float(self.inner.progress)

    def step(self, q_measured: Array, dt: float) -> TaskStatus:
        q = self.inner.next_command(q_measured, dt)
        if q is not None:
            return Running(np.asarray(q, dtype=np.float64))
        why = None if self._verdict is None else self._verdict()
        return Done() if why is None else Failed(f"{self.label}: {why}")


_FAILED_ENDS = frozenset({"aborted", "no_pose"})
"""Statuses of a refinement stage that mean it did not refine (the robot holds)."""


def refinement_task(
    inner: ViewRefinementTask | PoseStageTask | RefinementTask,
) -> MotionAdapter:
    """The closed-loop refinement of a returned view (a
    :class:`icenav.refinement.task.ViewRefinementTask`, or one of its stages) as a go-to-view
    task: done when it converged or used its budget, failed when it was aborted or lost the
    tracker (the robot then holds where it was)."""

    from icenav.refinement.task import ViewRefinementTask

    def verdict() -> str | None:
        if isinstance(inner, ViewRefinementTask):
            pose, image = inner.result()
            statuses: list[enum.Enum] = [pose.status]
            if image is not None:
                statuses.append(image.status)
        else:
            statuses = [inner.status]
        bad = [str(s.value) for s in statuses if s.value in _FAILED_ENDS]
        return None if not bad else f"ended {bad[-1].replace('_', ' ')}"

    return MotionAdapter(inner, Mode.GOTO_VIEW, verdict=verdict)

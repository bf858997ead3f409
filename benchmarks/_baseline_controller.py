"""BASELINE for benchmarks/bench_controller.py: the controller as it was before the control
core was rebuilt (``git show 7bec7da:src/icenav/control/controller.py``), kept verbatim but
for the imports of names that moved (the gamepad mapping to ``icenav.control.teleop``), so
that the benchmark measures the old and the new cycle in the same run. Not used elsewhere.

The control loop: inputs -> commands, modes, safety, recording, views, automatic motions.

The :class:`Controller` owns time and state. Its :meth:`Controller.step` runs one control
cycle; :meth:`Controller.start` runs cycles in a thread at ``rate_hz`` (default 100 Hz).
Adapters (console, OpenIGTLink bridge, scripts) talk to it through the
:class:`~icenav.control.state.ControllerCommands` protocol: requests are queued and executed at the
start of the next cycle, except the emergency stop, which acts at once from the caller's
thread.

One cycle:

1. execute queued requests;
2. read the robot; a FAULT or ESTOP status puts the controller in FAULT / ESTOP (any
   automatic motion is dropped; motion resumes only after ``reset_fault``);
3. read the gamepad; stale or non-finite input counts as released (watchdog);
   operator input during an automatic motion aborts it;
4. compute the motor command of the mode (knob or tip teleoperation, or the automatic
   task's next set-point), limited in velocity and to the joint limits (a limit hit is
   reported, never silent);
5. command the robot; record the measured state into the roadmap (and the store);
6. read the twin's truth / tracker / imager as configured, and publish a snapshot.

Modes and the allowed transitions are in :data:`TRANSITIONS`.
"""

from __future__ import annotations

import gc
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_positive
from icenav.calibration.plans import MotionPlan, Recording, five_point_targets, raster_grid
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.control.spin import SpinTask, tracked_tip2base
from icenav.control.state import (
    CalibrationKind,
    ControllerState,
    ImageFrame,
    Mode,
    ViewSummary,
)
from icenav.control.teleop import (
    InputSource,
    JoystickMapping,
    knob_velocity,
    tip_twist,
)
from icenav.devices.gamepad import JoystickSample
from icenav.devices.robot import RobotBackend, RobotStatus
from icenav.errors import ConfigurationError, IcenavError, InvalidValueError, PlanningError
from icenav.geometry.kinematics import (
    DEFAULT_GEOMETRY,
    CatheterGeometry,
    backbone,
    forward,
    tip_jog,
)
from icenav.geometry.trajectories import spin_trajectory
from icenav.recovery.roadmap import Roadmap, warm_up_planner
from icenav.recovery.views import View, ViewLibrary

__all__ = [
    "AutomaticTask",
    "CalibrationTask",
    "Controller",
    "ControllerConfig",
    "KnobMap",
    "PathTask",
    "PlanTask",
    "TRANSITIONS",
]

_AUTOMATIC = (Mode.GOTO_VIEW, Mode.SPINNING, Mode.CALIBRATING)
_GC_NO_AUTOMATIC_FULL = 1_000_000_000
"""Generation-2 threshold of the GC policy: so large that no full collection is automatic."""
_GC_LOCK = threading.Lock()
_GC_USERS: set[int] = set()  # controllers holding the GC policy (settle_gc)
_GC_SAVED: list[int] = []  # the generation-2 threshold before the policy
_TELEOP = (Mode.IDLE, Mode.KNOB, Mode.TIP)

TRANSITIONS: dict[Mode, frozenset[Mode]] = {
    Mode.IDLE: frozenset({Mode.KNOB, Mode.TIP, *_AUTOMATIC, Mode.FAULT, Mode.ESTOP}),
    Mode.KNOB: frozenset({Mode.IDLE, Mode.TIP, *_AUTOMATIC, Mode.FAULT, Mode.ESTOP}),
    Mode.TIP: frozenset({Mode.IDLE, Mode.KNOB, *_AUTOMATIC, Mode.FAULT, Mode.ESTOP}),
    Mode.GOTO_VIEW: frozenset({Mode.IDLE, Mode.KNOB, Mode.TIP, Mode.FAULT, Mode.ESTOP}),
    Mode.SPINNING: frozenset({Mode.IDLE, Mode.KNOB, Mode.TIP, Mode.FAULT, Mode.ESTOP}),
    Mode.CALIBRATING: frozenset({Mode.IDLE, Mode.KNOB, Mode.TIP, Mode.FAULT, Mode.ESTOP}),
    Mode.FAULT: frozenset({Mode.IDLE, Mode.ESTOP}),
    Mode.ESTOP: frozenset({Mode.IDLE}),
}
"""mode -> modes it may go to. FAULT and ESTOP are left only through reset_fault (-> IDLE)."""


class KnobMap(Protocol):
    """A compensation between model and motor joint states (the paper's F on the knobs;
    roll and translation pass through). :class:`icenav.compensation.elasticity.ElasticityMap` is
    one."""

    def model_to_motor(self, q_model: ArrayLike, *, check: bool = True) -> Array:
        """Motor joint state(s) (..., 4) that realise the model joint state(s) (F)."""
        ...

    def motor_to_model(self, q_motor: ArrayLike, *, check: bool = True) -> Array:
        """Model joint state(s) (..., 4) that the motor joint state(s) realise (F^-1)."""
        ...


# A KnobMap with state (icenav.compensation.tendon_map.TendonKnobMap) also has
# ``observe(q_motor)``: the
# controller calls it with every command it sends, so the map knows the transmission's state.


class AutomaticTask(Protocol):
    """An automatic motion, stepped by the controller once per cycle."""

    mode: Mode
    """The mode the controller is in while this runs."""
    label: str
    """What it is, for the operator ("go to view 'aortic'", "spin 360", ...)."""

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """The next motor set-point (4,), or None when the task has finished."""
        ...

    @property
    def progress(self) -> float:
        """Fraction done, in [0, 1]."""
        ...


_JOG_ABS_MAX = 1e3
"""Largest magnitude of a jog velocity component accepted (rad/s or mm/s)."""


@dataclass(frozen=True)
class ControllerConfig:
    """Settings of the control loop."""

    rate_hz: float = 100.0
    """Control rate (Hz); the loop is tested at 100 and 500 Hz."""
    max_velocity: tuple[float, float, float, float] = (
        math.radians(60.0),
        math.radians(60.0),
        math.radians(90.0),
        10.0,
    )
    """Per-joint speed limit of every command (rad/s, rad/s, rad/s, mm/s)."""
    watchdog_s: float = 0.25
    """Operator input older than this counts as released (s)."""
    publish_every: int = 1
    """Publish a snapshot every this many cycles."""
    image_rate_hz: float = 20.0
    """Rate of the live ICE image (Hz), when an imager is configured."""
    backbone_points: int = 30
    """Points per drawn bending section."""
    background_plan_vertices: int = 2_000
    """From this roadmap size on, go-to-view plans in a background thread (the robot holds
    meanwhile) and a new view's shortest-path tree is prepared in the background (it was
    20,000: a plan inside the cycle then took up to 50 ms of CPU, 100-300 ms on a busy
    machine; see docs/safety.md, soak)."""
    plan_in_process: bool = True
    """Run the background Dijkstra of go-to-view / a new view's tree in a worker process
    (``Roadmap.tree_job(isolate=True)``): scipy's Dijkstra holds the GIL for its whole run,
    so in a thread it would stall the control loop (see the soak in docs/safety.md)."""
    gc_full_every_s: float = 300.0
    """With the real-time loop's GC policy (:meth:`Controller.settle_gc`): run a full
    garbage collection at most this often (s), between cycles, in a cycle's idle time."""
    spin_feedback: bool = True
    """Servo the spin on the EM tracker when one is configured with a registration
    (``tracker.config.tracker2base`` and ``sensor2tip``): :class:`icenav.control.spin.SpinTask`
    with a :class:`icenav.control.servo.TipPoseServo` (``docs/calibration.md``, section 4b)."""
    plan_settle_s: float = 0.1
    """Wait at each tracked state of the dense + hysteresis calibration before reading the
    tracker (s); its sweeps and circles move 1.5-3 deg at a time (the whole calibration
    takes about 12 minutes at the controller's pace)."""
    geometry: CatheterGeometry = DEFAULT_GEOMETRY
    """Catheter geometry and joint limits (the motor limits equal the model limits)."""

    def __post_init__(self) -> None:
        check_positive(self.rate_hz, "rate_hz", "Hz")
        if self.rate_hz > 2000:
            raise ConfigurationError(f"rate_hz must be <= 2000 Hz, got {self.rate_hz} Hz")
        check_positive(self.watchdog_s, "watchdog_s", "s")
        check_positive(self.image_rate_hz, "image_rate_hz", "Hz")
        check_positive(self.gc_full_every_s, "gc_full_every_s", "s")
        v = check_finite(self.max_velocity, "max_velocity", "rad/s, rad/s, rad/s, mm/s")
        if v.shape != (4,) or np.any(v <= 0):
            raise ConfigurationError(
                f"max_velocity must be 4 positive values (rad/s, rad/s, rad/s, mm/s), got {v}"
            )
        if int(self.publish_every) < 1:
            raise ConfigurationError(f"publish_every must be >= 1 cycle, got {self.publish_every}")
        if not (math.isfinite(self.plan_settle_s) and 0.0 <= self.plan_settle_s <= 10.0):
            raise ConfigurationError(
                f"plan_settle_s must be in [0, 10] s, got {self.plan_settle_s} s"
            )

    @property
    def dt(self) -> float:
        """Control period (s)."""
        return 1.0 / self.rate_hz


@dataclass
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
    on_done: Callable[[], None] | None = None
    """Called once when the end is reached."""
    _cum_time: Array = field(init=False, repr=False)
    _t: float = field(default=0.0, init=False, repr=False)
    _elapsed: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        p = np.asarray(self.path, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 4 or len(p) < 1:
            raise InvalidValueError(f"path must have shape (n >= 1, 4), got {p.shape}")
        self.path = p
        v = np.asarray(self.max_velocity, dtype=np.float64) * self.speed_scale
        seg = np.abs(np.diff(p, axis=0)) / v if len(p) > 1 else np.zeros((0, 4))
        durations = seg.max(axis=1) if len(seg) else np.zeros(0)
        self._cum_time = np.concatenate([[0.0], np.cumsum(durations)])

    @property
    def duration(self) -> float:
        """Total time of the path (s)."""
        return float(self._cum_time[-1])

    @property
    def progress(self) -> float:
        return 1.0 if self.duration == 0 else min(1.0, self._t / self.duration)

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        if self._t >= self.duration:
            if self.on_done is not None:
                self.on_done()
                self.on_done = None
            return None
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
        return np.asarray(self.path[i] + s * (self.path[i + 1] - self.path[i]))


class PlanTask:
    """Drive a :class:`icenav.calibration.plans.MotionPlan` inside the control loop and read the
    tracker where it says: the calibration motions of :mod:`icenav.calibration.plans`, with every
    move under the controller's limits, stop and e-stop.

    For each state: move there at bounded speed (a :class:`PathTask`); where the plan reads
    the tracker, wait ``settle_s`` for the catheter and the tracker, then ``measure(n)``
    (n = the plan's ``n_average``, one attempt per cycle; a MISSING attempt is retried up to
    the plan's ``retries``, then the state is recorded as not measured). When all states are
    done, ``on_done(recording)`` is called (from the control thread) and the task ends.
    """

    def __init__(
        self,
        plan: MotionPlan,
        measure: Callable[[int], Array | None],
        on_done: Callable[[Recording], None],
        *,
        max_velocity: Array,
        label: str,
        settle_s: float = 0.3,
        ramp_s: float = 0.3,
        phase_in_label: bool = True,
    ) -> None:
        if not isinstance(plan, MotionPlan):
            raise InvalidValueError(f"plan must be a MotionPlan, got {type(plan).__name__}")
        self.mode = Mode.CALIBRATING
        self._base_label = label
        self.label = label
        self._plan = plan
        self._measure = measure
        self._on_done = on_done
        self._vmax = np.asarray(max_velocity, dtype=np.float64)
        if not (math.isfinite(settle_s) and settle_s >= 0.0):
            raise InvalidValueError(f"settle_s must be >= 0 s, got {settle_s!r}")
        self._settle_s = float(settle_s)
        self._ramp_s = float(ramp_s)
        self._phase_in_label = bool(phase_in_label)
        self._i = 0
        self._move: PathTask | None = None
        self._wait = 0.0
        self._misses = 0
        self._attempts = 0
        self._poses = np.full((plan.n, 4, 4), np.nan)
        self._tries = np.zeros(plan.n, dtype=np.int64)
        self._done = False

    @property
    def progress(self) -> float:
        return min(1.0, self._i / self._plan.n)

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        if self._done:
            return None
        plan = self._plan
        if self._i >= plan.n:
            self._done = True
            self._on_done(Recording(plan=plan, tip2base=self._poses, attempts=self._tries))
            return None
        target = plan.q_motor[self._i]
        if self._move is None:
            self._move = PathTask(
                np.vstack([q_measured, target]),
                self._vmax,
                mode=self.mode,
                label=self.label,
                ramp_s=self._ramp_s,
            )
            self._wait = 0.0
            self._misses = 0
            self._attempts = 0
            if self._phase_in_label:
                self.label = f"{self._base_label}: {plan.phase_at(self._i)}"
        q_next = self._move.next_command(q_measured, dt)
        if q_next is not None:
            return q_next
        n = int(plan.n_average[self._i])
        if n > 0:
            self._wait += dt
            if self._wait < self._settle_s:
                return target
            self._attempts += 1
            pose = self._measure(n)
            if pose is None and self._misses < int(plan.retries[self._i]):
                self._misses += 1
                return target
            if pose is not None:
                self._poses[self._i] = np.asarray(pose, dtype=np.float64)
            self._tries[self._i] = self._attempts
        self._i += 1
        self._move = None
        return target


class CalibrationTask(PlanTask):
    """Drive a calibration raster and measure the tip with the tracker at each point.

    A :class:`PlanTask` of ``points`` (each read with ``measure()``, retried ``retries``
    times, then skipped); when all points are done, ``on_samples(q_motor (n, 4), tip2base
    (n, 4, 4), skipped)`` gets the measured ones (from the control thread).
    """

    def __init__(
        self,
        points: Array,
        measure: Callable[[], Array | None],
        on_samples: Callable[[Array, Array, int], None],
        *,
        max_velocity: Array,
        label: str,
        settle_s: float = 0.3,
        retries: int = 3,
    ) -> None:
        def done(rec: Recording) -> None:
            ok = rec.measured
            on_samples(rec.plan.q_motor[ok], rec.tip2base[ok], int(np.sum(~ok)))

        super().__init__(
            MotionPlan.make(points, "calibration", n_average=1, retries=retries),
            lambda _n: measure(),
            done,
            max_velocity=max_velocity,
            label=label,
            settle_s=settle_s,
            phase_in_label=False,
        )


class _PlanningTask:
    """Go to a view on a large roadmap: hold while a thread computes the shortest-path tree
    on a snapshot of the graph (scipy Dijkstra, about half a second at 1e6 vertices), then
    install it in the loop (repairing only the edges added meanwhile), plan, and follow the
    path (a :class:`PathTask`)."""

    def __init__(self, ctrl: Controller, view: View) -> None:
        self.mode = Mode.GOTO_VIEW
        self.label = f"go to view {view.name!r}"
        self._ctrl = ctrl
        self._view = view
        self._path: PathTask | None = None
        self.failed = False
        """True when no path could be planned (the message says why)."""
        self._hold = ctrl._q_cmd.copy()
        job = ctrl.roadmap.tree_job(view, approach=True, isolate=ctrl.config.plan_in_process)

        def run() -> None:
            prepared = job()
            ctrl._submit(lambda: self._ready(prepared))

        threading.Thread(target=run, name="icenav-plan", daemon=True).start()

    def _ready(self, prepared: Any) -> None:
        ctrl = self._ctrl
        ctrl.roadmap.install_tree(self._view, prepared)
        if ctrl._task is not self:
            return  # aborted meanwhile: the tree stays cached for the next return
        try:
            path = ctrl.roadmap.plan(ctrl._q, self._view, approach=True)
        except (PlanningError, InvalidValueError) as exc:
            ctrl._message = f"cannot go to {self._view.name!r}: {exc}"
            self.failed = True
            return
        self._path = ctrl._goto_task(self._view, path)

    @property
    def progress(self) -> float:
        return 0.0 if self._path is None else self._path.progress

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        if self.failed:
            return None
        if self._path is None:
            return self._hold  # planning: hold position
        return self._path.next_command(q_measured, dt)


@dataclass
class _Jog:
    velocity: Array
    frame: Literal["knob", "tip"]
    client: str
    at: float


class Controller:
    """The control loop on a robot backend (simulated or real); see the module docstring.

    Parameters
    ----------
    robot : RobotBackend
        The robot; enabled by the controller at start.
    config : ControllerConfig
        Rates, limits, geometry.
    roadmap : Roadmap, optional
        Where every visited state is recorded (a new one by default).
    views : ViewLibrary, optional
        Saved views (a new, empty one by default).
    input_source : InputSource, optional
        The gamepad (or a scripted input). None: on-screen jog only.
    mapping : JoystickMapping
        Gamepad mapping.
    compensation : KnobMap, optional
        Model <-> motor knob map used by tip mode and the spin (identity when None).
    truth : callable, optional
        ``truth() -> (tip2base (4,4), backbone (n,3))`` of the twin (None on hardware).
    tracker : object, optional
        A tracker backend (``get_frame()`` -> frame with ``status`` and ``sensor2tracker``)
        with ``config.tracker2base``; the sensor pose is published in the base frame.
    imager : callable, optional
        ``imager(tip2base_true, t) -> (H, W) uint8`` image of the current pose.
    image_ijk2tip : ndarray, shape (4, 4), optional
        Maps a pixel (i = column, j = row, k = 0) of the image into the tip frame (mm).
    recorder : callable, optional
        ``recorder(event, payload)`` for persistence (the store adapter): events
        "state", "view_saved", "view_deleted", "event".
    clock : callable
        Time source (s) for timestamps of jog requests and the real-time loop.
    """

    def __init__(
        self,
        robot: RobotBackend,
        config: ControllerConfig | None = None,
        *,
        roadmap: Roadmap | None = None,
        views: ViewLibrary | None = None,
        input_source: InputSource | None = None,
        mapping: JoystickMapping | None = None,
        compensation: KnobMap | None = None,
        truth: Callable[[], tuple[Array, Array]] | None = None,
        tracker: Any = None,
        imager: Callable[[Array, float], NDArray[np.uint8]] | None = None,
        image_ijk2tip: Array | None = None,
        recorder: Callable[[str, dict[str, Any]], object] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.robot = robot
        self.config = config or ControllerConfig()
        self.roadmap = roadmap if roadmap is not None else Roadmap()
        self.views = views if views is not None else ViewLibrary()
        self.input_source = input_source
        self.mapping = mapping or JoystickMapping()
        self.compensation = compensation
        self.compensation_enabled = compensation is not None
        self.calibration: CalibrationSet | None = None
        """The calibration set behind the installed compensation (None: none made here)."""
        self._truth = truth
        self.tracker = tracker
        self._imager = imager
        self._ijk2tip = np.eye(4) if image_ijk2tip is None else np.asarray(image_ijk2tip, float)
        self._recorder = recorder
        self._clock = clock
        self._requests: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._listeners: list[Callable[[ControllerState], None]] = []
        self._lock = threading.Lock()
        self._mode = Mode.IDLE
        self._task: AutomaticTask | None = None
        self._jog: _Jog | None = None
        self._owner: str | None = None
        self._message = ""
        self._fault_message = ""  # reliability: the FAULT / ESTOP cause, shown until reset
        self._view_alarm: str | None = (
            None  # a view saved in memory only: shown until a later one is on disk
        )
        self._time = 0.0
        self._cycle = 0
        self._prev_buttons: tuple[bool, ...] = ()
        self._selected_view: str | None = None
        self._image: ImageFrame | None = None
        self._next_image_t = 0.0
        self._view_images: dict[str, ImageFrame] = {}
        self._thread: threading.Thread | None = None
        self._image_thread: threading.Thread | None = None
        self._running = threading.Event()
        self.cycle_times: deque[float] = deque(maxlen=100_000)
        """Compute time of the latest cycles (s), for the benchmark."""
        self.cycle_starts: deque[float] = deque(maxlen=100_000)
        """perf_counter() at the start of the latest real-time cycles (s), for jitter."""
        self._next_full_gc: float | None = None  # GC policy: off until settle_gc()
        if self.robot.status is RobotStatus.DISABLED:
            self.robot.enable()
        q0 = self.robot.read_state().q
        self._q_cmd = np.array(q0, dtype=np.float64)
        self._q = np.array(q0, dtype=np.float64)
        self.roadmap.add(self._q)
        self._state = self._make_state()

    # --- ControllerCommands: requests -------------------------------------------------

    def _submit(self, fn: Callable[[], None]) -> None:
        self._requests.put(fn)

    def _may_move(self, client: str) -> bool:
        if self._owner is None or self._owner == client:
            return True
        self._message = f"{client} asked for motion but {self._owner} holds control (view only)"
        return False

    def request_mode(self, mode: Mode, client: str = "script") -> None:
        def do() -> None:
            if mode not in _TELEOP:
                self._message = f"mode {mode.value} is started by its own command, not by a switch"
                return
            if self._may_move(client):
                self._abort_task(f"switched to {mode.value}")
                self._jog = None  # a held jog belongs to the mode it was made in
                self._set_mode(mode)

        self._submit(do)

    def jog(
        self, velocity: ArrayLike, frame: Literal["knob", "tip"], client: str = "script"
    ) -> None:
        v = np.asarray(velocity, dtype=np.float64)
        expected = 4 if frame == "knob" else 6
        if frame not in ("knob", "tip") or v.shape != (expected,):
            raise InvalidValueError(
                f"jog takes frame 'knob' with 4 velocities (rad/s, rad/s, rad/s, mm/s) or "
                f"'tip' with 6 (mm/s, rad/s); got frame {frame!r} and shape {v.shape}"
            )
        if not np.all(np.isfinite(v)):
            raise InvalidValueError(f"jog velocity must be finite, got {v}")
        if np.any(np.abs(v) > _JOG_ABS_MAX):
            # commands are clipped to max_velocity anyway; this only keeps the arithmetic of
            # the tip-frame solve away from overflow (a gamepad gives at most a few units)
            raise InvalidValueError(
                f"jog velocity must be within +-{_JOG_ABS_MAX:g} (rad/s or mm/s; the speed "
                f"limits clip it further), got {v}"
            )
        now = self._clock()

        def do() -> None:
            if self._may_move(client):
                self._jog = _Jog(v, frame, client, now)

        self._submit(do)

    def save_view(self, name: str, client: str = "script") -> None:
        def do() -> None:
            self._save_view(name)

        self._submit(do)

    def goto_view(self, name: str, client: str = "script") -> None:
        def do() -> None:
            if self._may_move(client):
                self._start_goto(name)

        self._submit(do)

    def delete_view(self, name: str, client: str = "script") -> None:
        def do() -> None:
            try:
                self.views.delete(name)
                self._view_images.pop(name, None)
                self._record("view_deleted", {"name": name})
                self._message = f"view {name!r} deleted"
            except IcenavError as exc:
                self._message = str(exc)

        self._submit(do)

    def start_spin(self, client: str = "script") -> None:
        def do() -> None:
            if self._may_move(client):
                self._start_spin()

        self._submit(do)

    def start_calibration(self, kind: CalibrationKind, client: str = "script") -> None:
        def do() -> None:
            if self._may_move(client):
                self._start_calibration(kind)

        self._submit(do)

    def set_compensation(self, enabled: bool, client: str = "script") -> None:
        def do() -> None:
            if enabled and self.compensation is None:
                self._message = "no calibration yet: run Calibrate first"
                return
            self.compensation_enabled = bool(enabled)
            self._message = f"compensation {'on' if enabled else 'off'}"

        self._submit(do)

    def stop(self, client: str = "script") -> None:
        def do() -> None:
            self._abort_task(f"stopped by {client}")
            self._jog = None
            self._q_cmd = self._q.copy()
            self.robot.stop()
            if self._mode not in (Mode.FAULT, Mode.ESTOP):
                self._set_mode(Mode.IDLE)

        self._submit(do)

    def estop(self, client: str = "script") -> None:
        """Emergency stop: acts at once from the caller's thread, whatever the loop is doing."""
        self.robot.estop()
        with self._lock:
            self._task = None
            self._jog = None
            self._mode = Mode.ESTOP
            self._message = f"EMERGENCY STOP by {client}: reset to continue"
            self._fault_message = self._message
        self._record("event", {"text": self._message})

    def reset_fault(self, client: str = "script") -> None:
        def do() -> None:
            if self._mode not in (Mode.FAULT, Mode.ESTOP):
                return
            self.robot.reset_fault()
            self.robot.enable()
            self._q = np.array(self.robot.read_state().q, dtype=np.float64)
            self._q_cmd = self._q.copy()
            self._mode = Mode.IDLE
            self._fault_message = ""
            self._message = f"reset by {client}; holding position"
            self._record("event", {"text": self._message})

        self._submit(do)

    def acquire_control(self, client: str) -> bool:
        with self._lock:
            if self._owner in (None, client) or client == "gamepad":
                self._owner = client
                return True
            return False

    def release_control(self, client: str) -> None:
        with self._lock:
            if self._owner == client:
                self._owner = None
                if self._jog is not None and self._jog.client == client:
                    self._jog = None

    def snapshot(self) -> ControllerState:
        return self._state

    def latest_image(self) -> ImageFrame | None:
        return self._image

    def view_image(self, name: str) -> ImageFrame | None:
        return self._view_images.get(name)

    def add_listener(self, callback: Callable[[ControllerState], None]) -> None:
        self._listeners.append(callback)

    # --- the cycle ----------------------------------------------------------------------

    @property
    def mode(self) -> Mode:
        """Current mode."""
        return self._mode

    @property
    def time(self) -> float:
        """Controller time (s): cycles x period."""
        return self._time

    def step(self) -> ControllerState:
        """Run one control cycle (see the module docstring) and return the new state."""
        t_start = time.perf_counter()
        dt = self.config.dt
        self._time += dt
        self._cycle += 1
        while True:
            try:
                self._requests.get_nowait()()
            except queue.Empty:
                break
        js = self.robot.read_state()
        self._q = np.array(js.q, dtype=np.float64)
        if js.status in (RobotStatus.FAULT, RobotStatus.ESTOP) and self._mode not in (
            Mode.FAULT,
            Mode.ESTOP,
        ):
            self._task = None
            self._jog = None
            self._mode = Mode.FAULT if js.status is RobotStatus.FAULT else Mode.ESTOP
            self._message = f"robot {js.status.value}: {js.message or 'stopped'}; reset to continue"
            self._fault_message = self._message
            self._record("event", {"text": self._message})
        sample = self._read_gamepad()
        if self._mode in (Mode.FAULT, Mode.ESTOP):
            self._q_cmd = self._q.copy()
        else:
            q_next = self._command(sample, dt)
            if q_next is not None:
                self._send(q_next, dt)
        self.roadmap.add(self._q)
        self._record("state", {"q": self._q, "t": self._time})
        if self._cycle % self.config.publish_every == 0:
            self._publish()
        self.cycle_times.append(time.perf_counter() - t_start)
        return self._state

    def _read_gamepad(self) -> JoystickSample | None:
        if self.input_source is None:
            return None
        sample = self.input_source.poll()
        now = self._clock()
        if not sample.connected:
            self._prev_buttons = ()
            return None
        if now - sample.timestamp > self.config.watchdog_s:
            self._message = "gamepad input stale: motion stopped"
            return None
        m = self.mapping
        prev = self._prev_buttons

        def pressed(i: int) -> bool:
            return sample.button(i) and not (0 <= i < len(prev) and prev[i])

        self._prev_buttons = sample.buttons
        if pressed(m.estop_button):
            self.estop("gamepad")
            return None
        if pressed(m.stop_button):
            self.stop("gamepad")
        if pressed(m.mode_button) and self._mode in _TELEOP:
            self.request_mode(Mode.TIP if self._mode is Mode.KNOB else Mode.KNOB, "gamepad")
        if pressed(m.save_view_button):
            self.save_view(f"view {len(self.views) + 1}", "gamepad")
        if pressed(m.goto_view_button) and self._selected_view is not None:
            self.goto_view(self._selected_view, "gamepad")
        if not all(math.isfinite(a) for a in sample.axes):  # reliability: never half-apply
            self._message = "gamepad input not finite (NaN / inf axis): treated as released"
            self.release_control("gamepad")
            return None
        if sample.button(m.enable_button):
            self.acquire_control("gamepad")
        elif self._owner == "gamepad":
            # the gamepad holds control while its dead-man button is held, then lets go
            self.release_control("gamepad")
        return sample

    def _command(self, sample: JoystickSample | None, dt: float) -> Array | None:
        gamepad_moving = sample is not None and bool(
            np.any(knob_velocity(sample, self.mapping) != 0)
        )
        jog = self._jog
        if jog is not None and self._clock() - jog.at > self.config.watchdog_s:
            self._jog = jog = None
        if self._task is not None:
            if gamepad_moving or jog is not None:
                self._abort_task("aborted by operator input")
                self._set_mode(Mode.KNOB if self._mode not in (Mode.KNOB, Mode.TIP) else self._mode)
            else:
                q_next = self._task.next_command(self._q, dt)
                if q_next is None:
                    label = self._task.label
                    failed = bool(getattr(self._task, "failed", False))
                    self._task = None
                    self._set_mode(Mode.IDLE)
                    if not failed:  # a failed task has said why already
                        self._message = f"{label}: done"
                return q_next
        if self._mode not in (Mode.KNOB, Mode.TIP) and (gamepad_moving or jog is not None):
            # any teleoperation input wakes the controller from IDLE into knob mode
            self._set_mode(Mode.TIP if jog is not None and jog.frame == "tip" else Mode.KNOB)
        if self._mode is Mode.KNOB:
            if gamepad_moving and sample is not None:
                dq = knob_velocity(sample, self.mapping)
            elif jog is not None and jog.frame == "knob":
                dq = jog.velocity
            else:
                return None  # no input: hold (nothing is commanded)
            return self._q_cmd + dq * dt
        if self._mode is Mode.TIP:
            if gamepad_moving and sample is not None:
                twist = tip_twist(sample, self.mapping)
            elif jog is not None and jog.frame == "tip":
                twist = jog.velocity
            else:
                return None  # no input: hold (nothing is commanded)
            q_model = self._to_model(self._q_cmd)
            dq_model = tip_jog(q_model, twist, self.config.geometry, dt=dt, check=False)
            return self._to_motor(q_model + dq_model * dt)
        return None

    def _send(self, q_next: Array, dt: float) -> None:
        """Limit the command in speed and to the joint limits, then command the robot."""
        vmax = np.asarray(self.config.max_velocity) * dt
        step = np.clip(q_next - self._q_cmd, -vmax, vmax)
        q = self._q_cmd + step
        lim = self.config.geometry.joint_limits
        clipped = np.clip(q, lim[:, 0], lim[:, 1])
        if np.any(clipped != q):
            names = [
                n
                for n, a, b in zip(("phi1", "phi2", "phi3", "d4"), q, clipped, strict=True)
                if a != b
            ]
            self._message = f"joint limit reached: {', '.join(names)} held at its limit"
        self._q_cmd = clipped
        try:
            self.robot.command_position(clipped)
        except IcenavError as exc:
            self._task = None
            self._message = f"command refused: {exc}"
            self._q_cmd = self._q.copy()
            return
        observe = getattr(self.compensation, "observe", None)
        if observe is not None:  # a compensation with state follows every command sent
            observe(clipped)

    # --- compensation -------------------------------------------------------------------

    def _to_model(self, q_motor: Array) -> Array:
        if not self.compensation_enabled or self.compensation is None:
            return np.array(q_motor, dtype=np.float64)
        return np.asarray(self.compensation.motor_to_model(q_motor, check=False))

    def _to_motor(self, q_model: Array) -> Array:
        if not self.compensation_enabled or self.compensation is None:
            return np.array(q_model, dtype=np.float64)
        return np.asarray(self.compensation.model_to_motor(q_model, check=False))

    # --- modes and tasks ----------------------------------------------------------------

    def _set_mode(self, mode: Mode) -> None:
        if mode is self._mode:
            return
        if mode not in TRANSITIONS[self._mode]:
            self._message = f"cannot go from {self._mode.value} to {mode.value}"
            return
        self._mode = mode
        self._record("event", {"text": f"mode {mode.value}"})

    def _abort_task(self, why: str) -> None:
        if self._task is not None:
            self._message = f"{self._task.label}: {why}"
            self._record("event", {"text": self._message})
            self._task = None
            self._q_cmd = self._q.copy()
            self.robot.stop()

    def start_task(self, task: AutomaticTask) -> None:
        """Run an automatic task (from the loop thread or before the loop starts)."""
        if self._mode in (Mode.FAULT, Mode.ESTOP):
            self._message = f"cannot start {task.label}: controller in {self._mode.value}"
            return
        self._abort_task("replaced")
        self._set_mode(task.mode)
        if self._mode is task.mode:
            self._task = task
            self._jog = None
            self._message = f"{task.label}: started"

    def _save_view(self, name: str) -> None:
        if name in self.views:
            self._message = f"a view named {name!r} exists already: choose another name"
            return
        tip = forward(self._to_model(self._q), self.config.geometry, check=False)
        thumb = None if self._image is None else self._image.pixels
        try:
            view = self.roadmap.make_view(
                name, created_s=time.time(), q=self._q, tip2base=tip, thumbnail=thumb
            )
            self.views.add(view)
        except IcenavError as exc:
            self._message = f"view not saved: {exc}"
            return
        if self._image is not None:
            self._view_images[name] = self._image
        self._selected_view = name
        self._prepare_plans_to(view)

        # --- store writer hand-off (the soak): a threaded recorder commits the view on its
        # own thread and calls back; the operator reads "saved" only once it is on disk
        def on_durable(error: BaseException | None) -> None:  # on the writer thread
            if error is None:
                text = f"view {name!r} saved"
            else:
                text = (
                    f"view {name!r} saved in memory only, NOT on disk: "
                    f"could not record view_saved: {error}"
                )
            self._submit(lambda: self._view_saved(name, text, error is None))

        recorded = self._record("view_saved", {"view": view, "on_durable": on_durable})
        if recorded == "pending":
            self._message = f"view {name!r}: saving to disk"
        elif recorded:
            self._view_saved(name, f"view {name!r} saved", True)
        else:  # reliability: the operator must know the view is not on disk
            text = f"view {name!r} saved in memory only, NOT on disk: {self._message}"
            self._view_saved(name, text, False)

    def _view_saved(self, name: str, text: str, durable: bool) -> None:
        """Tell the operator whether view ``name`` is on disk. A view that is *not* stays in
        front of every later message (an alarm) until a later view is saved to disk: a
        store failure also fails the next state batch, whose message must not hide it."""
        self._message = text
        self._view_alarm = None if durable else text

    def _goto_task(self, view: View, path: Array) -> PathTask:
        return PathTask(
            path,
            np.asarray(self.config.max_velocity),
            mode=Mode.GOTO_VIEW,
            label=f"go to view {view.name!r}",
        )

    def _prepare_plans_to(self, view: View) -> None:
        """On a large roadmap, compute the shortest-path tree to a new view in a background
        thread (from a snapshot; about a second at 1e6 vertices), so that the first return
        to it plans in milliseconds and the control loop never waits for a full search."""
        if self.roadmap.n_vertices < self.config.background_plan_vertices:
            return  # a first plan is fast enough on a small roadmap
        job = self.roadmap.tree_job(view, approach=True, isolate=self.config.plan_in_process)

        def run() -> None:
            tree = job()
            self._submit(lambda: self.roadmap.install_tree(view, tree))

        threading.Thread(target=run, name="icenav-plan-prepare", daemon=True).start()

    def _start_goto(self, name: str) -> None:
        try:
            view = self.views.get(name)
        except IcenavError as exc:
            self._message = str(exc)
            return
        # vertex budget (the soak, docs/safety.md): out of recorded territory, record the stretch
        # travelled since the roadmap was left, so the return can start from here
        self.roadmap.anchor()
        if self.roadmap.n_vertices >= self.config.background_plan_vertices:
            # a large roadmap: the search runs in a thread on a snapshot while the robot
            # holds; the control loop never waits for it
            self._selected_view = name
            self.start_task(_PlanningTask(self, view))
            return
        try:
            path = self.roadmap.plan(self._q, view, approach=True)
        except (PlanningError, InvalidValueError) as exc:
            self._message = f"cannot go to {name!r}: {exc}"
            return
        self._selected_view = name
        self.start_task(self._goto_task(view, path))

    def _start_spin(self) -> None:
        """The image plane turns 360 deg about the catheter axis while the model tip stays
        put (paper Sec. IV: phi1 = a cos t, phi2 = a sin t, phi3 = -t from an AP bend),
        mapped to motor states through the compensation when it is on."""
        g = self.config.geometry
        q_model = self._to_model(self._q)
        try:
            spin = spin_trajectory(q_model, 360, include_end=True, geometry=g)
        except IcenavError as exc:
            self._message = f"cannot spin from here: {exc}"
            return
        lim = g.joint_limits
        pose_source = None
        registration = getattr(getattr(self.tracker, "config", None), "tracker2base", None)
        if self.config.spin_feedback and self.tracker is not None and registration is not None:
            tracker = self.tracker

            def pose_source() -> tuple[float, Array | None]:
                try:
                    return tracked_tip2base(tracker)
                except IcenavError:  # the tracker is not in the safety path: hold the loop
                    return self._time, None

        task = SpinTask(
            spin.q_model,
            self._to_motor,
            np.asarray(self.config.max_velocity),
            lim,
            pose_source=pose_source,
            geometry=g,
            hold_measured=True,
        )
        self.start_task(task)

    def _start_calibration(self, kind: CalibrationKind) -> None:
        """Dense 10 deg raster (19 x 19 = 361 points over +-90 deg) or the simplified
        5-point calibration (centre, +-90 deg AP, +-90 deg RL), then build the elasticity
        map F in a background thread and switch the compensation on when it is ready; or
        ``dense+hysteresis``: :func:`icenav.calibration.catheter.catheter_plan` (the raster,
        hysteresis sweeps, roll and knob circles, 2,345 states) and the per-tendon
        compensation (:class:`icenav.compensation.tendon_map.TendonKnobMap`)."""
        if self.tracker is None:
            self._message = "calibration needs a tracker"
            return
        g = self.config.geometry
        if kind == "dense+hysteresis":
            self._start_catheter_calibration()
            return
        if kind == "dense":
            points = raster_grid(math.radians(10.0), g.knob_limit)
        elif kind == "five_point":
            knobs, _ = five_point_targets(g)
            points = np.zeros((5, 4))
            points[:, :2] = knobs
        else:
            self._message = (
                f"unknown calibration {kind!r}: use 'dense', 'five_point' or 'dense+hysteresis'"
            )
            return
        points[:, 2:] = self._q[2:]  # calibrate at the current roll and translation

        def on_samples(q: Array, t: Array, skipped: int) -> None:
            self._message = (
                f"calibration ({kind}): {len(q)} samples"
                + (f", {skipped} skipped (tracker MISSING)" if skipped else "")
                + "; building the compensation map"
            )
            self._fit_in_background(self._build_map, kind, q, t)

        task = CalibrationTask(
            points,
            lambda: self._measure_tip(4),
            on_samples,
            max_velocity=np.asarray(self.config.max_velocity),
            label=f"calibration ({kind}, {len(points)} points)",
        )
        self.start_task(task)

    def _start_catheter_calibration(self) -> None:
        """The full calibration of our compensation as a :class:`PlanTask` (the plan goes
        through zeros and ends there)."""
        from icenav.calibration.catheter import catheter_plan

        cplan = catheter_plan(geometry=self.config.geometry)

        def on_done(rec: Recording) -> None:
            missing = int(np.sum((rec.plan.n_average > 0) & ~rec.measured))
            self._message = (
                f"calibration (dense+hysteresis): {rec.plan.n} states"
                + (f", {missing} not tracked" if missing else "")
                + "; fitting the compensation (about 20 s)"
            )
            self._fit_in_background(self._build_tendon_map, cplan, rec)

        self.start_task(
            PlanTask(
                cplan.plan,
                self._measure_tip,
                on_done,
                max_velocity=np.asarray(self.config.max_velocity),
                label=f"calibration (dense+hysteresis, {cplan.plan.n} states)",
                settle_s=self.config.plan_settle_s,
                ramp_s=0.1,  # most moves are 1.5-3 deg: short ramps (5 rad/s^2 at 0.5 rad/s)
            )
        )

    def _measure_tip(self, n_average: int) -> Array | None:
        """The tracked tip pose (4, 4) averaged over ``n_average`` samples, None if MISSING."""
        pose = self.tracker.measure_tip2base(n_average=n_average)
        return None if pose is None else np.asarray(pose, dtype=np.float64)

    def _fit_in_background(self, fit: Callable[..., None], *args: Any) -> None:
        """Run a calibration's fit in a thread (it installs its result through a request);
        when the controller is stepped by hand there is no loop to poll, so wait for it."""
        thread = threading.Thread(target=fit, args=args, name="icenav-calibration", daemon=True)
        thread.start()
        if self._thread is None:
            thread.join()

    def _build_tendon_map(self, cplan: Any, rec: Recording) -> None:
        """Fit the per-tendon compensation (background thread); install it at the next
        cycle, relaxed where the robot is then."""
        from icenav.calibration.catheter import fit_catheter

        try:
            cal = fit_catheter(cplan, rec, geometry=self.config.geometry)
        except IcenavError as exc:
            text = f"calibration failed: {exc}"
            self._submit(lambda: setattr(self, "_message", text))
            return

        def install() -> None:
            self.compensation = cal.knob_map(self._q_cmd, self.config.geometry)
            self.compensation_enabled = True
            self.calibration = cal.dense
            self._message = "calibration (dense+hysteresis) done: compensation on"
            self._record(
                "calibration", {"kind": "dense+hysteresis", "n_samples": cal.dense.n_samples}
            )

        self._submit(install)

    def _build_map(self, kind: str, q: Array, t: Array) -> None:
        """Build F from the samples (background thread); install it at the next cycle."""
        try:
            cal = CalibrationSet(q_motor=q, tip2base=t, method=kind)
            emap = ElasticityMap.build(cal, self.config.geometry)
        except IcenavError as exc:
            text = f"calibration failed: {exc}"
            self._submit(lambda: setattr(self, "_message", text))
            return

        def install() -> None:
            self.compensation = emap
            self.compensation_enabled = True
            self.calibration = cal
            self._message = f"calibration ({kind}) done: compensation on"
            self._record("calibration", {"kind": kind, "n_samples": len(q)})

        self._submit(install)

    # --- publishing -----------------------------------------------------------------------

    def _record(self, event: str, payload: dict[str, Any]) -> bool | Literal["pending"]:
        """Hand ``event`` to the recorder; False (and a message) when it failed; "pending"
        when the recorder writes on its own thread and will call ``payload["on_durable"]``
        (see :meth:`_save_view`)."""
        if self._recorder is None:
            return True
        try:
            result = self._recorder(event, payload)
        except IcenavError as exc:
            self._message = f"could not record {event}: {exc}"
            return False
        return "pending" if result == "pending" else True

    def _operator_message(self) -> str:
        """The latest message; in FAULT / ESTOP the cause stays in front until reset, and a
        view that is not on disk stays in front until a later view is."""
        message = self._message
        alarm = self._view_alarm
        if alarm is not None and alarm not in message:
            message = f"{alarm} | {message}"
        fault = self._fault_message
        if self._mode not in (Mode.FAULT, Mode.ESTOP) or not fault or self._message == fault:
            return message
        return f"{fault} (then: {message})"

    def _make_state(self) -> ControllerState:
        g = self.config.geometry
        q_model = self._to_model(self._q)
        tip_model = forward(q_model, g, check=False)
        bb_model = backbone(
            np.clip(q_model, g.joint_limits[:, 0], g.joint_limits[:, 1]),
            g,
            self.config.backbone_points,
        ).points_in_base
        tip_true = bb_true = None
        if self._truth is not None:
            tip_true, bb_true = self._truth()
        sensor = None
        tracker_status = "none"
        if self.tracker is not None:
            try:
                frame = self.tracker.get_frame()
            except IcenavError as exc:  # reliability: the tracker is not in the control path
                frame = None
                tracker_status = "ERROR"
                self._message = f"tracker error: {exc}"
            if frame is not None:
                tracker_status = frame.status.name
                registration = getattr(getattr(self.tracker, "config", None), "tracker2base", None)
                if frame.sensor2tracker is not None and registration is not None:
                    sensor = registration @ frame.sensor2tracker
        task = self._task
        return ControllerState(
            time=self._time,
            cycle=self._cycle,
            mode=self._mode,
            robot_status=self.robot.status,
            q_motor=self._q.copy(),
            q_model=q_model,
            tip2base_model=tip_model,
            tip2base_true=tip_true,
            backbone_model=bb_model,
            backbone_true=bb_true,
            sensor2base=sensor,
            tracker_status=tracker_status,
            message=self._operator_message(),
            progress=None if task is None else task.progress,
            progress_label="" if task is None else task.label,
            n_vertices=self.roadmap.n_vertices,
            n_edges=self.roadmap.n_edges,
            views=tuple(
                ViewSummary(v.name, v.q, v.created_s, v.thumbnail is not None) for v in self.views
            ),
            compensation_enabled=self.compensation_enabled,
            control_owner=self._owner,
        )

    def _publish(self) -> None:
        state = self._make_state()
        self._state = state
        if self._image_thread is None and self._time >= self._next_image_t:
            # stepped by hand (simulation, tests): render inline at the image rate
            self._next_image_t = self._time + 1.0 / self.config.image_rate_hz
            self.render_image()
        for cb in list(self._listeners):
            cb(state)

    def render_image(self) -> ImageFrame | None:
        """Render the ICE image of the latest state's true pose (None without an imager)."""
        state = self._state
        if self._imager is None or state.tip2base_true is None:
            return None
        frame = ImageFrame(
            pixels=self._imager(state.tip2base_true, state.time),
            timestamp=state.time,
            ijk2tip=self._ijk2tip,
        )
        self._image = frame
        return frame

    def set_recorder(self, recorder: Callable[[str, dict[str, Any]], object] | None) -> None:
        """Install the persistence callback (see the class docstring)."""
        self._recorder = recorder

    # --- garbage-collection policy (the soak, docs/safety.md) ---------------------------------
    # A full (generation 2) collection traverses every container object of the process; on
    # a long procedure it stalled one control cycle for up to seconds. Policy: after
    # start-up, collect once and freeze what exists (never traversed again), switch the
    # automatic full collection off, and run a full collection only between cycles, in a
    # cycle's idle time, at most every ``gc_full_every_s``. Young generations stay
    # automatic: they only traverse objects allocated since the last collection.

    def settle_gc(self) -> None:
        """Apply the policy above (process-wide): collect, ``gc.freeze()``, and no automatic
        full collection, until :meth:`release_gc` (which :meth:`shutdown` calls) of the
        last controller that settled. :meth:`start` calls it; a caller stepping the loop by
        hand (the soak) may too, then calls :meth:`collect_garbage_if_due` between cycles."""
        if self._next_full_gc is not None:
            return
        with _GC_LOCK:
            if not _GC_USERS:
                gc.collect()
                gc.freeze()
                t0, t1, t2 = gc.get_threshold()
                _GC_SAVED[:] = [t2]
                gc.set_threshold(t0, t1, _GC_NO_AUTOMATIC_FULL)
            _GC_USERS.add(id(self))
        self._next_full_gc = self._time + self.config.gc_full_every_s

    def release_gc(self) -> None:
        """Undo :meth:`settle_gc` for this controller (the default policy is back once no
        controller holds it)."""
        if self._next_full_gc is None:
            return
        self._next_full_gc = None
        with _GC_LOCK:
            _GC_USERS.discard(id(self))
            if not _GC_USERS and _GC_SAVED:
                t0, t1, _ = gc.get_threshold()
                gc.set_threshold(t0, t1, _GC_SAVED.pop())
                gc.unfreeze()

    def collect_garbage_if_due(self) -> bool:
        """Between cycles: run a full collection if ``gc_full_every_s`` of controller time
        has passed since the last one (after :meth:`settle_gc`); return whether it ran."""
        if self._next_full_gc is None or self._time < self._next_full_gc:
            return False
        self._next_full_gc = self._time + self.config.gc_full_every_s
        gc.collect()
        return True

    # --- running in real time -------------------------------------------------------------

    def start(self) -> None:
        """Run cycles in a background thread at ``rate_hz`` until :meth:`shutdown`; images
        (when an imager is configured) are rendered in a thread of their own, so a slow
        renderer never delays a control cycle."""
        if self._thread is not None:
            return
        self.settle_gc()
        if self.config.plan_in_process:  # spawn the planning worker now, not at the first plan
            threading.Thread(target=warm_up_planner, name="icenav-plan-warmup", daemon=True).start()
        self._running.set()
        self._thread = threading.Thread(target=self._loop, name="icenav-control", daemon=True)
        self._thread.start()
        if self._imager is not None:
            self._image_thread = threading.Thread(
                target=self._image_loop, name="icenav-imager", daemon=True
            )
            self._image_thread.start()

    def _image_loop(self) -> None:
        period = 1.0 / self.config.image_rate_hz
        while self._running.is_set():
            t0 = time.perf_counter()
            try:
                self.render_image()
            except Exception as exc:  # noqa: BLE001 - the imager must not kill the process
                self._message = f"imaging stopped: {exc}"
                return
            time.sleep(max(0.0, period - (time.perf_counter() - t0)))

    def _loop(self) -> None:
        period = self.config.dt
        next_t = time.perf_counter()
        while self._running.is_set():
            self.cycle_starts.append(time.perf_counter())
            try:
                self.step()
            except IcenavError as exc:  # never let the loop die silently
                self.estop("controller")
                self._message = f"controller error: {exc}; e-stopped"
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0.5 * period and self.collect_garbage_if_due():  # GC policy (above)
                delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.perf_counter()

    def shutdown(self) -> None:
        """Stop the loop thread (the robot holds its position)."""
        self._running.clear()
        for thread in (self._thread, self._image_thread):
            if thread is not None:
                thread.join(timeout=5.0)
        self._thread = None
        self._image_thread = None
        self.release_gc()

    def run_cycles(self, n: int) -> ControllerState:
        """Run ``n`` cycles as fast as possible (simulation, tests)."""
        for _ in range(int(n)):
            self.step()
        return self._state

    def run_until(
        self, predicate: Callable[[ControllerState], bool], max_cycles: int
    ) -> ControllerState:
        """Run cycles until ``predicate(state)`` or ``max_cycles`` (simulation, tests)."""
        for _ in range(int(max_cycles)):
            state = self.step()
            if predicate(state):
                return state
        return self._state

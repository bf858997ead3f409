"""The control loop: commands in, set-points out, one short cycle over small parts.

The :class:`Controller` owns time and state. :meth:`Controller.step` runs one control cycle;
:meth:`Controller.start` runs cycles in a thread at ``rate_hz`` (default 100 Hz), with a
supervisor that e-stops the robot if the loop stops advancing. Adapters (console, gamepad,
OpenIGTLink, scripts) send commands (:mod:`icenav.control.commands`) through
:meth:`Controller.submit` or the thin calls that build them (``jog``, ``goto_view``, ...).

One cycle (:meth:`Controller.step`):

1. apply the results of background jobs (a plan's tree, a calibration's fit);
2. decide the queued commands in order: authorization (:mod:`.authorization`), then the
   mode machine (:mod:`.modes`; a command that moves is refused in FAULT / ESTOP), then the
   command's handler (:mod:`.handlers`); each outcome goes to its ticket and the event log;
3. read the robot; a FAULT or ESTOP status halts the mode machine;
4. read the gamepad (:mod:`.teleop`): its buttons and sticks become commands, decided now;
5. in FAULT / ESTOP drop any motion; otherwise ask the running task (:mod:`.tasks`) or the
   held jog for the next set-point, limit it (speed, joint limits; a limit hit is reported)
   and send it through the guard (:mod:`.guard`), which never sends after an e-stop;
6. record the measured state into the roadmap (not during a calibration) and the store;
7. publish a snapshot (:mod:`.publish`).

Any exception in steps 1-6 ends in FAULT with the robot quick-stopped and the exception's
text in the message; the loop goes on and Reset works. E-STOP acts at once from the
caller's thread (:meth:`Controller.estop`).
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.control.calibration_runner import CalibrationPreview, preview
from icenav.control.calls import CommandCalls
from icenav.control.commands import (
    Command,
    CommandResult,
    Disconnect,
    EStop,
    Jog,
    Outcome,
    ReleaseControl,
    Source,
    TakeControl,
    Ticket,
)
from icenav.control.config import ControllerConfig
from icenav.control.guard import RobotGuard
from icenav.control.handlers import Handlers
from icenav.control.modes import HALTED, TRANSITIONS, Mode, ModeChange, ModeMachine, Via
from icenav.control.publish import Publisher
from icenav.control.runtime import GcPolicy, ImagingThread, Jobs, LoopThread, Supervisor
from icenav.control.sensing import cycle_pose, tip_pose_now
from icenav.control.state import CalibrationKind, ControllerState, ImageFrame, KnobMap
from icenav.control.tasks import Done, PathTask, Running, Task, TaskStatus
from icenav.control.teleop import GamepadReader, InputSource, JogHold, JoystickMapping, jog_setpoint
from icenav.devices.robot import JointState, RobotBackend, RobotStatus
from icenav.devices.tracker import PoseSampleBuffer
from icenav.errors import IcenavError
from icenav.recovery.drift import Phases
from icenav.recovery.force import ForceRecord, ForceSensor
from icenav.recovery.roadmap import Roadmap, warm_up_planner
from icenav.recovery.views import ViewLibrary

__all__ = [
    "Controller",
    "ControllerConfig",
    "KnobMap",
    "PathTask",
    "TRANSITIONS",
]

logger = logging.getLogger("icenav.control")

SUPERVISOR = Source("script", "supervisor")
"""The source of the supervisor's e-stop."""

_OPERATOR_MODES = (Mode.KNOB, Mode.TIP)
"""Modes in which the operator drives: their contact forces are the returns' reference."""
_UNBUFFERED_MODES = (Mode.CALIBRATING, Mode.SPINNING)
"""Modes whose tracker samples no refinement averages (the loop skips the sample buffer)."""


class Controller(CommandCalls):
    """The control loop on a robot backend (simulated or real); see the module docstring.

    Parameters
    ----------
    robot : RobotBackend
        The robot; enabled by the controller at start.
    config : ControllerConfig
        Rates, limits, geometry.
    roadmap : Roadmap, optional
        Where every travelled state is recorded (a new one by default).
    views : ViewLibrary, optional
        Saved views (a new, empty one by default).
    input_source : InputSource, optional
        The gamepad (``icenav.devices.gamepad``). None: on-screen jog only.
    mapping : JoystickMapping
        Gamepad mapping.
    compensation : KnobMap, optional
        Model <-> motor knob map used by tip mode and the spin (identity when None).
    truth : callable, optional
        ``truth() -> (tip2base (4,4), backbone (n,3))`` of the twin (None on hardware).
    tracker : object, optional
        A tracker (``get_frame()``, ``measure_tip2base(n_average)``, ``registration``);
        the sensor pose is published in the base frame.
    imager : callable, optional
        ``imager(tip2base_true, t) -> (H, W) uint8`` image of the current pose.
    image_ijk2tip : ndarray, shape (4, 4), optional
        Maps a pixel (i = column, j = row, k = 0) of the image into the tip frame (mm).
    recorder : callable, optional
        ``recorder(event, payload)`` for persistence (``icenav.persistence.recorder``):
        events "state", "view_saved", "view_renamed", "view_deleted", "event", "command".
    clock : callable
        Time source (s) for timestamps of jogs and the gamepad watchdog.
    force_sensor : ForceSensor, optional
        The robot's contact-force channel (:mod:`icenav.recovery.force`). None: no force
        is recorded and returns are not force-checked (the state says so).
    forces : ForceRecord, optional
        The operator's recorded forces (a resumed session's); a new one by default.
    respiration : RespiratoryMonitor, optional
        The respiratory belt / ventilator signal; None without one.
    cardiac_phase : callable t (s) -> [0, 1), optional
        The ECG's cardiac phase (0 at the R wave, the ``clock``'s time); None without one.
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
        force_sensor: ForceSensor | None = None,
        forces: ForceRecord | None = None,
        respiration: Any = None,
        cardiac_phase: Callable[[float], float] | None = None,
    ) -> None:
        from icenav.control.authorization import Authorizer

        self.robot = robot
        self.config = config or ControllerConfig()
        self.roadmap = roadmap if roadmap is not None else Roadmap()
        self.views = views if views is not None else ViewLibrary()
        self.input_source = input_source
        self.mapping = mapping or JoystickMapping()
        self.compensation = compensation
        self.compensation_enabled = compensation is not None
        self.calibration: Any = None
        """The calibration set behind the installed compensation (None: none made here)."""
        self.tracker = tracker
        self.force_sensor = force_sensor
        """The contact-force channel (None: no force check)."""
        self.forces = forces if forces is not None else ForceRecord()
        """The operator's contact forces per vertex and per tip pose (Eqs. F1, F2)."""
        self.pose_buffer: PoseSampleBuffer | None = (
            PoseSampleBuffer() if tracker is not None else None
        )
        """The tracked tip poses of the last seconds with their times (the control loop
        fills it from the tracker's newest samples), for :meth:`cycle_pose`."""
        self.respiration = respiration
        self.cardiac_phase = cardiac_phase
        self._still_since = 0.0
        self._recorder = recorder
        self._clock = clock
        self._outbox: deque[tuple[str, dict[str, Any]]] = deque()
        self.machine = ModeMachine(on_change=self._on_mode_change)
        """The mode machine (the only writer of the mode)."""
        self.authorization = Authorizer()
        """Control ownership and the authorization of every command."""
        self.guard = RobotGuard(robot, self.machine)
        self.jobs = Jobs()
        """Background work (plans, fits, tracker readings), applied on the loop."""
        self._seq = itertools.count()
        self._dt = self.config.dt
        self._queue: deque[tuple[Ticket, float]] = deque()
        self._queue_lock = threading.Lock()
        self._pad = (
            None
            if input_source is None
            else GamepadReader(input_source, self.mapping, self.config.watchdog_s, clock)
        )
        self._message = ""
        self._halt_text = ""
        self._time = 0.0
        self._cycle = 0
        self._task: Task | None = None
        self._task_ticket: Ticket | None = None
        self._jog: JogHold | None = None
        self._jog_logged: dict[str, tuple[Outcome, str]] = {}
        self.selected_view: str | None = None
        """The view the gamepad's Go to view button returns to (the last saved or visited)."""
        self.cycle_times: deque[float] = deque(maxlen=100_000)
        """Compute time of the latest cycles (s), for the benchmark."""
        self._gc = GcPolicy(self.config.gc_full_every_s)
        self._loop = LoopThread(self.step, self.config.dt, self._idle)
        self._supervisor = Supervisor(
            lambda: self._loop.heartbeat, self._on_stall, self.config.stall_estop_s
        )
        self.publisher = Publisher(self, truth, imager, image_ijk2tip)
        self._imaging: ImagingThread | None = None
        if imager is not None:
            self._imaging = ImagingThread(
                self.publisher.render_image, self.config.image_rate_hz, self.publisher.image_error
            )
        self.handlers = Handlers(self)
        if self.robot.status is RobotStatus.DISABLED:
            self.robot.enable()
        q0 = self.robot.read_state().q
        self._q_cmd = np.array(q0, dtype=np.float64)
        self._q = np.array(q0, dtype=np.float64)
        self._q_last = self._q.copy()
        self._driven_last = False
        """Whether the last motion was the operator's (KNOB / TIP, or IDLE after it)."""
        self.forces.keep_rest_if_at(self._q)  # a restored rest pose: only if nothing moved
        self.roadmap.add(self._q)
        self._state = self.publisher.make_state()

    # --- submitting commands (any thread) -----------------------------------------------

    def submit(self, command: Command) -> Ticket:
        """Submit a command; decided by the loop at its next cycle, in submission order
        (E-STOP, take and release control are decided at once, on the caller's thread)."""
        if not isinstance(command, Command):
            raise IcenavError(f"submit takes a Command, got {type(command).__name__}")
        if isinstance(command, EStop):
            return self._estop_now(command, f"EMERGENCY STOP by {command.source.client}")
        with self._queue_lock:
            ticket = Ticket(next(self._seq), command)
            if isinstance(command, TakeControl | ReleaseControl | Disconnect):
                self._decide_ownership(ticket)
                if not isinstance(command, Disconnect):
                    return ticket
            self._queue.append((ticket, self._clock()))
        return ticket

    def _decide_ownership(self, ticket: Ticket) -> None:
        """Take / release control at once (queue lock held: ordered with the queue)."""
        cmd = ticket.command
        auth = self.authorization
        if isinstance(cmd, TakeControl):
            reason = auth.take(cmd.source)
        elif isinstance(cmd, ReleaseControl):
            reason = auth.release(cmd.source, ticket.seq)
            if reason is None and self._jog is not None and self._jog.client == cmd.source.client:
                self._jog = None
        else:
            auth.disconnect(cmd.source, ticket.seq)
            return  # the loop stops what the client started, then the ticket is done
        if reason is None:
            self.settle(ticket, Outcome.DONE)
        else:
            self.settle(ticket, Outcome.REFUSED, reason)

    def _estop_now(self, command: Command, cause: str) -> Ticket:
        with self._queue_lock:
            ticket = Ticket(next(self._seq), command)
        cause = f"{cause}: reset to continue"
        problems = self.guard.estop(cause, ticket.seq)
        self._message = cause if not problems else f"{cause} ({problems})"
        self.settle(ticket, Outcome.DONE, problems)
        return ticket

    def settle(self, ticket: Ticket, outcome: Outcome, reason: str = "") -> None:
        """Record an outcome of ``ticket`` (any thread) and queue it for the event log."""
        result = CommandResult(ticket.seq, ticket.command, outcome, reason, self._time)
        if ticket.resolve(result):
            self._log_result(result)

    def _log_result(self, result: CommandResult) -> None:
        cmd = result.command
        if isinstance(cmd, Jog):  # a stream of jogs: logged when its outcome changes
            key = (result.outcome, result.reason)
            if self._jog_logged.get(cmd.source.client) == key:
                return
            self._jog_logged[cmd.source.client] = key
            if len(self._jog_logged) > 256:
                self._jog_logged.clear()
        self._outbox.append(
            (
                "command",
                {
                    "seq": result.seq,
                    "command": cmd.describe(),
                    "kind": cmd.source.kind,
                    "client": cmd.source.client,
                    "outcome": result.outcome.value,
                    "reason": result.reason,
                },
            )
        )

    def set_view_only(self, client: str, view_only: bool) -> None:
        self.authorization.set_view_only(client, view_only)

    def preview_calibration(self, kind: CalibrationKind) -> CalibrationPreview:
        """What calibration ``kind`` would do from here, and about how long it takes."""
        from icenav.calibration.procedures import make_procedure

        cfg = self.config
        return preview(
            make_procedure(kind, geometry=cfg.geometry),
            self._q_cmd.copy(),
            np.asarray(cfg.max_velocity),
            settle_s=cfg.plan_settle_s,
            ramp_s=cfg.calibration_ramp_s,
            dt=cfg.dt,
            geometry=cfg.geometry,
        )

    def snapshot(self) -> ControllerState:
        return self._state

    def latest_image(self) -> ImageFrame | None:
        return self.publisher.image

    def view_image(self, name: str) -> ImageFrame | None:
        return self.publisher.view_images.get(name)

    def add_listener(self, callback: Callable[[ControllerState], None]) -> None:
        self.publisher.listeners.append(callback)

    def render_image(self) -> ImageFrame | None:
        """Render the ICE image of the latest state's true pose (None without an imager)."""
        return self.publisher.render_image()

    def set_recorder(self, recorder: Callable[[str, dict[str, Any]], object] | None) -> None:
        """Install the persistence callback (see the class docstring)."""
        self._recorder = recorder

    @property
    def recorder(self) -> Callable[[str, dict[str, Any]], object] | None:
        """The persistence callback."""
        return self._recorder

    # --- the cycle ----------------------------------------------------------------------

    @property
    def mode(self) -> Mode:
        """Current mode."""
        return self.machine.mode

    @property
    def time(self) -> float:
        """Controller time (s): cycles x period."""
        return self._time

    @property
    def cycle(self) -> int:
        """Cycles run so far."""
        return self._cycle

    @property
    def q_command(self) -> Array:
        """The latest motor set-point (4,) (rad, rad, rad, mm); a copy."""
        return self._q_cmd.copy()

    @property
    def task(self) -> Task | None:
        """The running automatic task (None: none)."""
        return self._task

    def step(self) -> ControllerState:
        """Run one control cycle (see the module docstring) and return the new state."""
        t_start = time.perf_counter()
        dt = self._dt
        self._time += dt
        self._cycle += 1
        try:
            self.jobs.apply_finished()
            self._decide_queued()
            self._follow_robot(self.robot.read_state())
            if self._pad is not None:
                self._read_pad()
            if self.machine.halted:
                self._drop_motion(f"{self.machine.mode.name}: {self.machine.cause}")
            else:
                q_next = self._next_setpoint(dt)
                if q_next is not None:
                    self.handlers.send(q_next, dt)
            if self.machine.mode is not Mode.CALIBRATING:  # the roadmap: what was driven
                self.roadmap.add(self._q, check=False)
            now = self._clock()
            moved = not np.array_equal(self._q, self._q_last)
            if moved:
                self._still_since, self._q_last = now, self._q.copy()
            mode = self.machine.mode
            # the robot settling in IDLE after the operator's Stop is still their drive
            driving = mode in _OPERATOR_MODES or (mode is Mode.IDLE and self._driven_last)
            if moved:
                self._driven_last = driving
            operator = self.force_sensor is not None and driving
            buffered = self.pose_buffer is not None and mode not in _UNBUFFERED_MODES
            tip = self.tip_pose_now() if operator or buffered else None
            if buffered:
                self.pose_buffer.push(now, tip)  # type: ignore[union-attr]
            if moved:  # where the operator left the tip (Eq. F5: a tracker is enough)
                self.forces.note_motion(tip, driving, self._q, now)
            elif tip is not None and self.forces.wants_still_readings(now):
                self.forces.note_still(now, tip, self.signals)  # Eq. (F5)'s reference
            if operator:
                self._record_force(tip)
            self.record("state", {"q": self._q, "t": self._time})
        except Exception as exc:  # the loop never dies: FAULT, robot quick-stopped
            self._halt(exc)
        self._flush_log()
        if self._cycle % self.config.publish_every == 0:
            try:
                self.publisher.publish()
            except Exception as exc:
                self._halt(exc)
                self.publisher.publish_minimal()
        self.cycle_times.append(time.perf_counter() - t_start)
        return self._state

    def _record_force(self, tip2base: Array | None) -> None:
        """The operator's contact force at the vertex just recorded and at the tracked tip
        pose (the newest sample, never waited for): the reference of a later return."""
        try:
            f = self.force_sensor.contact_force_n()  # type: ignore[union-attr]
        except Exception as exc:  # the channel failed: nothing recorded, the operator told
            self._message = f"force channel error: {exc}"
            return
        self.forces.record(self.roadmap.current_vertex, f, tip2base)

    def still_em_pose(self) -> Array | None:
        """The cycle-averaged EM pose (4, 4) (mm) of the last ``refine_window_s`` when the
        catheter has been still that long and the tracker's buffer spans it; else None."""
        window = self.config.refine_window_s
        buf = self.pose_buffer
        if buf is None or self._clock() - self._still_since < window:
            return None
        if buf.span_s() + 2.0 * buf.min_dt < window:  # the loop has not buffered that long
            return None
        pose: Array | None = self.cycle_pose(window).measure_tip2base()
        return pose

    def cycle_pose(self, window_s: float = 9.0, rate_hz: float = 10.0) -> Any:
        """The refinement's EM pose sensor over the loop's buffer (:func:`sensing.cycle_pose`)."""
        return cycle_pose(self.pose_buffer, self.respiration, self.cardiac_phase, window_s, rate_hz)

    def now(self) -> float:
        """The loop's clock (s)."""
        return float(self._clock())

    def signals(self, t: float) -> Phases:
        """The respiratory signal and the cardiac phase in [0, 1) at ``t`` (s), each None
        without its channel (Eq. F5's phase match)."""
        resp = None
        if self.respiration is not None:
            resp = float(np.asarray(self.respiration.signal(np.array([t])), np.float64)[0])
        phase = None if self.cardiac_phase is None else float(self.cardiac_phase(t))
        return resp, phase

    def tip_pose_now(self) -> Array | None:
        """(4, 4) the tracked tip pose now (mm), never waited for (:func:`sensing.tip_pose_now`)."""
        return tip_pose_now(self.tracker)

    def _decide_queued(self) -> None:
        while self._queue:
            with self._queue_lock:
                if not self._queue:
                    return
                ticket, at = self._queue.popleft()
            self.decide(ticket, at)

    def decide(self, ticket: Ticket, at: float) -> None:
        """Decide one command (loop thread): authorization, the mode, its handler."""
        cmd = ticket.command
        reason = self.authorization.authorize(cmd, ticket.seq)
        if reason is None and cmd.moves and self.machine.halted:
            reason = f"the controller is in {self.machine.mode.name}: reset first"
        if reason is not None:
            self._message = reason
            self.settle(ticket, Outcome.REFUSED, reason)
            return
        self.handlers.run(ticket, at)

    def _follow_robot(self, js: JointState) -> None:
        self._q = np.array(js.q, dtype=np.float64)
        if js.status not in (RobotStatus.FAULT, RobotStatus.ESTOP) or self.machine.halted:
            return
        text = f"robot {js.status.value}: {js.message or 'stopped'}; reset to continue"
        if js.status is RobotStatus.ESTOP:
            self.machine.estop(text, next(self._seq))
        else:
            self.machine.fault(text)
        self._message = text
        self._outbox.append(("event", {"text": text}))

    def _read_pad(self) -> None:
        assert self._pad is not None
        reading = self._pad.read(
            self.machine.mode, self.authorization.holder, len(self.views), self.selected_view
        )
        if reading.message:
            self._message = reading.message
        if not reading.active and self._jog is not None and self._jog.client == "gamepad":
            self._jog = None  # the sticks let go (or the pad went stale): stop at once
        for cmd in reading.commands:
            ticket = (
                self.submit(cmd) if isinstance(cmd, EStop | TakeControl | ReleaseControl) else None
            )
            if ticket is None:
                with self._queue_lock:
                    ticket = Ticket(next(self._seq), cmd)
                if isinstance(cmd, Disconnect):
                    self.authorization.disconnect(cmd.source, ticket.seq)
                self.decide(ticket, self._clock())

    def _next_setpoint(self, dt: float) -> Array | None:
        jog = self._jog
        if jog is not None and self._clock() - jog.at > self.config.watchdog_s:
            self._jog = jog = None
        if self._task is not None:
            status = self._task.step(self._q, dt)
            if isinstance(status, Running):
                return status.q
            self.end_task(status)
            return None
        if jog is None:
            return None  # no input: hold (nothing is commanded)
        return jog_setpoint(
            self.machine.mode,
            jog,
            self._q_cmd,
            dt,
            self.config.geometry,
            self.handlers.to_model,
            self.handlers.to_motor,
        )

    # --- tasks --------------------------------------------------------------------------

    def start_task(self, task: Task, ticket: Ticket | None = None) -> str | None:
        """Run an automatic task (call from the loop thread, or before the loop starts);
        None when it started, else why not. ``ticket`` ends with the task."""
        refused = self.machine.go(task.mode, Via.START)
        if refused is not None:
            return f"cannot start {task.label}: {refused}"
        self.abort_task("replaced", keep_mode=True)
        self._task = task
        self._task_ticket = ticket
        self._jog = None
        self._message = f"{task.label}: started"
        return None

    def end_task(self, status: TaskStatus) -> None:
        """The running task returned Done or Failed: back to IDLE, the ticket settled."""
        task, ticket = self._task, self._task_ticket
        assert task is not None and not isinstance(status, Running)
        self._task = self._task_ticket = None
        self.machine.go(Mode.IDLE, Via.END)
        if task.mode is Mode.CALIBRATING:
            self.roadmap.break_trace()  # the calibration's motions are not the operator's
        if isinstance(status, Done):
            self._message = status.message or f"{task.label}: done"
            if ticket is not None and not self.handlers.finishes_later(task):
                self.settle(ticket, Outcome.DONE, self._message)
        else:
            self._message = status.reason
            if ticket is not None:
                self.settle(ticket, Outcome.FAILED, status.reason)
        self._outbox.append(("event", {"text": self._message}))

    def abort_task(self, why: str, *, keep_mode: bool = False, client: str | None = None) -> bool:
        """Stop the running task (if any, and if ``client`` is given only the one that
        client started): the robot holds, its ticket fails with ``why``. The mode goes to
        IDLE unless ``keep_mode``. Returns whether a task was aborted."""
        task, ticket = self._task, self._task_ticket
        if task is None:
            return False
        if client is not None and (ticket is None or ticket.command.source.client != client):
            return False
        self._task = self._task_ticket = None
        text = f"{task.label}: {why}"
        self._message = text
        self._outbox.append(("event", {"text": text}))
        if ticket is not None:
            self.settle(ticket, Outcome.FAILED, text)
        if task.mode is Mode.CALIBRATING:
            self.roadmap.break_trace()
        self._q_cmd = self._q.copy()
        self.guard.hold()
        if not keep_mode:
            self.machine.go(Mode.IDLE, Via.REQUEST)
        return True

    def _drop_motion(self, why: str) -> None:
        """In FAULT / ESTOP: no task, no jog, the set-point is where the robot is."""
        if self._task is not None:
            task, ticket = self._task, self._task_ticket
            self._task = self._task_ticket = None
            if ticket is not None:
                self.settle(ticket, Outcome.FAILED, f"{task.label}: {why}")
            if task.mode is Mode.CALIBRATING:
                self.roadmap.break_trace()
        self._jog = None
        self._q_cmd = self._q.copy()

    # --- faults -------------------------------------------------------------------------

    def _halt(self, exc: BaseException) -> None:
        """An exception in a cycle: FAULT, robot quick-stopped, the text in the message."""
        text = (
            f"controller error: {type(exc).__name__}: {exc}; robot quick-stopped, reset to continue"
        )
        problem = self.guard.halt(text)
        if problem:
            text = f"{text} ({problem})"
        self._message = text
        self._task = self._task_ticket = None
        self._jog = None
        self._q_cmd = self._q.copy()
        if text != self._halt_text:  # an exception that repeats every cycle is logged once
            self._halt_text = text
            logger.error("control cycle %d: %s", self._cycle, text, exc_info=exc)
            self._outbox.append(("event", {"text": text}))

    def _on_mode_change(self, change: ModeChange) -> None:
        self._outbox.append(("event", {"text": f"mode {change.new.value}"}))
        if change.new in HALTED:
            self._halt_text = ""

    def _on_stall(self, stalled_s: float) -> None:
        """The supervisor's e-stop (its own thread)."""
        cause = (
            f"control loop stalled for {stalled_s:.2f} s (limit {self.config.stall_estop_s:g} s): "
            "robot e-stopped by the supervisor"
        )
        logger.error(cause)
        self._estop_now(EStop(source=SUPERVISOR), cause)

    # --- persistence --------------------------------------------------------------------

    def record(self, event: str, payload: dict[str, Any]) -> bool | Literal["pending"]:
        """Hand ``event`` to the recorder (loop thread); False (and a message) when it
        failed; "pending" when the recorder writes on its own thread and will call
        ``payload["on_durable"]``."""
        if self._recorder is None:
            return True
        try:
            result = self._recorder(event, payload)
        except IcenavError as exc:
            self._message = f"could not record {event}: {exc}"
            return False
        return "pending" if result == "pending" else True

    def note(self, text: str) -> None:
        """An event for the session's log (any thread; written by the loop)."""
        self._outbox.append(("event", {"text": text}))

    def _flush_log(self) -> None:
        while self._outbox:
            event, payload = self._outbox.popleft()
            self.record(event, payload)

    # --- running in real time -----------------------------------------------------------

    def settle_gc(self) -> None:
        """Apply the GC policy (``icenav.control.runtime``); :meth:`start` calls it; a caller
        stepping the loop by hand (the soak) may too, then calls
        :meth:`collect_garbage_if_due` between cycles."""
        self._gc.settle(self._time)

    def release_gc(self) -> None:
        """Undo :meth:`settle_gc` for this controller."""
        self._gc.release()

    def collect_garbage_if_due(self) -> bool:
        """Between cycles: run a full collection if due; return whether it ran."""
        return self._gc.collect_if_due(self._time)

    def _idle(self) -> bool:
        return self.collect_garbage_if_due()

    @property
    def cycle_starts(self) -> deque[float]:
        """perf_counter() at the start of the latest real-time cycles (s), for jitter."""
        return self._loop.cycle_starts

    @property
    def running(self) -> bool:
        """True while the real-time loop runs."""
        return self._loop.running

    @property
    def heartbeat(self) -> int:
        """Real-time cycles finished so far (what the supervisor watches)."""
        return self._loop.heartbeat

    def start(self) -> None:
        """Run cycles in a background thread at ``rate_hz`` until :meth:`shutdown`, with the
        supervisor; images (with an imager) are rendered in a thread of their own."""
        if self._loop.running:
            return
        self.settle_gc()
        if self.config.plan_in_process:  # spawn the planning worker now, not at the first plan
            threading.Thread(target=warm_up_planner, name="icenav-plan-warmup", daemon=True).start()
        self.jobs.threaded = True
        self._loop.start()
        self._supervisor.start()
        if self._imaging is not None:
            self._imaging.start()

    def shutdown(self) -> None:
        """Stop the loop thread (the robot holds its position)."""
        self._supervisor.stop()
        self._loop.stop()
        if self._imaging is not None:
            self._imaging.stop()
        self.jobs.threaded = False
        self._flush_log()
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

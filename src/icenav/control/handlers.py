"""What each command does, once it is authorized (the loop thread calls these).

A handler either refuses its command (the reason goes to the ticket, the log and the message),
or accepts it: a command that completes at once is settled DONE in the same cycle; one that
starts a task is settled when the task ends (a calibration's when its fit is installed); a
saved view's when it is on disk. Also here: the command's path to the robot (speed and joint
limits, the compensation) and the calibration's fit and installation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from icenav._typing import Array
from icenav.calibration.procedure import CalibrationOutcome
from icenav.control.calibration_runner import CalibrationRunner, calibration_document, preview
from icenav.control.commands import (
    Calibrate,
    Command,
    DeleteView,
    Disconnect,
    Export,
    GoToView,
    Jog,
    Outcome,
    RefineView,
    RenameView,
    Reset,
    SaveView,
    SetCompensation,
    SetMode,
    Spin,
    Stop,
    Ticket,
)
from icenav.control.modes import TELEOP, Mode, Via
from icenav.control.spin import SpinTask, tracked_tip2base
from icenav.control.tasks import (
    MotionAdapter,
    PathTask,
    PlanningTask,
    Task,
    goto_view_task,
    refinement_task,
)
from icenav.control.teleop import JogHold
from icenav.errors import CommandRefusedError, IcenavError
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory
from icenav.recovery.views import View


def refine_stage_config(window_s: float) -> Any:
    """The pose stage of "refine view" on the cycle-averaged pose: the in-vivo settings
    measured in ``icenav eval recovery`` (:data:`icenav.refinement.presets.CYCLE_POSE_STAGE`),
    holding the estimator's window (``window_s``, s) before each measurement."""
    from icenav.refinement.presets import product_stage

    return product_stage(window_s)


if TYPE_CHECKING:
    from icenav.control.controller import Controller

__all__ = ["Handlers"]


@dataclass(eq=False)
class _CalibrationRun:
    """One calibration: its task, ticket, and the fit (installed once the task is over)."""

    runner: CalibrationRunner
    ticket: Ticket
    kind: str
    returned: bool = False
    fit: Future[CalibrationOutcome] | None = None


class Handlers:
    """The handlers of one controller's commands (see the module docstring)."""

    def __init__(self, ctrl: Controller) -> None:
        self._ctrl = ctrl
        self._table: dict[type[Command], Callable[[Ticket, float], None]] = {
            SetMode: self._set_mode,
            Jog: self._jog,
            GoToView: self._goto,
            SaveView: self._save_view,
            RefineView: self._refine,
            RenameView: self._rename_view,
            DeleteView: self._delete_view,
            Spin: self._spin,
            Calibrate: self._calibrate,
            SetCompensation: self._set_compensation,
            Stop: self._stop,
            Reset: self._reset,
            Disconnect: self._disconnect,
            Export: self._export,
        }
        self._calibrations: dict[int, _CalibrationRun] = {}
        lim = ctrl.config.geometry.joint_limits
        self._lo, self._hi = lim[:, 0].copy(), lim[:, 1].copy()
        self._vmax = np.asarray(ctrl.config.max_velocity, dtype=np.float64)

    def run(self, ticket: Ticket, at: float) -> None:
        """Run the handler of ``ticket``'s command (submitted at controller-clock ``at``)."""
        ctrl = self._ctrl
        handler = self._table.get(type(ticket.command))
        try:
            if handler is None:
                raise CommandRefusedError(f"{ticket.command.name} is not a command the loop runs")
            handler(ticket, at)
        except IcenavError as exc:
            ctrl._message = str(exc)  # noqa: SLF001
            ctrl.settle(ticket, Outcome.REFUSED, str(exc))
        except Exception as exc:  # the cycle ends in FAULT; the client still gets an answer
            ctrl.settle(ticket, Outcome.REFUSED, f"{type(exc).__name__}: {exc}")
            raise

    def _done(self, ticket: Ticket, text: str = "") -> None:
        self._ctrl.settle(ticket, Outcome.DONE, text)

    def _start(self, ticket: Ticket, task: Task) -> None:
        refused = self._ctrl.start_task(task, ticket)
        if refused is not None:
            raise CommandRefusedError(refused)
        self._ctrl.settle(ticket, Outcome.ACCEPTED)

    # --- modes and teleoperation --------------------------------------------------------

    def _set_mode(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        mode = ticket.command.mode  # type: ignore[attr-defined]
        if mode not in TELEOP:
            raise CommandRefusedError(
                f"mode {mode.value} is started by its own command, not by a switch"
            )
        ctrl.abort_task(f"switched to {mode.value}", keep_mode=True)
        ctrl._jog = None  # noqa: SLF001 - a held jog belongs to the mode it was made in
        refused = ctrl.machine.go(mode, Via.REQUEST, ticket.command.source.client)
        if refused is not None:
            raise CommandRefusedError(refused)
        self._done(ticket)

    def _jog(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        cmd = ticket.command
        assert isinstance(cmd, Jog)
        wake = Mode.TIP if cmd.frame == "tip" else Mode.KNOB
        if ctrl.task is not None:  # operator input ends an automatic motion
            ctrl.abort_task("aborted by operator input", keep_mode=True)
            ctrl.machine.go(wake, Via.REQUEST, cmd.source.client)
        elif ctrl.machine.mode is Mode.IDLE:  # teleoperation input wakes the controller
            ctrl.machine.go(wake, Via.REQUEST, cmd.source.client)
        ctrl._jog = JogHold(cmd.velocity, cmd.frame, cmd.source.client, at)  # noqa: SLF001
        self._done(ticket)

    def _stop(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        client = ticket.command.source.client
        ctrl.abort_task(f"stopped by {client}", keep_mode=True)
        ctrl._jog = None  # noqa: SLF001
        ctrl._q_cmd = ctrl._q.copy()  # noqa: SLF001
        ctrl.guard.hold()
        if not ctrl.machine.halted:
            ctrl.machine.go(Mode.IDLE, Via.REQUEST, client)
        self._done(ticket)

    def _reset(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        client = ticket.command.source.client
        try:
            refused, q = ctrl.guard.reset(ticket.seq)
        except IcenavError as exc:
            text = f"reset failed, still {ctrl.machine.mode.name}: {exc}"
            ctrl._message = text  # noqa: SLF001
            ctrl.settle(ticket, Outcome.ACCEPTED)
            ctrl.settle(ticket, Outcome.FAILED, text)
            return
        if refused is not None:
            raise CommandRefusedError(f"reset refused: {refused}")
        assert q is not None
        ctrl._q = q  # noqa: SLF001
        ctrl._q_cmd = q.copy()  # noqa: SLF001
        ctrl._jog = None  # noqa: SLF001
        ctrl._message = f"reset by {client}; holding position"  # noqa: SLF001
        ctrl.note(ctrl._message)  # noqa: SLF001
        self._done(ticket, ctrl._message)  # noqa: SLF001

    def _disconnect(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        client = ticket.command.source.client
        stopped = ctrl.abort_task(f"stopped: {client} disconnected", client=client)
        if ctrl._jog is not None and ctrl._jog.client == client:  # noqa: SLF001
            ctrl._jog = None  # noqa: SLF001
        self._done(ticket, "its automatic motion stopped" if stopped else "")

    def _set_compensation(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        enabled = bool(ticket.command.enabled)  # type: ignore[attr-defined]
        if enabled and ctrl.compensation is None:
            raise CommandRefusedError("no calibration yet: run Calibrate first")
        ctrl.compensation_enabled = enabled
        ctrl._message = f"compensation {'on' if enabled else 'off'}"  # noqa: SLF001
        self._done(ticket)

    # --- the command path ---------------------------------------------------------------

    def to_model(self, q_motor: Array) -> Array:
        ctrl = self._ctrl
        if not ctrl.compensation_enabled or ctrl.compensation is None:
            return np.array(q_motor, dtype=np.float64)
        return np.asarray(ctrl.compensation.motor_to_model(q_motor, check=False))

    def to_motor(self, q_model: Array) -> Array:
        ctrl = self._ctrl
        if not ctrl.compensation_enabled or ctrl.compensation is None:
            return np.array(q_model, dtype=np.float64)
        return np.asarray(ctrl.compensation.model_to_motor(q_model, check=False))

    def send(self, q_next: Array, dt: float) -> None:
        """Limit the command in speed and to the joint limits, then command the robot."""
        ctrl = self._ctrl
        q_cmd = ctrl._q_cmd  # noqa: SLF001
        vmax = self._vmax * dt
        q = q_cmd + np.clip(q_next - q_cmd, -vmax, vmax)
        clipped = np.clip(q, self._lo, self._hi)
        if np.any(clipped != q):
            names = [
                n
                for n, a, b in zip(("phi1", "phi2", "phi3", "d4"), q, clipped, strict=True)
                if a != b
            ]
            ctrl._message = f"joint limit reached: {', '.join(names)} held at its limit"  # noqa: SLF001
        try:
            sent = ctrl.guard.send(clipped)
        except IcenavError as exc:
            ctrl._q_cmd = ctrl._q.copy()  # noqa: SLF001
            ctrl.abort_task(f"command refused: {exc}")
            ctrl._message = f"command refused: {exc}"  # noqa: SLF001
            return
        if not sent:
            ctrl._q_cmd = ctrl._q.copy()  # noqa: SLF001
            return
        ctrl._q_cmd = clipped  # noqa: SLF001
        observe = getattr(ctrl.compensation, "observe", None)
        if observe is not None:  # a compensation with state follows every command sent
            observe(clipped)

    # --- views --------------------------------------------------------------------------

    def _goto(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        name = ticket.command.view  # type: ignore[attr-defined]
        view = ctrl.views.get(name)
        roadmap = ctrl.roadmap
        # vertex budget (the soak, docs/safety.md): out of recorded territory, record the
        # stretch travelled since the roadmap was left, so the return can start from here
        roadmap.anchor()
        task: Task
        if roadmap.n_vertices >= ctrl.config.background_plan_vertices:
            # a large roadmap: the search runs in a worker on a snapshot while the robot
            # holds; the control loop never waits for it
            job = roadmap.tree_job(view, approach=True, isolate=ctrl.config.plan_in_process)
            installed = [False]

            def install(f: Future[Any]) -> None:
                if not installed[0] and f.exception() is None:
                    installed[0] = True
                    roadmap.install_tree(view, f.result())

            tree = ctrl.jobs.submit(job, install, "icenav-plan", threaded=True)
            task = PlanningTask(
                view,
                tree,
                roadmap,
                ctrl._q_cmd,  # noqa: SLF001
                lambda path: self._goto_path(view, path),
                install=lambda: install(tree),
            )
        else:
            try:
                path = roadmap.plan(ctrl._q, view, approach=True)  # noqa: SLF001
            except IcenavError as exc:
                raise CommandRefusedError(f"cannot go to {name!r}: {exc}") from exc
            task = self._goto_path(view, path)
        ctrl.selected_view = name
        self._start(ticket, task)

    def _goto_path(self, view: View, path: Array) -> PathTask:
        ctrl = self._ctrl
        # the force check (Eqs. F1, F2, F4, F5 of icenav.recovery.force): with a force channel,
        # the forces the operator's trace produced along the path, looked up as the task goes
        return goto_view_task(
            path,
            ctrl.config,
            label=f"go to view {view.name!r}",
            force_sensor=ctrl.force_sensor,
            forces=ctrl.forces,
            roadmap=ctrl.roadmap,
            tip_pose=ctrl.tip_pose_now,
            tip_index=self._tip_index,
            signals=ctrl.signals,
            clock=ctrl.now,
        )

    def _refine(self, ticket: Ticket, at: float) -> None:
        """The EM pose stage (:mod:`icenav.refinement.pose_stage`) on the cycle-averaged
        pose (Eq. R1) towards the pose measured the same way when the view was saved."""
        from icenav.refinement.pose_stage import PoseStageTask

        ctrl = self._ctrl
        name = ticket.command.view  # type: ignore[attr-defined]
        view = ctrl.views.get(name)
        saved = view.em_tip2base
        if saved is None or ctrl.pose_buffer is None:
            raise CommandRefusedError(
                f"cannot refine {name!r}: no EM pose was saved with it (a registered tracker "
                f"and the catheter held still {ctrl.config.refine_window_s:.0f} s before "
                "saving are needed)"
            )
        cfg = ctrl.config
        gate = None
        if ctrl.respiration is not None:
            from icenav.refinement.cycle_pose import ExpirationGate

            # the stage's moves arrive at end-expiration (its preset's arrive_at_expiration)
            gate = ExpirationGate(ctrl.respiration, ctrl._clock)  # noqa: SLF001
        stage = PoseStageTask(
            view.q,
            saved,
            ctrl.cycle_pose(cfg.refine_window_s),
            q_start=ctrl._q_cmd,  # noqa: SLF001
            arrival_direction=view.arrival_direction,
            config=refine_stage_config(cfg.refine_window_s),
            expiration=gate,
        )
        self._start(ticket, refinement_task(stage))

    def _tip_index(self) -> Future[Any] | None:
        """The operator's tip readings indexed on a worker (not on the control thread), or
        None when there are none."""
        tips = self._ctrl.forces.tips
        n = tips.n_samples
        if n == 0:
            return None
        return self._ctrl.jobs.submit(lambda: tips.index(n), name="icenav-force-index",
                                      threaded=True)  # fmt: skip

    def _save_view(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        name = ticket.command.view  # type: ignore[attr-defined]
        if name in ctrl.views:
            raise CommandRefusedError(f"a view named {name!r} exists already: choose another name")
        tip = forward(self.to_model(ctrl._q), ctrl.config.geometry, check=False)  # noqa: SLF001
        image = ctrl.publisher.image
        try:
            view = ctrl.roadmap.make_view(
                name,
                created_s=time.time(),
                q=ctrl._q,  # noqa: SLF001
                tip2base=tip,
                thumbnail=None if image is None else image.pixels,
                # the refinement's target, measured as it will measure (None: not still)
                em_tip2base=ctrl.still_em_pose(),
            )
            ctrl.views.add(view)
        except IcenavError as exc:
            raise CommandRefusedError(f"view not saved: {exc}") from exc
        if image is not None:
            ctrl.publisher.view_images[name] = image
        ctrl.selected_view = name
        self._prepare_plans_to(view)
        ctrl.settle(ticket, Outcome.ACCEPTED)

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
            ctrl.jobs.call_soon(lambda: self._view_saved(ticket, name, text, error is None))

        recorded = ctrl.record("view_saved", {"view": view, "on_durable": on_durable})
        if recorded == "pending":
            ctrl._message = f"view {name!r}: saving to disk"  # noqa: SLF001
        elif recorded:
            self._view_saved(ticket, name, f"view {name!r} saved", True)
        else:  # reliability: the operator must know the view is not on disk
            text = f"view {name!r} saved in memory only, NOT on disk: {ctrl._message}"  # noqa: SLF001
            self._view_saved(ticket, name, text, False)

    def _view_saved(self, ticket: Ticket, name: str, text: str, durable: bool) -> None:
        """Tell the operator whether view ``name`` is on disk. A view that is *not* stays in
        front of every later message (an alarm) until a later view is saved to disk: a
        store failure also fails the next state batch, whose message must not hide it."""
        ctrl = self._ctrl
        ctrl._message = text  # noqa: SLF001
        ctrl.publisher.view_alarm = None if durable else text
        ctrl.settle(ticket, Outcome.DONE if durable else Outcome.FAILED, text)

    def _prepare_plans_to(self, view: View) -> None:
        """On a large roadmap, compute the shortest-path tree to a new view in a worker
        (from a snapshot; about a second at 1e6 vertices), so that the first return to it
        plans in milliseconds and the control loop never waits for a full search."""
        ctrl = self._ctrl
        roadmap = ctrl.roadmap
        if roadmap.n_vertices < ctrl.config.background_plan_vertices:
            return  # a first plan is fast enough on a small roadmap
        job = roadmap.tree_job(view, approach=True, isolate=ctrl.config.plan_in_process)

        def install(f: Future[Any]) -> None:
            if f.exception() is None and view.name in ctrl.views:
                roadmap.install_tree(view, f.result())

        ctrl.jobs.submit(job, install, "icenav-plan-prepare", threaded=True)

    def _rename_view(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        cmd = ticket.command
        assert isinstance(cmd, RenameView)
        ctrl.views.rename(cmd.view, cmd.new_name)
        images = ctrl.publisher.view_images
        if cmd.view in images:
            images[cmd.new_name] = images.pop(cmd.view)
        if ctrl.selected_view == cmd.view:
            ctrl.selected_view = cmd.new_name
        ctrl.record("view_renamed", {"old": cmd.view, "new": cmd.new_name})
        ctrl._message = f"view {cmd.view!r} renamed {cmd.new_name!r}"  # noqa: SLF001
        self._done(ticket)

    def _delete_view(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        name = ticket.command.view  # type: ignore[attr-defined]
        ctrl.views.delete(name)
        ctrl.publisher.view_images.pop(name, None)
        if ctrl.selected_view == name:
            ctrl.selected_view = None
        ctrl.record("view_deleted", {"name": name})
        ctrl._message = f"view {name!r} deleted"  # noqa: SLF001
        self._done(ticket)

    def _export(self, ticket: Ticket, at: float) -> None:
        ctrl = self._ctrl
        name = ticket.command.view  # type: ignore[attr-defined]
        if name not in ctrl.views:
            raise CommandRefusedError(f"no saved view named {name!r}")
        if name not in ctrl.publisher.view_images:
            raise CommandRefusedError(f"view {name!r} has no saved image: nothing to export")
        self._done(ticket)

    # --- automatic motions --------------------------------------------------------------

    def _spin(self, ticket: Ticket, at: float) -> None:
        """The image plane turns 360 deg about the catheter axis while the model tip stays
        put (paper Sec. IV: phi1 = a cos t, phi2 = a sin t, phi3 = -t from an AP bend),
        mapped to motor states through the compensation when it is on; servoed on the EM
        tracker when one is registered."""
        ctrl = self._ctrl
        g = ctrl.config.geometry
        try:
            spin = spin_trajectory(self.to_model(ctrl._q), 360, include_end=True, geometry=g)  # noqa: SLF001
        except IcenavError as exc:
            raise CommandRefusedError(f"cannot spin from here: {exc}") from exc
        tracker = ctrl.tracker
        pose_source = None
        if ctrl.config.spin_feedback and tracker is not None and tracker.registration is not None:

            def pose_source() -> tuple[float, Array | None]:
                try:
                    return tracked_tip2base(tracker)
                except IcenavError:  # a dropped frame: the servo holds its correction
                    return ctrl.time, None

        task = SpinTask(
            spin.q_model,
            self.to_motor,
            np.asarray(ctrl.config.max_velocity),
            g.joint_limits,
            pose_source=pose_source,
            geometry=g,
            hold_measured=True,
        )
        self._start(ticket, MotionAdapter(task, Mode.SPINNING))

    def _calibrate(self, ticket: Ticket, at: float) -> None:
        """A calibration procedure (``icenav.calibration.procedures``) as a bench procedure
        (:class:`~icenav.control.calibration_runner.CalibrationRunner`); its fit runs in the
        background and its compensation is installed once the catheter is back."""
        from icenav.calibration.procedures import make_procedure

        ctrl = self._ctrl
        cfg = ctrl.config
        tracker = ctrl.tracker
        if tracker is None:
            raise CommandRefusedError("calibration needs a tracker")
        kind = ticket.command.kind  # type: ignore[attr-defined]
        procedure = make_procedure(kind, geometry=cfg.geometry)
        vmax = np.asarray(cfg.max_velocity)
        q_start = ctrl._q_cmd.copy()  # noqa: SLF001
        expected = preview(
            procedure,
            q_start,
            vmax,
            settle_s=cfg.plan_settle_s,
            ramp_s=cfg.calibration_ramp_s,
            dt=cfg.dt,
            geometry=cfg.geometry,
        )

        def measure(n: int) -> Future[Array | None]:
            return ctrl.jobs.submit(lambda: tracker.measure_tip2base(n_average=n))

        runs: list[_CalibrationRun] = []

        def on_recording(recording: Any) -> None:
            run = runs[0]
            ctrl._message = f"{run.runner.label}: fitting the compensation"  # noqa: SLF001
            run.fit = ctrl.jobs.submit(
                lambda: procedure.fit(recording), lambda f: self._fit_done(run), "icenav-fit"
            )

        runner = CalibrationRunner(
            procedure,
            measure,
            on_recording,
            q_start=q_start,
            max_velocity=vmax,
            settle_s=cfg.plan_settle_s,
            ramp_s=cfg.calibration_ramp_s,
            n_expected=expected.n_visits,
        )
        run = _CalibrationRun(runner, ticket, kind)
        runs.append(run)
        self._calibrations[id(runner)] = run
        self._start(ticket, runner)

    def finishes_later(self, task: Task) -> bool:
        """The task ended Done; True when its ticket is settled later (a calibration: once
        its fit is installed)."""
        run = self._calibrations.get(id(task))
        if run is None:
            return False
        run.returned = True
        if run.fit is not None and run.fit.done():
            self._install(run)
        return True

    def _fit_done(self, run: _CalibrationRun) -> None:
        if run.returned or run.ticket.finished:
            self._install(run)

    def _install(self, run: _CalibrationRun) -> None:
        """Install a calibration's compensation, relaxed where the robot is now."""
        ctrl = self._ctrl
        self._calibrations.pop(id(run.runner), None)
        if run.ticket.finished or run.fit is None:
            return  # stopped or e-stopped before the end: nothing is installed
        exc = run.fit.exception()
        if exc is not None:  # the fit is not in the control path: the robot goes on
            text = f"calibration ({run.kind}) failed: {type(exc).__name__}: {exc}"
            ctrl._message = text  # noqa: SLF001
            ctrl.settle(run.ticket, Outcome.FAILED, text)
            return
        outcome = run.fit.result()
        ctrl.compensation = outcome.knob_map
        observe = getattr(outcome.knob_map, "observe", None)
        if observe is not None:  # the map's state follows the catheter from here
            observe(ctrl._q_cmd)  # noqa: SLF001
        ctrl.compensation_enabled = True
        ctrl.calibration = outcome.calibration_set
        text = f"calibration ({run.kind}) done: compensation on; {outcome.quality.describe()}"
        ctrl._message = text  # noqa: SLF001
        ctrl.record(
            "calibration",
            {
                "kind": run.kind,
                "n_samples": outcome.quality.n_used,
                "quality": outcome.quality.describe(),
                # its calibration-file document, made by the recorder off the loop
                "document": partial(calibration_document, outcome),
            },
        )
        ctrl.settle(run.ticket, Outcome.DONE, text)

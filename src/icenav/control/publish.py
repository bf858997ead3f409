"""What the controller shows: the snapshot of each cycle and the live image.

:class:`Publisher` builds the :class:`~icenav.control.state.ControllerState` of a cycle (the
model's and the twin's tip and backbone, the tracked sensor in the base frame, the message
with the cause of a FAULT / ESTOP in front), hands it to the listeners, and renders the ICE
image (inline at the image rate when the controller is stepped by hand, else on the imaging
thread). The tracker and the imager are read here for display only: an error of either is
reported (tracker status "ERROR", a message) and never stops the robot; where the tracker is
in the control path (a calibration, the closed-loop spin) its errors are the task's.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.control.modes import HALTED
from icenav.control.state import ControllerState, ImageFrame, ViewSummary
from icenav.geometry.kinematics import CatheterGeometry, backbone, forward
from icenav.recovery.drift import CONFIRM_S, DEFAULT_DRIFT_MM, RestReference, cannot_tell

if TYPE_CHECKING:
    from icenav.control.controller import Controller

__all__ = ["Publisher", "force_check_text", "pending_question"]


def _points(q_model: Array, geometry: CatheterGeometry, n: int) -> Array:
    """(n, 3) points of the model's bending section in the base frame (mm)."""
    return backbone(q_model, geometry, n).points_in_base


class Publisher:
    """Snapshots and images of one controller (see the module docstring)."""

    def __init__(
        self,
        ctrl: Controller,
        truth: Callable[[], tuple[Array, Array]] | None,
        imager: Callable[[Array, float], NDArray[np.uint8]] | None,
        image_ijk2tip: Array | None,
    ) -> None:
        self._ctrl = ctrl
        self._truth = truth
        self._imager = imager
        self._ijk2tip = np.eye(4) if image_ijk2tip is None else np.asarray(image_ijk2tip, float)
        self.listeners: list[Callable[[ControllerState], None]] = []
        self.image: ImageFrame | None = None
        """The latest ICE image."""
        self.view_images: dict[str, ImageFrame] = {}
        """The image saved with each view."""
        self.view_alarm: str | None = None
        """A view saved in memory only: shown in front until a later view is on disk."""
        self._next_image_t = 0.0
        self._image_error = ""
        lim = ctrl.config.geometry.joint_limits
        self._lo, self._hi = lim[:, 0].copy(), lim[:, 1].copy()

    def gamepad(self) -> str:
        """The gamepad, for display (read-only): "none" (none configured), "connected", or
        "disconnected" (configured, not seen at its latest reading)."""
        pad = self._ctrl._pad  # noqa: SLF001 - the controller's own part
        if pad is None:
            return "none"
        return "connected" if pad._connected else "disconnected"  # noqa: SLF001

    def operator_message(self) -> str:
        """The latest message; in FAULT / ESTOP the cause stays in front until reset, and a
        view that is not on disk stays in front until a later view is."""
        ctrl = self._ctrl
        message = ctrl._message  # noqa: SLF001 - the controller's own part
        alarm = self.view_alarm
        if alarm is not None and alarm not in message:
            message = f"{alarm} | {message}"
        if self._image_error and self._image_error not in message:
            message = f"{message} | {self._image_error}" if message else self._image_error
        machine = ctrl.machine
        if machine.mode not in HALTED:  # (the cause is read under the machine's lock)
            return message
        cause = machine.cause
        if not cause or message == cause or cause in message:
            return message
        return f"{cause} (then: {message})" if message else cause

    def make_state(self) -> ControllerState:
        ctrl = self._ctrl
        cfg = ctrl.config
        g = cfg.geometry
        q = ctrl._q  # noqa: SLF001
        q_model = ctrl.handlers.to_model(q)
        tip_model = forward(q_model, g, check=False)
        # the model's backbone is drawing data: computed when the console first reads it
        # (the state is immutable and q_model a fresh array, so it is this cycle's shape)
        bb_model = functools.partial(
            _points, np.clip(q_model, self._lo, self._hi), g, cfg.backbone_points
        )
        tip_true = bb_true = None
        if self._truth is not None:
            tip_true, bb_true = self._truth()
        sensor, tracker_status = self._sensor()
        task = ctrl.task
        return ControllerState(
            time=ctrl.time,
            cycle=ctrl._cycle,  # noqa: SLF001
            mode=ctrl.machine.mode,
            robot_status=ctrl.robot.status,
            q_motor=q.copy(),
            q_model=q_model,
            tip2base_model=tip_model,
            tip2base_true=tip_true,
            backbone_model=bb_model,
            backbone_true=bb_true,
            sensor2base=sensor,
            tracker_status=tracker_status,
            force_check=force_check_text(
                ctrl.force_sensor is not None,
                ctrl.forces,
                ctrl.tracker is not None,
                ctrl.config.force_drift_mm,
            ),
            message=self.operator_message(),
            question=pending_question(ctrl.forces, ctrl.now, ctrl.task is None)
            if ctrl.machine.mode not in HALTED
            else "",
            progress=None if task is None else task.progress,
            progress_label="" if task is None else task.label,
            n_vertices=ctrl.roadmap.n_vertices,
            n_edges=ctrl.roadmap.n_edges,
            views=tuple(
                ViewSummary(v.name, v.q, v.created_s, v.thumbnail is not None) for v in ctrl.views
            ),
            compensation_enabled=ctrl.compensation_enabled,
            control_owner=ctrl.authorization.holder,
        )

    def _sensor(self) -> tuple[Array | None, str]:
        """The tracked sensor pose in the base frame and the tracker's status text."""
        tracker = self._ctrl.tracker
        if tracker is None:
            return None, "none"
        try:
            frame = tracker.get_frame()
            registration = tracker.registration
        except Exception as exc:  # display only: the tracker is not in the control path here
            self._ctrl._message = f"tracker error: {exc}"  # noqa: SLF001
            return None, "ERROR"
        if frame.sensor2tracker is None or registration is None:
            return None, frame.status.name
        return registration.sensor2base(frame.sensor2tracker), frame.status.name

    def publish(self) -> None:
        """Make this cycle's state, render the image when due (stepped by hand), tell the
        listeners."""
        ctrl = self._ctrl
        state = self.make_state()
        ctrl._state = state  # noqa: SLF001
        if not ctrl.running and ctrl.time >= self._next_image_t:
            # stepped by hand (simulation, tests): render inline at the image rate
            self._next_image_t = ctrl.time + 1.0 / ctrl.config.image_rate_hz
            try:
                self.render_image()
            except Exception as exc:  # display only
                self.image_error(exc)
        for cb in list(self.listeners):
            cb(state)

    def publish_minimal(self) -> None:
        """After a failed publish: the last state with this cycle's time, mode and message
        (so a reader sees the FAULT even when the state itself could not be made)."""
        ctrl = self._ctrl
        ctrl._state = dataclasses.replace(  # noqa: SLF001
            ctrl._state,  # noqa: SLF001
            time=ctrl.time,
            cycle=ctrl._cycle,  # noqa: SLF001
            mode=ctrl.machine.mode,
            robot_status=ctrl.robot.status,
            message=self.operator_message(),
            question=pending_question(ctrl.forces, ctrl.now, ctrl.task is None)
            if ctrl.machine.mode not in HALTED
            else "",
            progress=None,
            progress_label="",
            control_owner=ctrl.authorization.holder,
        )

    def render_image(self) -> ImageFrame | None:
        """Render the ICE image of the latest state's true pose (None without an imager)."""
        state = self._ctrl.snapshot()
        if self._imager is None or state.tip2base_true is None:
            return None
        frame = ImageFrame(
            pixels=self._imager(state.tip2base_true, state.time),
            timestamp=state.time,
            ijk2tip=self._ijk2tip,
        )
        self.image = frame
        self._image_error = ""
        return frame

    def image_error(self, exc: Exception) -> None:
        """An imager error (any thread): shown until an image renders again."""
        self._image_error = f"imaging error: {type(exc).__name__}: {exc}"


def force_check_text(
    has_channel: bool,
    forces: Any,
    has_tracker: bool = False,
    drift_limit_mm: float = DEFAULT_DRIFT_MM,
) -> str:
    """What the operator is told of the returns' checks: the force check (a force channel)
    and the tip-drift check (a tracker, Eqs. F5 and F6 of :mod:`icenav.recovery.drift`),
    including where it cannot tell a moved patient from the still tip's own motion."""
    drift = ""
    if has_tracker:  # Eq. (F5) compares with where the operator's last drive left the tip
        rest = getattr(forces, "rest", None)
        if rest is None:
            drift = (
                "; tip-drift check on (tracker, armed at your next drive: the last motion "
                "was not yours)"
            )
        elif cannot_tell(r := rest.resolution_mm(within=0.8), drift_limit_mm):  # Eq. (F6)
            drift = (
                f"; tip-drift check on (tracker; cannot tell here: the still tip strays "
                f"{r:.1f} mm by itself, so a return that finds it moved asks you to confirm)"
            )
        else:
            drift = "; tip-drift check on (tracker)"
    if not has_channel:
        return "off: no force channel" + drift
    n = forces.forces.n_recorded
    text = f"on ({n} states of your trace with a force)" if n else "on (no force recorded yet)"
    return text + drift


def pending_question(forces: Any, now: Callable[[], float], idle: bool) -> str:
    """The question a held return left open (Eq. F6 of :mod:`icenav.recovery.drift`), with
    the seconds left to answer it; "" when there is none, it has expired, or a task runs
    (``idle`` False). ``now`` is the loop's clock (s), read only while a question is open."""
    rest = getattr(forces, "rest", None)
    if not idle or not isinstance(rest, RestReference) or rest.asked_at is None:
        return ""
    t = now()
    if not rest.confirmed(t):
        return ""
    left = CONFIRM_S if not np.isfinite(rest.asked_at) else CONFIRM_S - (t - rest.asked_at)
    return (
        f"The return waits for you ({left:.0f} s left): the tip-drift check cannot tell here "
        "whether the patient has moved. If the image shows the patient has not moved, press "
        "the return again to go with the force check alone; else drive to the view by hand."
    )

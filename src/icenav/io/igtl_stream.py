"""Stream a controller's state to 3D Slicer through an :class:`~icenav.io.igtl.IgtlBridge`.

A background thread reads the controller's latest snapshot and image at fixed rates and
sends ``TipToBase`` (model tip pose), ``SensorToTracker`` (the tracked sensor, when
valid), ``Image`` (the ICE image placed in the base frame by its ijk-to-base matrix) and a
status string; commands the bridge accepts (only those enabled in its configuration) are
forwarded to the controller by :func:`handle_request`, the one adapter between the bridge's
requests and the controller, whose reply goes back to the client. Sending happens outside
the control thread (packing on the streamer's thread, the sockets on the server's), so the
network never delays a control cycle.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from icenav.control.commands import Command, GoToView, RefineView, SaveView, Source, Stop
from icenav.control.controller import Controller
from icenav.errors import IcenavError, IgtlError
from icenav.io.igtl import (
    DEVICE_IMAGE,
    DEVICE_SENSOR_TO_TRACKER,
    DEVICE_TIP_TO_BASE,
    IgtlBridge,
    IgtlCommand,
    IgtlOutcome,
    IgtlReply,
    IgtlRequest,
)

__all__ = [
    "CommandForwarder",
    "DECISION_TIMEOUT_S",
    "IgtlStreamer",
    "SOURCE",
    "attach_bridge",
    "handle_request",
    "source_for",
    "to_command",
]


_CLIENT = "igtl"


DECISION_TIMEOUT_S = 2.0
"""How long a command waits for the controller's decision before the reply says so (s); the
controller decides at its next cycle (10 ms at 100 Hz)."""
SOURCE = Source("igtl", _CLIENT)
"""The source of an OpenIGTLink command whose peer is not known (a direct call)."""


def source_for(peer: str) -> Source:
    """The source of the commands of one OpenIGTLink connection (``host:port``): each
    connection is its own client, so authorization tells two Slicers apart, and the close of
    one ends the control it held and stops the motion it started."""
    return Source("igtl", f"{_CLIENT}-{peer}") if peer else SOURCE


def to_command(request: IgtlRequest) -> Command:
    """The controller's command for an OpenIGTLink request (the one command set)."""
    source = source_for(request.peer)
    if request.command is IgtlCommand.STOP:
        return Stop(source=source)
    if request.command is IgtlCommand.SAVE_VIEW:
        return SaveView(request.argument, source=source)
    if request.command is IgtlCommand.REFINE_VIEW:
        return RefineView(request.argument, source=source)
    return GoToView(request.argument, source=source)


def handle_request(
    ctrl: Controller, request: IgtlRequest, timeout_s: float = DECISION_TIMEOUT_S
) -> IgtlReply:
    """Submit one OpenIGTLink command to the controller and reply with its true outcome:
    the controller's own decision (accepted, or refused and why: not in control, in ESTOP,
    no such view, ...), waited for on the server's command thread, never the I/O thread."""
    try:
        result = ctrl.submit(to_command(request)).result(timeout_s)
    except IcenavError as exc:  # a malformed name, or no decision in time
        return IgtlReply(IgtlOutcome.REFUSED, str(exc))
    return IgtlReply(IgtlOutcome(result.outcome.value), result.reason)


class CommandForwarder:
    """The bridge's ``on_command`` and ``on_disconnect`` callbacks, bound to a controller once
    it exists (the bridge must be created first, on the main thread)."""

    def __init__(self) -> None:
        self.ctrl: Controller | None = None

    def __call__(self, request: IgtlRequest) -> IgtlReply:
        if self.ctrl is None:
            return IgtlReply(IgtlOutcome.REFUSED, "the controller is not running yet")
        return handle_request(self.ctrl, request)

    def disconnected(self, peer: str) -> None:
        """A connection that sent commands is gone: the controller releases the control it
        held and stops (and holds) any automatic motion it started."""
        if self.ctrl is not None:
            self.ctrl.disconnect(source_for(peer))


class IgtlStreamer:
    """Sends poses at ``pose_rate_hz`` and each new image (at most ``image_rate_hz``)
    until :meth:`stop`, on a thread of its own, paced by deadlines (no drift)."""

    def __init__(
        self,
        ctrl: Controller,
        bridge: IgtlBridge,
        pose_rate_hz: float = 50.0,
        image_rate_hz: float = 30.0,
    ):
        self.ctrl = ctrl
        self.bridge = bridge
        self._pose_period = 1.0 / pose_rate_hz
        self._image_period = 1.0 / image_rate_hz
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="icenav-igtl", daemon=True)
        self.sent_poses = 0
        self.sent_images = 0
        self._last_image: object = None

    def start(self) -> None:
        self._thread.start()

    def send_once(self, with_image: bool = True) -> None:
        """Send the current state (and image) once."""
        state = self.ctrl.snapshot()
        self.bridge.send_pose(DEVICE_TIP_TO_BASE, state.tip2base_model)
        if state.sensor2base is not None and self.ctrl.tracker is not None:
            tracker2base = self.ctrl.tracker.config.tracker2base
            sensor2tracker = np.linalg.inv(tracker2base) @ state.sensor2base
            self.bridge.send_pose(DEVICE_SENSOR_TO_TRACKER, sensor2tracker)
        self.bridge.send_status(
            {
                "mode": state.mode.value,
                "robot": state.robot_status.value,
                "tracker": state.tracker_status,
                "message": state.message,
            }
        )
        self.sent_poses += 1
        frame = self.ctrl.latest_image()
        new = frame is not None and frame is not self._last_image
        if with_image and new and frame is not None and state.tip2base_true is not None:
            self.bridge.send_image(DEVICE_IMAGE, frame.pixels, state.tip2base_true @ frame.ijk2tip)
            self._last_image = frame
            self.sent_images += 1

    def _run(self) -> None:
        # every tick sends the pose; the image when the controller has a new one and the
        # last went out at least an image period ago (the controller's rate is the usual cap)
        now = time.perf_counter()
        next_pose = now
        last_image = -float("inf")
        while not self._stop.is_set():
            with_image = now - last_image >= self._image_period
            sent = self.sent_images
            try:
                self.send_once(with_image)
            except IgtlError:  # the bridge was closed under us: the stream ends
                return
            if self.sent_images != sent:
                last_image = now
            next_pose = max(next_pose + self._pose_period, now - self._pose_period)
            self._stop.wait(max(0.0, next_pose - time.perf_counter()))
            now = time.perf_counter()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)


def attach_bridge(
    ctrl: Controller, bridge: IgtlBridge, forwarder: CommandForwarder | None = None
) -> IgtlStreamer:
    """Start streaming ``ctrl`` through ``bridge``; bind ``forwarder`` (the bridge's
    ``on_command``) to ``ctrl``."""
    if forwarder is not None:
        forwarder.ctrl = ctrl
    streamer = IgtlStreamer(ctrl, bridge)
    streamer.start()
    return streamer

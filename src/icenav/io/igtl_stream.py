"""Stream a controller's state to 3D Slicer through an :class:`~icenav.io.igtl.IgtlBridge`.

A background thread reads the controller's latest snapshot and image at fixed rates and
sends ``TipToBase`` (model tip pose), ``SensorToTracker`` (the tracked sensor, when
valid), ``Image`` (the ICE image placed in the base frame by its ijk-to-base matrix) and a
status string; commands the bridge accepts (only those enabled in its configuration) are
forwarded to the controller as requests from client "igtl". Sending happens outside the
control thread, so the network never delays a control cycle.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from icenav.control.controller import Controller
from icenav.io.igtl import (
    DEVICE_IMAGE,
    DEVICE_SENSOR_TO_TRACKER,
    DEVICE_TIP_TO_BASE,
    IgtlBridge,
    IgtlCommand,
    IgtlRequest,
)

__all__ = ["CommandForwarder", "IgtlStreamer", "attach_bridge", "handle_request"]


def handle_request(ctrl: Controller, request: IgtlRequest) -> None:
    """Forward one accepted OpenIGTLink command to the controller."""
    if request.command is IgtlCommand.STOP:
        ctrl.stop("igtl")
    elif request.command is IgtlCommand.SAVE_VIEW:
        ctrl.save_view(request.argument, "igtl")
    elif request.command is IgtlCommand.GO_TO_VIEW:
        ctrl.goto_view(request.argument, "igtl")


class CommandForwarder:
    """The bridge's ``on_command`` callback, bound to a controller once it exists (the
    bridge must be created first, on the main thread)."""

    def __init__(self) -> None:
        self.ctrl: Controller | None = None

    def __call__(self, request: IgtlRequest) -> None:
        if self.ctrl is not None:
            handle_request(self.ctrl, request)


class IgtlStreamer:
    """Sends poses at ``pose_rate_hz`` and images at ``image_rate_hz`` until :meth:`stop`."""

    def __init__(
        self,
        ctrl: Controller,
        bridge: IgtlBridge,
        pose_rate_hz: float = 50.0,
        image_rate_hz: float = 15.0,
    ):
        self.ctrl = ctrl
        self.bridge = bridge
        self._pose_period = 1.0 / pose_rate_hz
        self._image_period = 1.0 / image_rate_hz
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="icenav-igtl", daemon=True)
        self.sent_poses = 0
        self.sent_images = 0

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
        if with_image and frame is not None and state.tip2base_true is not None:
            self.bridge.send_image(DEVICE_IMAGE, frame.pixels, state.tip2base_true @ frame.ijk2tip)
            self.sent_images += 1

    def _run(self) -> None:
        next_image = 0.0
        while not self._stop.is_set():
            now = time.perf_counter()
            with_image = now >= next_image
            if with_image:
                next_image = now + self._image_period
            self.send_once(with_image)
            self._stop.wait(self._pose_period)

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

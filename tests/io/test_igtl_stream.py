"""The controller streamed to an OpenIGTLink client (pyigtl) over loopback: poses, image,
status, and commands routed back to the controller."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pyigtl
import pytest

from icenav.apps.wiring import SimSession, make_sim_controller
from icenav.io.igtl import (
    DEVICE_COMMAND,
    DEVICE_IMAGE,
    DEVICE_SENSOR_TO_TRACKER,
    DEVICE_TIP_TO_BASE,
    IgtlBridge,
    IgtlCommand,
    IgtlConfig,
)
from icenav.io.igtl_stream import CommandForwarder, IgtlStreamer
from tests.io.test_igtl import connected_client

TIMEOUT_S = 15.0


def wait_for(client: pyigtl.OpenIGTLinkClient, device: str, accept: Callable[[Any], bool]) -> Any:
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        msg = client.wait_for_message(device, timeout=0.05)
        if msg is not None and accept(msg):
            return msg
    pytest.fail(f"no acceptable {device} message within {TIMEOUT_S} s")


@pytest.fixture
def streamed() -> Iterator[tuple[SimSession, IgtlStreamer, pyigtl.OpenIGTLinkClient]]:
    forwarder = CommandForwarder()
    bridge = IgtlBridge(
        IgtlConfig(port=0, accepted_commands=frozenset({IgtlCommand.SAVE_VIEW})),
        on_command=forwarder,
    )
    session = make_sim_controller(seed=104)
    forwarder.ctrl = session.controller
    streamer = IgtlStreamer(session.controller, bridge)
    try:
        with connected_client(bridge) as client:
            yield session, streamer, client
    finally:
        streamer.stop()
        session.close()
        bridge.close()


def test_pose_image_and_sensor_reach_the_client(streamed: Any) -> None:
    session, streamer, client = streamed
    ctrl = session.controller
    for _ in range(60):
        ctrl.jog([0.6, -0.2, 0.3, 2.0], "knob")
        ctrl.step()
    state = ctrl.snapshot()
    streamer.send_once(with_image=True)
    tip = wait_for(
        client,
        DEVICE_TIP_TO_BASE,
        lambda m: np.allclose(m.matrix, state.tip2base_model, atol=1e-3),
    )
    assert tip.device_name == "TipToBase"
    if state.sensor2base is not None:
        wait_for(client, DEVICE_SENSOR_TO_TRACKER, lambda m: m.matrix.shape == (4, 4))
    frame = ctrl.latest_image()
    assert frame is not None
    img = wait_for(client, DEVICE_IMAGE, lambda m: m.image.size == frame.pixels.size)
    np.testing.assert_array_equal(np.squeeze(img.image), frame.pixels)
    # the image sits in the imaging plane at the true tip: its centre column's first pixel
    # is next to the transducer (the image centre frame's origin)
    ijk2base = np.asarray(img.ijk_to_world_matrix)
    expected = state.tip2base_true @ frame.ijk2tip  # type: ignore[operator]
    np.testing.assert_allclose(ijk2base, expected, atol=1e-3)


def test_save_view_command_from_the_client_reaches_the_controller(streamed: Any) -> None:
    session, _, client = streamed
    ctrl = session.controller
    ctrl.step()
    client.send_message(pyigtl.StringMessage("SAVE_VIEW slicer-view", device_name=DEVICE_COMMAND))
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline and "slicer-view" not in ctrl.views:
        ctrl.step()
        time.sleep(0.01)
    assert "slicer-view" in ctrl.views

"""The controller streamed to an OpenIGTLink client (pyigtl) over loopback: poses, image,
status, and commands routed to the controller through the one adapter, with true replies."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pyigtl
import pytest

from icenav.apps.wiring import SimSession, make_sim_controller
from icenav.io.igtl import (
    DEVICE_COMMAND,
    DEVICE_COMMAND_ACK,
    DEVICE_IMAGE,
    DEVICE_SENSOR_TO_TRACKER,
    DEVICE_TIP_TO_BASE,
    IgtlBridge,
    IgtlCommand,
    IgtlConfig,
    IgtlOutcome,
    IgtlRequest,
)
from icenav.io.igtl_stream import CommandForwarder, IgtlStreamer, handle_request
from tests.support.igtl import RecordingClient, connected_client


@pytest.fixture
def streamed() -> Iterator[tuple[SimSession, IgtlStreamer, RecordingClient]]:
    forwarder = CommandForwarder()
    bridge = IgtlBridge(
        IgtlConfig(
            port=0,
            accepted_commands=frozenset(
                {IgtlCommand.SAVE_VIEW, IgtlCommand.GO_TO_VIEW, IgtlCommand.REFINE_VIEW}
            ),
        ),
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
    tip = client.wait_for(
        DEVICE_TIP_TO_BASE, lambda m: np.allclose(m.matrix, state.tip2base_model, atol=1e-3)
    )
    assert tip.device_name == "TipToBase"
    if state.sensor2base is not None:
        client.wait_for(DEVICE_SENSOR_TO_TRACKER, lambda m: m.matrix.shape == (4, 4))
    frame = ctrl.latest_image()
    assert frame is not None
    img = client.wait_for(DEVICE_IMAGE, lambda m: m.image.size == frame.pixels.size)
    np.testing.assert_array_equal(np.squeeze(img.image), frame.pixels)
    # the image sits in the imaging plane at the true tip
    ijk2base = np.asarray(img.ijk_to_world_matrix)
    expected = state.tip2base_true @ frame.ijk2tip  # type: ignore[operator]
    np.testing.assert_allclose(ijk2base, expected, atol=1e-3)
    # the same image is not sent twice
    streamer.send_once(with_image=True)
    assert streamer.sent_images == 1


def _command(client: RecordingClient, text: str) -> str:
    before = len(client.messages(DEVICE_COMMAND_ACK))
    client.send_message(pyigtl.StringMessage(text, device_name=DEVICE_COMMAND), wait=True)
    assert client.wait_until(lambda: len(client.messages(DEVICE_COMMAND_ACK)) > before)
    return str(client.messages(DEVICE_COMMAND_ACK)[before].string)


def test_commands_from_the_client_get_the_controllers_answer(streamed: Any) -> None:
    session, _, client = streamed
    ctrl = session.controller
    ctrl.start()  # the controller decides each command at its next cycle
    assert _command(client, "go_to_view nowhere").startswith("refused: go_to_view nowhere: ")
    assert "nowhere" in _command(client, "go_to_view nowhere")
    assert _command(client, "SAVE_VIEW slicer-view").startswith("accepted: SAVE_VIEW slicer-view")
    assert "slicer-view" in ctrl.views
    refused = _command(client, "save_view slicer-view")
    assert refused.startswith("refused: save_view slicer-view: ") and "exists" in refused
    # saved before the loop had buffered the tracker for the refinement's window: no EM
    # pose, and the controller's refusal reaches Slicer
    no_em = _command(client, "refine_view slicer-view")
    assert no_em.startswith("refused: refine_view slicer-view: ") and "EM pose" in no_em
    ctrl.estop("test")
    estopped = _command(client, "go_to_view slicer-view")
    assert estopped.startswith("refused: go_to_view slicer-view: ") and "ESTOP" in estopped.upper()


def test_the_adapter_refuses_motion_while_another_client_holds_control() -> None:
    session = make_sim_controller(seed=104, imaging=False)
    try:
        ctrl = session.controller
        ctrl.save_view("apex")  # the script took control to save it
        ctrl.step()
        ctrl.release_control("script")
        assert ctrl.acquire_control("browser-1")
        ctrl.start()
        reply = handle_request(ctrl, IgtlRequest(IgtlCommand.GO_TO_VIEW, "apex", 0.0))
        assert reply.outcome is IgtlOutcome.REFUSED and "browser-1 holds control" in reply.reason
        assert ctrl.snapshot().mode.value == "idle"  # nothing moved
        stop = handle_request(ctrl, IgtlRequest(IgtlCommand.STOP, "", 0.0))
        assert stop.outcome is IgtlOutcome.ACCEPTED  # stop from anyone
    finally:
        session.close()


def test_no_decision_in_time_is_a_refusal_that_says_so() -> None:
    session = make_sim_controller(seed=104, imaging=False)
    try:  # the loop is not running: nobody decides
        reply = handle_request(
            session.controller, IgtlRequest(IgtlCommand.STOP, "", 0.0), timeout_s=0.05
        )
        assert reply.outcome is IgtlOutcome.REFUSED and "within 0.05 s" in reply.reason
    finally:
        session.close()


def test_a_forwarder_without_a_controller_refuses() -> None:
    reply = CommandForwarder()(IgtlRequest(IgtlCommand.STOP, "", 0.0))
    assert reply.outcome is IgtlOutcome.REFUSED and "not running" in reply.reason


def _until(predicate: Any, timeout: float = 10.0) -> bool:
    """Poll an observable condition of the controller's loop (it runs on its own thread)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return bool(predicate())


def test_each_connection_is_its_own_client_and_its_close_stops_its_motion() -> None:
    """Two Slicers: the first one's go to view takes control for that connection only, the
    second is refused while it runs; when the first connection closes, its motion stops and
    holds and control is free again."""
    forwarder = CommandForwarder()
    bridge = IgtlBridge(
        IgtlConfig(port=0, accepted_commands=frozenset({IgtlCommand.GO_TO_VIEW})),
        on_command=forwarder,
        on_disconnect=forwarder.disconnected,
    )
    session = make_sim_controller(seed=104, imaging=False)
    ctrl = session.controller
    try:
        ctrl.save_view("home")
        ctrl.step()
        for _ in range(400):  # far from home: the return takes seconds
            ctrl.jog([1.0, -1.0, 1.0, 4.0], "knob")
            ctrl.step()
        ctrl.release_control("script")
        forwarder.ctrl = ctrl
        ctrl.start()
        with connected_client(bridge) as first, connected_client(bridge, n_before=1) as second:
            assert _command(first, "go_to_view home").startswith("accepted: go_to_view home")
            holder = ctrl.authorization.holder
            assert holder is not None and holder.startswith("igtl-127.0.0.1:")
            refused = _command(second, "go_to_view home")
            assert refused.startswith("refused: ") and f"{holder} holds control" in refused
            assert ctrl.snapshot().mode.value == "goto_view"
            start = ctrl.robot.read_state().q.copy()
            assert _until(lambda: not np.allclose(ctrl.robot.read_state().q, start))
            moving = ctrl.robot.read_state().q.copy()
            first.close()
            assert _until(lambda: ctrl.task is None)
            assert _until(lambda: ctrl.snapshot().mode.value == "idle")
            assert ctrl.authorization.holder is None
            assert f"{holder} disconnected" in ctrl.snapshot().message
            held = ctrl.robot.read_state().q.copy()
            assert not np.allclose(held, start)  # it had moved, and stopped short of home
            assert not np.allclose(held, ctrl.views.get("home").q, atol=1e-3)
            assert not np.allclose(moving, ctrl.views.get("home").q, atol=1e-3)
            assert _command(second, "go_to_view home").startswith("accepted: ")
    finally:
        session.close()
        bridge.close()

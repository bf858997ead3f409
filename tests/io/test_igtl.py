"""The OpenIGTLink bridge with pyigtl's client over loopback, on a port the OS chooses.

The client keeps every message it receives (tests/support/igtl.py); every check waits on a
condition with a timeout, no fixed sleeps.
"""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Iterator
from typing import Any

import numpy as np
import pyigtl
import pytest

from icenav.errors import InvalidValueError, NonFiniteError, ShapeError, TransformError
from icenav.io.igtl import (
    DEVICE_COMMAND,
    DEVICE_COMMAND_ACK,
    DEVICE_IMAGE,
    DEVICE_SENSOR_TO_TRACKER,
    DEVICE_STATUS,
    DEVICE_TIP_TO_BASE,
    IgtlBridge,
    IgtlCommand,
    IgtlConfig,
    IgtlError,
    IgtlOutcome,
    IgtlReply,
    IgtlRequest,
    check_device_name,
)
from tests.support.igtl import RecordingClient, connected_client


def _rigid(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    t = np.eye(4)
    t[:3, :3] = q
    t[:3, 3] = rng.uniform(-100, 100, size=3)
    return t


class FakeSink:
    """The command callback: records requests; refuses go_to_view, accepts the rest."""

    def __init__(self) -> None:
        self.received: list[IgtlRequest] = []

    def __call__(self, request: IgtlRequest) -> IgtlReply:
        self.received.append(request)
        if request.command is IgtlCommand.GO_TO_VIEW:
            return IgtlReply(IgtlOutcome.REFUSED, "control is held by browser-1")
        return IgtlReply(IgtlOutcome.ACCEPTED)


@pytest.fixture
def link() -> Iterator[tuple[IgtlBridge, RecordingClient, FakeSink]]:
    sink = FakeSink()
    config = IgtlConfig(
        port=0, accepted_commands=frozenset({IgtlCommand.STOP, IgtlCommand.SAVE_VIEW})
    )
    bridge = IgtlBridge(config, on_command=sink)
    try:
        with connected_client(bridge) as client:
            yield bridge, client, sink
    finally:
        bridge.close()


def test_binds_loopback_on_a_free_port(link: Any) -> None:
    bridge, _, _ = link
    assert bridge.host == "127.0.0.1"
    assert bridge.port > 0


def test_transforms_arrive_with_their_matrices_and_names(link: Any) -> None:
    bridge, client, _ = link
    rng = np.random.default_rng(1)
    tip2base, sensor2tracker = _rigid(rng), _rigid(rng)
    bridge.send_pose(DEVICE_TIP_TO_BASE, tip2base)
    bridge.send_pose(DEVICE_SENSOR_TO_TRACKER, sensor2tracker)
    for name, expected in (
        (DEVICE_TIP_TO_BASE, tip2base),
        (DEVICE_SENSOR_TO_TRACKER, sensor2tracker),
    ):
        msg = client.wait_for(name)
        assert msg.device_name == name
        np.testing.assert_allclose(msg.matrix, expected, atol=1e-4)


def test_latest_pose_wins_when_many_are_queued(link: Any) -> None:
    bridge, client, _ = link
    rng = np.random.default_rng(2)
    poses = [_rigid(rng) for _ in range(50)]
    for pose in poses:
        bridge.send_pose(DEVICE_TIP_TO_BASE, pose)
    # The client may skip intermediate poses, but it ends on the newest one.
    msg = client.wait_for(DEVICE_TIP_TO_BASE, lambda m: np.allclose(m.matrix, poses[-1], atol=1e-4))
    np.testing.assert_allclose(msg.matrix, poses[-1], atol=1e-4)


def test_image_content_and_ijk_matrix(link: Any) -> None:
    bridge, client, _ = link
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, size=(48, 64), dtype=np.uint8)
    spacing = np.array([0.3, 0.25, 1.0])  # mm per column, per row, slice
    pose = _rigid(rng)
    ijk2base = pose.copy()
    ijk2base[:3, :3] = pose[:3, :3] * spacing
    bridge.send_image(DEVICE_IMAGE, image, ijk2base)
    msg = client.wait_for(DEVICE_IMAGE)
    assert msg.device_name == DEVICE_IMAGE
    assert msg.image.shape == (1, 48, 64)
    np.testing.assert_array_equal(msg.image[0], image)
    np.testing.assert_allclose(msg.ijk_to_world_matrix, ijk2base, atol=1e-3)
    # A pixel lands where ijk2base says: column 10, row 20 in the base frame.
    p = msg.ijk_to_world_matrix @ np.array([10.0, 20.0, 0.0, 1.0])
    np.testing.assert_allclose(p, ijk2base @ np.array([10.0, 20.0, 0.0, 1.0]), atol=1e-3)
    assert msg.world_coordinate_system == "ras"


def test_status_text_and_json(link: Any) -> None:
    bridge, client, _ = link
    bridge.send_status("homing")
    client.wait_for(DEVICE_STATUS, lambda m: m.string == "homing")
    bridge.send_status({"mode": "knob", "fault": ""})
    msg = client.wait_for(DEVICE_STATUS, lambda m: m.string.startswith("{"))
    assert json.loads(msg.string) == {"fault": "", "mode": "knob"}


def _send_command(client: RecordingClient, text: str) -> list[str]:
    """Send one STRING; the replies to it (one per non-blank line), in order."""
    n_lines = sum(1 for ln in text.splitlines() if ln.strip())
    before = len(client.messages(DEVICE_COMMAND_ACK))
    client.send_message(pyigtl.StringMessage(text, device_name=DEVICE_COMMAND), wait=True)
    assert client.wait_until(lambda: len(client.messages(DEVICE_COMMAND_ACK)) >= before + n_lines)
    return [m.string for m in client.messages(DEVICE_COMMAND_ACK)[before:]]


def test_enabled_commands_reach_the_callback(link: Any) -> None:
    bridge, client, sink = link
    assert _send_command(client, "save_view septum") == ["accepted: save_view septum"]
    assert _send_command(client, "stop") == ["accepted: stop"]
    assert [(r.command, r.argument) for r in sink.received] == [
        (IgtlCommand.SAVE_VIEW, "septum"),
        (IgtlCommand.STOP, ""),
    ]
    assert all(r.peer.startswith("127.0.0.1:") for r in sink.received)


def test_disabled_and_malformed_commands_are_refused_with_the_reason(link: Any) -> None:
    bridge, client, sink = link
    assert _send_command(client, "go_to_view septum") == [
        "refused: go_to_view septum: command go_to_view is not enabled"
    ]
    (ack,) = _send_command(client, "launch rockets")
    assert ack.startswith("refused") and "unknown command" in ack
    (ack,) = _send_command(client, "save_view")
    assert ack.startswith("refused") and "needs a view name" in ack
    assert sink.received == []
    assert [r.command for r in bridge.command_log] == [
        "go_to_view septum",
        "launch rockets",
        "save_view",
    ]
    assert bridge.command_counts["refused"] == 3


def test_the_callbacks_refusal_is_what_the_client_reads() -> None:
    sink = FakeSink()
    config = IgtlConfig(port=0, accepted_commands=frozenset(IgtlCommand))
    with IgtlBridge(config, on_command=sink) as bridge, connected_client(bridge) as client:
        assert _send_command(client, "go_to_view apex") == [
            "refused: go_to_view apex: control is held by browser-1"
        ]
        assert [r.argument for r in sink.received] == ["apex"]


def test_several_commands_in_one_message_each_get_their_reply_in_order(link: Any) -> None:
    bridge, client, sink = link
    acks = _send_command(client, "save_view a\nstop\n\ngo_to_view a\nsave_view b")
    assert acks == [
        "accepted: save_view a",
        "accepted: stop",
        "refused: go_to_view a: command go_to_view is not enabled",
        "accepted: save_view b",
    ]
    assert [r.argument for r in sink.received] == ["a", "", "b"]


def test_more_lines_than_the_cap_are_refused_in_one_reply(link: Any) -> None:
    bridge, client, sink = link
    cap = bridge.config.limits.max_commands_per_message
    text = "\n".join(f"save_view v{i}" for i in range(cap + 5))
    client.send_message(pyigtl.StringMessage(text, device_name=DEVICE_COMMAND), wait=True)
    assert client.wait_until(lambda: len(client.messages(DEVICE_COMMAND_ACK)) >= cap + 1)
    acks = [m.string for m in client.messages(DEVICE_COMMAND_ACK)]
    assert acks[:cap] == [f"accepted: save_view v{i}" for i in range(cap)]
    assert acks[cap] == f"refused: ...: 5 more commands in one message (at most {cap} are read)"
    assert len(sink.received) == cap


def test_a_handler_that_raises_is_a_failed_reply_and_the_server_goes_on() -> None:
    def broken(request: IgtlRequest) -> IgtlReply:
        raise RuntimeError("boom")

    config = IgtlConfig(port=0, accepted_commands=frozenset(IgtlCommand))
    with IgtlBridge(config, on_command=broken) as bridge, connected_client(bridge) as client:
        assert _send_command(client, "stop") == ["failed: stop: RuntimeError: boom"]
        bridge.send_status("still here")
        client.wait_for(DEVICE_STATUS, lambda m: m.string == "still here")


def test_no_commands_accepted_by_default() -> None:
    assert IgtlConfig().accepted_commands == frozenset()
    assert IgtlConfig().port == 18944
    assert IgtlConfig().local_only


def test_bad_input_is_rejected(link: Any) -> None:
    bridge, _, _ = link
    with pytest.raises(InvalidValueError, match="has 21 characters.*at most 20"):
        bridge.send_pose("TipToBaseTransformXYZ", np.eye(4))
    with pytest.raises(TransformError, match="not a rigid transform"):
        bridge.send_pose(DEVICE_TIP_TO_BASE, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(NonFiniteError):
        bridge.send_pose(DEVICE_TIP_TO_BASE, np.full((4, 4), np.nan))
    with pytest.raises(InvalidValueError, match="uint8"):
        bridge.send_image(DEVICE_IMAGE, np.zeros((4, 4), dtype=np.float32), np.eye(4))
    with pytest.raises(ShapeError, match=r"\(H, W\)"):
        bridge.send_image(DEVICE_IMAGE, np.zeros((4, 4, 3), dtype=np.uint8), np.eye(4))
    with pytest.raises(InvalidValueError, match="singular"):
        bridge.send_image(DEVICE_IMAGE, np.zeros((4, 4), dtype=np.uint8), np.diag([1, 1, 0, 1]))


def test_device_names() -> None:
    assert check_device_name("x" * 20) == "x" * 20
    with pytest.raises(InvalidValueError, match="non-empty"):
        check_device_name("")
    with pytest.raises(InvalidValueError, match="ASCII"):
        check_device_name("Spitze→Basis")


def test_may_be_created_off_the_main_thread_and_leaves_signal_handlers_alone() -> None:
    before = signal.getsignal(signal.SIGINT)
    made: list[IgtlBridge] = []
    t = threading.Thread(target=lambda: made.append(IgtlBridge(IgtlConfig(port=0))))
    t.start()
    t.join()
    (bridge,) = made
    assert signal.getsignal(signal.SIGINT) is before
    bridge.close()
    with pytest.raises(IgtlError, match="closed"):
        bridge.send_status("late")


def test_a_port_in_use_is_an_error_naming_the_port() -> None:
    first = IgtlBridge(IgtlConfig(port=0))
    try:
        with pytest.raises(IgtlError, match=f"port {first.port}.*in use"):
            IgtlBridge(IgtlConfig(port=first.port))
    finally:
        first.close()

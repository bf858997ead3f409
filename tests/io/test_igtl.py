"""The OpenIGTLink bridge with pyigtl's client over loopback, on a port the OS chooses.

pyigtl keeps only the latest message per device on the receiving side, so every check waits
(with a timeout) until the client's latest message is the expected one; no fixed sleeps.
"""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from collections.abc import Callable, Iterator
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
    IgtlRequest,
    check_device_name,
    wait_for_client,
)

TIMEOUT_S = 10.0


def _rigid(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    t = np.eye(4)
    t[:3, :3] = q
    t[:3, 3] = rng.uniform(-100, 100, size=3)
    return t


def wait_for(client: pyigtl.OpenIGTLinkClient, device: str, accept: Callable[[Any], bool]) -> Any:
    """The first message of ``device`` that ``accept`` takes, within TIMEOUT_S."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        msg = client.wait_for_message(device, timeout=0.05)
        if msg is not None and accept(msg):
            return msg
    pytest.fail(f"no acceptable {device} message within {TIMEOUT_S} s")


@pytest.fixture
def link() -> Iterator[tuple[IgtlBridge, pyigtl.OpenIGTLinkClient, list[IgtlRequest]]]:
    received: list[IgtlRequest] = []
    config = IgtlConfig(
        port=0, accepted_commands=frozenset({IgtlCommand.STOP, IgtlCommand.SAVE_VIEW})
    )
    bridge = IgtlBridge(config, on_command=received.append)
    try:
        with connected_client(bridge) as client:
            yield bridge, client, received
    finally:
        bridge.close()


@contextlib.contextmanager
def connected_client(bridge: IgtlBridge) -> Iterator[pyigtl.OpenIGTLinkClient]:
    """A real pyigtl client connected to ``bridge`` over loopback; stopped and closed after."""
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=bridge.port)
    try:
        assert wait_for_client(bridge, TIMEOUT_S)
        yield client
    finally:
        client.stop()
        if client.socket is not None:
            client.socket.close()


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
        msg = wait_for(client, name, lambda m: True)
        assert msg.device_name == name
        np.testing.assert_allclose(msg.matrix, expected, atol=1e-4)


def test_latest_pose_wins_when_many_are_queued(link: Any) -> None:
    bridge, client, _ = link
    rng = np.random.default_rng(2)
    poses = [_rigid(rng) for _ in range(50)]
    for pose in poses:
        bridge.send_pose(DEVICE_TIP_TO_BASE, pose)
    # The client may skip intermediate poses, but it ends on the newest one.
    msg = wait_for(
        client, DEVICE_TIP_TO_BASE, lambda m: np.allclose(m.matrix, poses[-1], atol=1e-4)
    )
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
    msg = wait_for(client, DEVICE_IMAGE, lambda m: True)
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
    wait_for(client, DEVICE_STATUS, lambda m: m.string == "homing")
    bridge.send_status({"mode": "knob", "fault": ""})
    msg = wait_for(client, DEVICE_STATUS, lambda m: m.string.startswith("{"))
    assert json.loads(msg.string) == {"fault": "", "mode": "knob"}


def _send_command(client: pyigtl.OpenIGTLinkClient, text: str) -> str:
    client.send_message(pyigtl.StringMessage(text, device_name=DEVICE_COMMAND), wait=True)
    return str(wait_for(client, DEVICE_COMMAND_ACK, lambda m: text in m.string).string)


def test_enabled_commands_reach_the_callback(link: Any) -> None:
    bridge, client, received = link
    assert _send_command(client, "save_view septum").startswith("accepted")
    assert _send_command(client, "stop").startswith("accepted")
    assert [(r.command, r.argument) for r in received] == [
        (IgtlCommand.SAVE_VIEW, "septum"),
        (IgtlCommand.STOP, ""),
    ]


def test_disabled_and_malformed_commands_are_rejected(link: Any) -> None:
    bridge, client, received = link
    ack = _send_command(client, "go_to_view septum")
    assert ack.startswith("rejected") and "not enabled" in ack
    ack = _send_command(client, "launch rockets")
    assert ack.startswith("rejected") and "unknown command" in ack
    ack = _send_command(client, "save_view")
    assert "needs a view name" in ack
    assert received == []
    assert bridge.rejected == ["go_to_view septum", "launch rockets", "save_view"]


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


def test_must_be_created_on_the_main_thread() -> None:
    errors: list[BaseException] = []

    def create() -> None:
        try:
            IgtlBridge(IgtlConfig(port=0))
        except BaseException as exc:  # collected for the assertion below
            errors.append(exc)

    t = threading.Thread(target=create)
    t.start()
    t.join()
    assert len(errors) == 1 and isinstance(errors[0], IgtlError)
    assert "main thread" in str(errors[0])


def test_close_restores_the_signal_handlers() -> None:
    before = signal.getsignal(signal.SIGINT)
    bridge = IgtlBridge(IgtlConfig(port=0))
    assert signal.getsignal(signal.SIGINT) is not before  # pyigtl installed its own
    bridge.close()
    assert signal.getsignal(signal.SIGINT) is before
    with pytest.raises(IgtlError, match="closed"):
        bridge.send_status("late")

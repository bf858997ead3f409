"""Tracker backends: the protocol, and the NDI Aurora backend over a mocked ndicapy layer.

scikit-surgerynditracker's ``NDITracker`` runs for real; only ``ndicapy`` (NDI's serial
command layer) is replaced by :class:`FakeAurora`, which answers the command set the way an
Aurora with two wired tools does, as scikit-surgerynditracker's own tests mock it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import ndicapy
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from icenav.devices.tracker import (
    NDIAuroraConfig,
    NDIAuroraTracker,
    ToolStatus,
    TrackerBackend,
    quaternion_to_transform,
)
from icenav.errors import ConfigurationError, TrackerError
from icenav.sim.tracker import EMTracker

Pose = tuple[float, float, float, float, float, float, float, float]


class FakeAurora:
    """ndicapy's functions for an Aurora with wired tools on port handles 0x0A and 0x0B."""

    def __init__(self, handles: tuple[int, ...] = (0x0A, 0x0B), probe_ok: bool = True):
        self.handles = list(handles)
        self.probe_ok = probe_ok
        self.commands: list[str] = []
        self.initialised: set[int] = set()
        self.enabled: set[int] = set()
        self.listing: list[int] = []
        self.frame = 100
        self.poses: dict[int, Pose | str] = {h: "MISSING" for h in handles}
        self.closed = False
        self.frozen = False

    # -- connection
    def ndiProbe(self, name: str) -> int:
        return ndicapy.NDI_OKAY if self.probe_ok else ndicapy.NDI_PROBE_FAIL

    def ndiOpen(self, name: str) -> str:
        self.port = name
        return "aurora-device"

    def ndiClose(self, device: str) -> None:
        self.closed = True

    def ndiGetError(self, device: str) -> int:
        return ndicapy.NDI_OKAY

    def ndiErrorString(self, errnum: int) -> str:
        return f"error {errnum}"

    def ndiVER(self, device: str, n: int) -> str:
        return "NDI AURORA\nFreeze Tag: AURORA Rev 009\n"

    # -- commands
    def ndiCommand(self, device: str, command: str) -> None:
        self.commands.append(command)
        if command == "PHSR:02":  # port handles to initialise
            self.listing = [h for h in self.handles if h not in self.initialised]
        elif command == "PHSR:03":  # initialised, not enabled
            self.listing = [h for h in self.handles if h in self.initialised - self.enabled]
        elif command.startswith("PINIT:"):
            self.initialised.add(int(command[6:8], 16))
        elif command.startswith("PENA:"):
            self.enabled.add(int(command[5:7], 16))
        elif command in ("BX:0801", "TX:0801") and not self.frozen:
            self.frame += 1

    def ndiGetPHSRNumberOfHandles(self, device: str) -> int:
        return len(self.listing)

    def ndiGetPHSRHandle(self, device: str, index: int) -> int:
        return self.listing[index]

    def ndiGetBXFrame(self, device: str, handle: bytes) -> int:
        return self.frame

    def ndiGetBXTransform(self, device: str, handle: bytes) -> Pose | str:
        return self.poses[handle[0]]

    def install(self, monkeypatch: pytest.MonkeyPatch) -> None:
        for name in dir(self):
            if name.startswith("ndi"):
                monkeypatch.setattr(ndicapy, name, getattr(self, name))


@pytest.fixture
def aurora(monkeypatch: pytest.MonkeyPatch) -> FakeAurora:
    fake = FakeAurora()
    fake.install(monkeypatch)
    return fake


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        self.t += 0.025
        return self.t


@pytest.fixture
def tracker(aurora: FakeAurora) -> Iterator[NDIAuroraTracker]:
    t = NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0"), clock=Clock())
    t.start()
    yield t
    t.stop()


def test_backends_satisfy_the_protocol() -> None:
    assert isinstance(NDIAuroraTracker(), TrackerBackend)
    assert issubclass(EMTracker, TrackerBackend)


def test_start_sends_the_aurora_command_sequence(aurora: FakeAurora) -> None:
    t = NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0"))
    t.start()
    assert aurora.port == "/dev/ttyNDI0"
    assert aurora.commands == [
        "INIT:",
        f"COMM:{ndicapy.NDI_115200:d}{ndicapy.NDI_8N1:03d}{ndicapy.NDI_NOHANDSHAKE:d}",
        "PHSR:02",  # find wired tools
        "PINIT:0a",
        "PINIT:0b",
        "PHSR:02",  # none left to initialise
        "PHSR:02",  # scikit-surgerynditracker's _initialise_ports
        "PINIT:0a",
        "PINIT:0b",
        "PHSR:03",  # enable the initialised tools, dynamic mode
        "PENA:0aD",
        "PENA:0bD",
        "TSTART:",
    ]
    t.stop()
    assert aurora.commands[-1] == "TSTOP:"
    assert aurora.closed


def test_valid_pose_is_converted_to_a_transform(
    aurora: FakeAurora, tracker: NDIAuroraTracker
) -> None:
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)  # 90 deg about z
    aurora.poses[0x0A] = (c, 0.0, 0.0, s, 10.0, -20.0, 150.0, 0.25)
    frame = tracker.get_frame()
    assert frame.status is ToolStatus.VALID
    assert frame.sensor2tracker is not None
    expected = np.array(
        [[0.0, -1.0, 0.0, 10.0], [1.0, 0.0, 0.0, -20.0], [0.0, 0.0, 1.0, 150.0], [0, 0, 0, 1]]
    )
    np.testing.assert_allclose(frame.sensor2tracker, expected, atol=1e-12)
    assert frame.quality == pytest.approx(1.0 / 1.25)


def test_missing_tool_is_missing_never_a_stale_pose(
    aurora: FakeAurora, tracker: NDIAuroraTracker
) -> None:
    aurora.poses[0x0A] = (1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 0.1)
    assert tracker.get_frame().status is ToolStatus.VALID
    aurora.poses[0x0A] = "MISSING"
    for _ in range(3):
        frame = tracker.get_frame()
        assert frame.status is ToolStatus.MISSING
        assert frame.sensor2tracker is None
        assert frame.quality == 0.0
    aurora.poses[0x0A] = "DISABLED"
    assert tracker.get_frame().status is ToolStatus.MISSING
    aurora.poses[0x0A] = (1.0, 0.0, 0.0, 0.0, 4.0, 5.0, 6.0, 0.1)
    frame = tracker.get_frame()
    assert frame.status is ToolStatus.VALID
    assert frame.sensor2tracker is not None
    np.testing.assert_allclose(frame.sensor2tracker[:3, 3], [4.0, 5.0, 6.0])


def test_second_tool_is_selectable(aurora: FakeAurora, monkeypatch: pytest.MonkeyPatch) -> None:
    aurora.poses[0x0B] = (1.0, 0.0, 0.0, 0.0, 7.0, 8.0, 9.0, 0.0)
    t = NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0", tool_index=1))
    t.start()
    frame = t.get_frame()
    t.stop()
    assert frame.status is ToolStatus.VALID and frame.quality == 1.0
    assert frame.sensor2tracker is not None
    np.testing.assert_allclose(frame.sensor2tracker[:3, 3], [7.0, 8.0, 9.0])


def test_same_tracker_frame_is_repeated_unchanged(
    aurora: FakeAurora, tracker: NDIAuroraTracker
) -> None:
    aurora.poses[0x0A] = (1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 0.1)
    first = tracker.get_frame()
    aurora.frozen = True  # the tracker has no newer sample (same frame number)
    assert tracker.get_frame() is first  # the same report, same timestamp
    aurora.frozen = False
    newer = tracker.get_frame()
    assert newer.timestamp > first.timestamp


def test_errors(aurora: FakeAurora, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(TrackerError, match="not started"):
        NDIAuroraTracker().get_frame()
    with pytest.raises(TrackerError, match="tool_index 2 does not exist.*2 wired tool"):
        NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/x", tool_index=2)).start()
    aurora.probe_ok = False
    with pytest.raises(TrackerError, match="cannot open the NDI Aurora"):
        NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0")).start()
    with pytest.raises(ConfigurationError, match="tool_index must be >= 0"):
        NDIAuroraConfig(tool_index=-1)


def test_settings_never_smooth() -> None:
    settings: dict[str, Any] = NDIAuroraConfig().as_nditracker_settings()
    assert settings["smoothing buffer"] == 1
    assert settings["use quaternions"] is True
    assert "serial port" not in settings


def test_quaternion_to_transform_matches_scipy() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        q = rng.normal(size=4)
        t = rng.uniform(-300, 300, size=3)
        got = quaternion_to_transform(q * rng.uniform(0.5, 2.0), t)
        ref = Rotation.from_quat(q, scalar_first=True).as_matrix()
        np.testing.assert_allclose(got[:3, :3], ref, atol=1e-12)
        np.testing.assert_allclose(got[:3, 3], t)
    with pytest.raises(TrackerError, match="invalid quaternion"):
        quaternion_to_transform(np.zeros(4), np.zeros(3))

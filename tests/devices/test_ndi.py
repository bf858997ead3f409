"""Tests of icenav.devices.ndi: the NDI Aurora backend over a mocked ndicapy layer.

scikit-surgerynditracker's ``NDITracker`` runs for real; only ``ndicapy`` (NDI's serial
command layer) is replaced by :class:`tests.support.ndi.FakeAurora`, which answers the command
set the way an Aurora with two wired tools does, as scikit-surgerynditracker's own tests mock it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import ndicapy
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from icenav.devices.ndi import NDIAuroraConfig, NDIAuroraTracker, quaternion_to_transform
from icenav.devices.registration import Registration
from icenav.devices.tracker import ToolStatus
from icenav.errors import ConfigurationError, TrackerError
from icenav.geometry.se3 import rigid_inverse
from tests.support.ndi import Clock, FakeAurora


@pytest.fixture
def aurora(monkeypatch: pytest.MonkeyPatch) -> FakeAurora:
    fake = FakeAurora()
    fake.install(monkeypatch)
    return fake


@pytest.fixture
def tracker(aurora: FakeAurora) -> Iterator[NDIAuroraTracker]:
    t = NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0"), clock=Clock())
    t.start()
    yield t
    t.stop()


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


def test_measure_averages_new_samples_and_maps_them_through_the_registration(
    aurora: FakeAurora, tracker: NDIAuroraTracker
) -> None:
    c, s = math.cos(math.pi / 8), math.sin(math.pi / 8)  # 45 deg about x
    aurora.poses[0x0A] = (c, s, 0.0, 0.0, 10.0, -20.0, 150.0, 0.2)
    before = len(aurora.commands)
    sensor = tracker.measure_sensor2tracker(4)
    assert sensor is not None
    frames = [c for c in aurora.commands[before:] if c == "BX:0801"]
    assert len(frames) == 4  # one frame read per new sample
    np.testing.assert_allclose(sensor[:3, 3], [10.0, -20.0, 150.0])
    assert tracker.registration is None
    assert tracker.measure_tip2base(4) is None  # not registered: no tip2base, no read
    t2b = np.eye(4)
    t2b[:3, 3] = [5.0, 0.0, -300.0]
    mount = np.eye(4)
    mount[:3, 3] = [-1.0, 0.0, -4.0]
    tracker.registration = Registration.given(t2b, mount)
    tip = tracker.measure_tip2base(2)
    assert tip is not None
    np.testing.assert_allclose(tip, t2b @ sensor @ rigid_inverse(mount), atol=1e-12)


def test_measure_with_the_tool_missing_is_none(
    aurora: FakeAurora, tracker: NDIAuroraTracker
) -> None:
    tracker.registration = Registration.given(np.eye(4), np.eye(4))
    assert tracker.measure_tip2base(3) is None
    aurora.poses[0x0A] = (1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 0.1)
    tip = tracker.measure_tip2base(3)
    assert tip is not None and np.allclose(tip[:3, 3], [1.0, 2.0, 3.0])


def test_a_frozen_tracker_is_an_error_not_a_hang(
    aurora: FakeAurora, monkeypatch: pytest.MonkeyPatch
) -> None:
    t = NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0", reads_per_sample=5))
    t.start()
    aurora.poses[0x0A] = (1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 0.1)
    t.get_frame()
    aurora.frozen = True
    with pytest.raises(TrackerError, match="no new sample in 5 frame reads"):
        t.measure_sensor2tracker(2)
    with pytest.raises(ConfigurationError, match=r"n_average must be an integer >= 1 \(samples\)"):
        t.measure_sensor2tracker(0)
    with pytest.raises(ConfigurationError, match="reads_per_sample"):
        NDIAuroraConfig(reads_per_sample=0)
    t.stop()

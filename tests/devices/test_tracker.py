"""Tests of icenav.devices.tracker: the one tracker protocol, satisfied by the twin's EM
tracker and by the NDI Aurora backend (over the mocked ndicapy command layer), both giving the
same ``tip2base`` through the same registration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from icenav.devices.ndi import NDIAuroraConfig, NDIAuroraTracker
from icenav.devices.registration import Registration
from icenav.devices.tracker import (
    PoseSampleBuffer,
    ToolStatus,
    TrackerBackend,
    TrackerFrame,
    check_n_average,
    mean_sensor_pose,
)
from icenav.errors import ConfigurationError
from icenav.sim import CatheterPlant, EMTracker
from tests.support.ndi import FakeAurora
from tests.support.twin import EXACT


@pytest.fixture
def aurora(monkeypatch: pytest.MonkeyPatch) -> FakeAurora:
    fake = FakeAurora()
    fake.install(monkeypatch)
    return fake


def test_both_backends_satisfy_the_protocol() -> None:
    plant = CatheterPlant(seed=1)
    assert isinstance(NDIAuroraTracker(), TrackerBackend)
    assert isinstance(EMTracker(plant, seed=1), TrackerBackend)


def test_the_twin_and_the_aurora_give_the_same_tip2base_for_the_same_sensor_pose(
    aurora: FakeAurora,
) -> None:
    """The twin's sensor pose (without its errors) sent through the mocked Aurora's wire
    format (quaternion, mm): the NDI backend's ``tip2base`` through the twin's registration is
    the plant's true tip, as the twin's own noise-free tracker reports it."""
    plant = CatheterPlant(seed=3)
    twin = EMTracker(plant, seed=3, config=EXACT)
    ndi = NDIAuroraTracker(NDIAuroraConfig(serial_port="/dev/ttyNDI0"))
    ndi.start()
    ndi.registration = twin.registration
    for q in ([0.0, 0.0, 0.0, 0.0], [0.7, -0.4, 1.1, 12.0], [-1.2, 0.3, -2.0, -20.0]):
        tip = plant.move(np.array(q))
        sensor = twin.true_sensor2tracker()
        quat = Rotation.from_matrix(sensor[:3, :3]).as_quat(scalar_first=True)
        aurora.poses[0x0A] = (*quat, *sensor[:3, 3], 0.1)  # type: ignore[assignment]
        from_ndi = ndi.measure_tip2base(2)
        from_twin = twin.measure_tip2base(2)
        assert from_ndi is not None and from_twin is not None
        np.testing.assert_allclose(from_ndi, tip, atol=1e-9)
        np.testing.assert_allclose(from_twin, tip, atol=1e-9)
    ndi.stop()


def test_the_twin_reports_no_tip2base_unregistered_and_uses_a_set_registration() -> None:
    plant = CatheterPlant(seed=4)
    twin = EMTracker(plant, seed=4)
    assert twin.registration is not None  # the twin's truth by default
    twin.registration = None
    assert twin.measure_tip2base(4) is None
    sensor = twin.measure_sensor2tracker(4)
    assert sensor is not None  # the sensor is still seen in the tracker frame
    shifted = np.eye(4)
    shifted[:3, 3] = [1.0, 2.0, 3.0]
    cfg = twin.config
    twin.registration = Registration.given(shifted @ cfg.tracker2base, cfg.sensor2tip)
    tip = twin.measure_tip2base(64)
    assert tip is not None
    # the tip moves with the registration it is given (the sample's noise aside)
    assert np.linalg.norm(tip[:3, 3] - plant.state.tip2base[:3, 3] - [1.0, 2.0, 3.0]) < 3.0


def test_mean_sensor_pose_skips_frames_without_a_pose() -> None:
    a = np.eye(4)
    b = np.eye(4)
    b[:3, 3] = [2.0, 0.0, 0.0]
    frames = [
        TrackerFrame(0.0, a, ToolStatus.VALID, 1.0),
        TrackerFrame(0.1, None, ToolStatus.MISSING, 0.0),
        TrackerFrame(0.2, b, ToolStatus.VALID, 1.0),
    ]
    mean = mean_sensor_pose(frames)
    assert mean is not None
    np.testing.assert_allclose(mean[:3, 3], [1.0, 0.0, 0.0])
    assert mean_sensor_pose(frames[1:2]) is None


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2", float("nan")])
def test_n_average_must_be_a_whole_number_of_samples(bad: object) -> None:
    with pytest.raises(ConfigurationError, match="n_average must be an integer >= 1"):
        check_n_average(bad)
    with pytest.raises(ConfigurationError, match="n_average"):
        EMTracker(CatheterPlant(seed=0)).measure_tip2base(bad)  # type: ignore[arg-type]


def test_the_sample_buffer_keeps_the_last_seconds_thinned_to_the_rate() -> None:
    buf = PoseSampleBuffer(capacity_s=2.0, max_rate_hz=50.0)
    assert buf.sample_window(1.0, 10.0)[0].shape == (0,)
    assert buf.span_s() == 0.0
    for k in range(500):  # 5 s at 100 Hz: every other sample kept, the last 2 s
        pose = np.eye(4)
        pose[0, 3] = k
        buf.push(0.01 * k, pose)
        buf.push(0.01 * k, None)  # no VALID sample: skipped
    assert len(buf) == 102
    assert buf.span_s() == pytest.approx(2.02)  # the 102 kept, 20 ms apart
    t, p = buf.sample_window(1.0, 10.0)
    assert len(t) == 10 and t[-1] == pytest.approx(4.98) and t[0] > 3.98
    assert np.all(np.diff(t) >= 0.1 - 1e-9)
    np.testing.assert_allclose(p[:, 0, 3], np.round(t / 0.01))
    with pytest.raises(ConfigurationError):
        buf.sample_window(0.0, 10.0)

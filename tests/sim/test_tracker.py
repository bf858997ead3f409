"""The simulated EM tracker: noise statistics, rate and latency, dropouts, volume, config."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError, TrackerError
from icenav.sim import CatheterPlant, EMTracker, ToolStatus, TrackerConfig
from icenav.sim.tracker import rotvec_to_matrix


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _rot_angle(r: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0)))


def test_total_error_matches_ndi_accuracy_over_the_volume() -> None:
    """Over many catheter poses and field generators: 1.4 mm / 0.5 deg RMS (within 15 %)."""
    rng = np.random.default_rng(0)
    pos_err, rot_err = [], []
    for seed in range(12):
        plant = CatheterPlant(seed=seed)
        tracker = EMTracker(plant, seed=seed, config=TrackerConfig(dropout_probability=0.0))
        for _ in range(60):
            q = [*rng.uniform(-1.4, 1.4, 2), rng.uniform(-3, 3), rng.uniform(-50, 50)]
            plant.move(q)
            true = tracker.true_sensor2tracker()
            frame = tracker._sample(0.0)
            assert frame.status is ToolStatus.VALID and frame.sensor2tracker is not None
            pos_err.append(np.linalg.norm(frame.sensor2tracker[:3, 3] - true[:3, 3]))
            rot_err.append(_rot_angle(true[:3, :3].T @ frame.sensor2tracker[:3, :3]))
    pos_rms = math.sqrt(np.mean(np.square(pos_err)))
    rot_rms = math.degrees(math.sqrt(np.mean(np.square(rot_err))))
    assert pos_rms == pytest.approx(math.hypot(1.3, 0.5), rel=0.15)
    assert rot_rms == pytest.approx(math.hypot(0.45, 0.2), rel=0.15)


def test_jitter_at_a_fixed_pose_matches_its_setting_and_bias_is_constant() -> None:
    plant = CatheterPlant(seed=1)
    plant.move([0.5, -0.3, 0.2, 0.0])
    cfg = TrackerConfig(dropout_probability=0.0)
    tracker = EMTracker(plant, seed=4, config=cfg)
    samples = np.stack([tracker._sample(0.0).sensor2tracker for _ in range(4000)])  # type: ignore[misc]
    true = tracker.true_sensor2tracker()
    bias, _ = tracker.distortion_at(true[:3, 3])
    mean = samples[:, :3, 3].mean(axis=0)
    np.testing.assert_allclose(mean - true[:3, 3], bias, atol=0.05)
    jitter = samples[:, :3, 3] - mean
    assert math.sqrt(np.mean(np.sum(jitter**2, axis=1))) == pytest.approx(0.5, rel=0.08)


def test_field_distortion_is_smooth_in_space() -> None:
    tracker = EMTracker(CatheterPlant(seed=0), seed=2)
    p = np.array([10.0, -20.0, 300.0])
    b0, _ = tracker.distortion_at(p)
    b1, _ = tracker.distortion_at(p + [1.0, 0.0, 0.0])
    far = np.random.default_rng(3).uniform(-200, 200, size=(500, 3)) + [0, 0, 300]
    spread = np.std(tracker.distortion_at(far)[0], axis=0)
    assert np.linalg.norm(b1 - b0) < 0.1  # 1 mm apart: almost the same bias
    assert np.all(spread > 0.3)  # across the volume the bias varies


def test_rate_latency_and_no_stale_valid_pose() -> None:
    clock = FakeClock()
    plant = CatheterPlant(seed=0)
    cfg = TrackerConfig(rate_hz=50.0, latency_s=0.01, dropout_probability=0.0)
    tracker = EMTracker(plant, seed=0, config=cfg, clock=clock)
    with pytest.raises(TrackerError, match="not running"):
        tracker.get_frame()
    tracker.start()
    assert tracker.get_frame().status is ToolStatus.MISSING  # nothing before the latency
    clock.now += 0.011
    first = tracker.get_frame()
    assert first.status is ToolStatus.VALID and first.timestamp == pytest.approx(100.0)
    clock.now += 0.005
    assert tracker.get_frame() is first  # no new sample before 1 / rate
    plant.move([0.6, 0.0, 0.0, 0.0])
    clock.now += 0.015
    second = tracker.get_frame()
    assert second.timestamp == pytest.approx(100.02)
    assert second.sensor2tracker is not None and first.sensor2tracker is not None
    assert np.linalg.norm(second.sensor2tracker[:3, 3] - first.sensor2tracker[:3, 3]) > 5.0
    tracker.stop()
    with pytest.raises(TrackerError):
        tracker.get_frame()


def test_dropouts_are_reported_missing_never_as_a_stale_pose() -> None:
    clock = FakeClock()
    cfg = TrackerConfig(rate_hz=100.0, dropout_probability=0.05, dropout_mean_samples=4.0)
    tracker = EMTracker(CatheterPlant(seed=0), seed=9, config=cfg, clock=clock)
    tracker.start()
    statuses = []
    for _ in range(20000):
        clock.now += 0.01
        frame = tracker.get_frame()
        statuses.append(frame.status)
        if frame.status is ToolStatus.MISSING:
            assert frame.sensor2tracker is None and frame.quality == 0.0
        else:
            assert frame.sensor2tracker is not None and 0.0 < frame.quality <= 1.0
    missing = np.mean([s is ToolStatus.MISSING for s in statuses])
    expected = 0.05 * 4.0 / (1.0 + 0.05 * 3.0)  # renewal: bursts of mean 4 started w.p. 0.05
    assert missing == pytest.approx(expected, rel=0.2)


def test_out_of_volume() -> None:
    far = np.eye(4)
    far[:3, 3] = [0.0, 0.0, -2000.0]  # the tracker frame 2 m away: the tip is out of range
    cfg = TrackerConfig(tracker2base=far, dropout_probability=0.0)
    tracker = EMTracker(CatheterPlant(seed=0), config=cfg)
    frame = tracker._sample(0.0)
    assert frame.status is ToolStatus.OUT_OF_VOLUME and frame.sensor2tracker is None


def test_measure_tip2base_maps_through_the_fixed_transforms() -> None:
    plant = CatheterPlant(seed=5)
    plant.move([0.4, 0.2, 1.0, 10.0])
    tracker = EMTracker(plant, seed=1, config=TrackerConfig(dropout_probability=0.0))
    measured = tracker.measure_tip2base(n_average=50)
    assert measured is not None
    true = plant.state.tip2base
    bias, rot_bias = tracker.distortion_at(tracker.true_sensor2tracker()[:3, 3])
    err = np.linalg.norm(measured[:3, 3] - true[:3, 3])
    assert err < 5.0 and err == pytest.approx(np.linalg.norm(bias), abs=0.6)
    assert _rot_angle(true[:3, :3].T @ measured[:3, :3]) < math.radians(2.0)
    none = EMTracker(plant, config=TrackerConfig(dropout_probability=0.999999))
    assert none.measure_tip2base(3) is None


def test_rotvec_to_matrix_is_a_rotation_by_the_angle() -> None:
    w = np.array([0.3, -0.2, 0.5])
    r = rotvec_to_matrix(w)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert _rot_angle(r) == pytest.approx(np.linalg.norm(w))
    np.testing.assert_allclose(r @ w, w, atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rate_hz": 0.0}, r"rate_hz must be finite and > 0 Hz, got 0.0 Hz"),
        ({"latency_s": -0.1}, r"latency_s must be finite and >= 0 s"),
        ({"position_jitter_rms_mm": math.inf}, r"position_jitter_rms_mm must be finite"),
        ({"dropout_probability": 1.0}, r"dropout_probability must be in \[0, 1\)"),
        ({"dropout_mean_samples": 0.5}, r"dropout_mean_samples must be >= 1"),
        ({"volume_min_mm": (0, 0, 0), "volume_max_mm": (1, 1, 0)}, "volume_min_mm must be below"),
        ({"sensor2tip": np.diag([2.0, 1.0, 1.0, 1.0])}, "sensor2tip is not a rigid transform"),
    ],
)
def test_bad_tracker_settings_are_rejected(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises((ConfigurationError, ValueError), match=match):
        TrackerConfig(**kwargs)  # type: ignore[arg-type]


def test_bad_seed_and_average_count_are_rejected() -> None:
    plant = CatheterPlant(seed=0)
    with pytest.raises(ConfigurationError, match="seed must be an integer >= 0"):
        EMTracker(plant, seed=-2)
    with pytest.raises(ConfigurationError, match="n_average must be an integer >= 1"):
        EMTracker(plant).measure_tip2base(0)

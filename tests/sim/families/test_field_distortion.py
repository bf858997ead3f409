"""The field-distortion tracker: errors that change with the sensor's orientation at a fixed
position and with the robot's roll, a 60-80 mm field, and the default tracker's sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.devices.tracker import ToolStatus
from icenav.errors import ConfigurationError, TrackerError
from icenav.geometry.kinematics import forward
from icenav.sim import CatheterPlant, EMTracker, TrackerConfig
from icenav.sim.families.field_distortion import DistortionConfig, FieldDistortionTracker
from icenav.sim.tracker import rotvec_to_matrix

QUIET = TrackerConfig(
    position_jitter_rms_mm=0.0, rotation_jitter_rms_rad=0.0, dropout_probability=0.0
)


def workspace_poses(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Sensor poses in the tracker frame over the catheter's workspace, and their q."""
    rng = np.random.default_rng(seed)
    q = np.column_stack(
        [
            rng.uniform(-1.4, 1.4, n),
            rng.uniform(-1.4, 1.4, n),
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(-40, 40, n),
        ]
    )
    cfg = TrackerConfig()
    s2t = np.linalg.inv(cfg.tracker2base) @ forward(q) @ cfg.sensor2tip
    return s2t, q


def test_the_error_changes_with_the_sensors_orientation_at_a_fixed_position() -> None:
    tracker = FieldDistortionTracker(CatheterPlant(seed=1), seed=201)
    s2t, q = workspace_poses(50, 0)
    rng = np.random.default_rng(1)
    changes = []
    for pose, qi in zip(s2t, q, strict=True):
        other = rotvec_to_matrix(rng.normal(size=3)) @ pose[:3, :3]
        a = tracker.distortion_at(pose[:3, 3], pose[:3, :3], qi[2], qi[3])[0]
        b = tracker.distortion_at(pose[:3, 3], other, qi[2], qi[3])[0]
        changes.append(np.linalg.norm(a - b))
    assert np.median(changes) > 0.3


def test_the_error_changes_with_the_robots_roll_at_a_fixed_sensor_pose() -> None:
    tracker = FieldDistortionTracker(CatheterPlant(seed=1), seed=202)
    s2t, q = workspace_poses(50, 2)
    changes = [
        np.linalg.norm(
            tracker.distortion_at(p[:3, 3], p[:3, :3], qi[2], qi[3])[0]
            - tracker.distortion_at(p[:3, 3], p[:3, :3], qi[2] + math.pi, qi[3])[0]
        )
        for p, qi in zip(s2t, q, strict=True)
    ]
    assert np.median(changes) > 0.05 and np.max(changes) > 0.3


def test_the_field_varies_at_a_60_to_80_mm_wavelength() -> None:
    """Two points 30 mm apart (about half a wavelength) see unrelated biases; the default
    tracker's 250 mm field barely changes over that distance."""
    ours = FieldDistortionTracker(CatheterPlant(seed=1), seed=203)
    assert 60.0 <= ours.wavelength_mm <= 80.0
    default = EMTracker(CatheterPlant(seed=1), seed=203)
    s2t, _ = workspace_poses(200, 3)
    rng = np.random.default_rng(4)
    step = rng.normal(size=(200, 3))
    step *= 30.0 / np.linalg.norm(step, axis=1, keepdims=True)

    def relative_change(bias: object) -> float:
        a = np.array([bias(p[:3, 3]) for p in s2t])  # type: ignore[operator]
        b = np.array([bias(p[:3, 3] + d) for p, d in zip(s2t, step, strict=True)])  # type: ignore[operator]
        return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)) / np.mean(np.sum(a**2, axis=1))))

    eye = np.eye(3)
    assert relative_change(lambda p: ours.distortion_at(p, eye, 0.0, -2000.0)[0]) > 0.9
    assert relative_change(lambda p: default.distortion_at(p)[0]) < 0.6


def test_the_total_error_is_that_of_an_em_tracker_in_a_clinical_room() -> None:
    """About the NDI 3D Guidance's 1.4 mm / 0.5 deg RMS over the workspace (with jitter)."""
    tracker = FieldDistortionTracker(CatheterPlant(seed=1), seed=204)
    s2t, q = workspace_poses(400, 5)
    errs = np.array(
        [
            tracker.distortion_at(p[:3, 3], p[:3, :3], qi[2], qi[3])
            for p, qi in zip(s2t, q, strict=True)
        ]
    )
    pos = math.hypot(float(np.sqrt(np.mean(np.sum(errs[:, 0] ** 2, axis=1)))), 0.5)
    rot = math.hypot(float(np.sqrt(np.mean(np.sum(errs[:, 1] ** 2, axis=1)))), math.radians(0.2))
    assert 0.9 < pos < 2.0
    assert math.radians(0.3) < rot < math.radians(0.8)


def test_measurements_carry_exactly_the_distortion_at_the_true_pose() -> None:
    plant = CatheterPlant(seed=5)
    tracker = FieldDistortionTracker(plant, seed=205, config=QUIET)
    tracker.start()  # the sampling clock: time.monotonic, only timestamps here
    q = np.array([0.7, -0.4, 2.0, 10.0])
    true = plant.move(q)
    s2t = tracker.true_sensor2tracker()
    bias_p, bias_r = tracker.distortion_at(s2t[:3, 3], s2t[:3, :3], q[2], q[3])
    measured = tracker.measure_tip2base(3)
    assert measured is not None
    meas_s2t = np.linalg.inv(QUIET.tracker2base) @ measured @ QUIET.sensor2tip
    np.testing.assert_allclose(meas_s2t[:3, 3], s2t[:3, 3] + bias_p, atol=1e-9)
    np.testing.assert_allclose(meas_s2t[:3, :3], rotvec_to_matrix(bias_r) @ s2t[:3, :3], atol=1e-9)
    assert np.linalg.norm(measured[:3, 3] - true[:3, 3]) > 0.05


def test_frames_follow_the_default_trackers_sampling() -> None:
    now = [0.0]
    plant = CatheterPlant(seed=6)
    tracker = FieldDistortionTracker(plant, seed=206, config=QUIET, clock=lambda: now[0])
    with pytest.raises(TrackerError):
        tracker.get_frame()
    tracker.start()
    assert tracker.get_frame().status is ToolStatus.MISSING  # before the first sample is due
    now[0] = 0.1
    a = tracker.get_frame()
    assert a.status is ToolStatus.VALID and 0.0 < a.quality <= 1.0
    plant.move([0.5, 0.0, 0.0, 0.0])
    assert tracker.get_frame() is a  # the same sample until a newer one is due
    now[0] = 0.2
    b = tracker.get_frame()
    assert b.timestamp > a.timestamp
    s2t = tracker.true_sensor2tracker()
    bias_p, _ = tracker.distortion_at(s2t[:3, 3], s2t[:3, :3], 0.0, 0.0)
    assert b.sensor2tracker is not None
    np.testing.assert_allclose(b.sensor2tracker[:3, 3], s2t[:3, 3] + bias_p, atol=1e-9)
    assert tracker.registration.tracker2base.shape == (4, 4)


def test_a_plant_without_joints_in_its_state_is_tracked_at_roll_zero() -> None:
    class Bare:
        class State:
            tip2base = forward(np.array([0.3, 0.2, 0.0, 0.0]))

        state = State()

    tracker = FieldDistortionTracker(Bare(), seed=207, config=QUIET)
    assert tracker.robot_joints() == (0.0, 0.0)
    assert tracker.measure_tip2base() is not None


def test_the_distortion_is_seeded() -> None:
    s2t, q = workspace_poses(5, 6)
    p, r = s2t[0][:3, 3], s2t[0][:3, :3]
    a = FieldDistortionTracker(CatheterPlant(seed=1), seed=208).distortion_at(p, r, 0.3)
    b = FieldDistortionTracker(CatheterPlant(seed=2), seed=208).distortion_at(p, r, 0.3)
    c = FieldDistortionTracker(CatheterPlant(seed=1), seed=209).distortion_at(p, r, 0.3)
    np.testing.assert_array_equal(a[0], b[0])
    assert np.linalg.norm(a[0] - c[0]) > 1e-3


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigurationError, match="wavelengths"):
        DistortionConfig(wavelength_min_mm=90.0, wavelength_max_mm=80.0)
    with pytest.raises(ConfigurationError, match="metal_position_mm"):
        DistortionConfig(metal_position_mm=-1.0)

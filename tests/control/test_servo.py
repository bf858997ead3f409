"""Tests of icenav.control.servo: the integral pose servo on the EM-tracked tip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.control.servo import PoseServoConfig, TipPoseServo, body_pose_error
from icenav.errors import ConfigurationError, InvalidValueError
from icenav.geometry.kinematics import forward


def _rot_z(a: float) -> np.ndarray:
    t = np.eye(4)
    t[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return t


def test_body_pose_error_of_known_offsets() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = np.array([*rng.uniform(-1.2, 1.2, 3), rng.uniform(-20, 20)])
        m = forward(q)
        assert np.allclose(body_pose_error(m, m, 30.0), 0.0, atol=1e-12)
        # a move of 2 mm along the tip's own x axis, and 3 deg about its own z axis
        t = m @ _rot_z(math.radians(3.0))
        t[:3, 3] += 2.0 * m[:3, 0]
        e = body_pose_error(t, m, 10.0)
        assert np.allclose(e[:3], [2.0, 0.0, 0.0], atol=1e-9)
        assert np.allclose(e[3:], [0.0, 0.0, 10.0 * math.radians(3.0)], atol=1e-9)


@pytest.mark.parametrize("seed", range(8))
def test_servo_removes_a_joint_offset_of_an_ideal_catheter(seed: int) -> None:
    """Plant = the model with an unknown joint offset; the servo drives the measured pose
    to the target, i.e. learns minus the offset (where the pose determines the joints)."""
    rng = np.random.default_rng(seed)
    q = np.array([*rng.uniform(0.3, 0.9, 2) * rng.choice([-1, 1], 2), rng.uniform(-2, 2), 5.0])
    offset = np.array([*np.radians(rng.uniform(-4, 4, 3)), rng.uniform(-1.5, 1.5)])
    target = forward(q)
    servo = TipPoseServo(PoseServoConfig(gain=0.5))
    before = np.linalg.norm(forward(q + offset)[:3, 3] - target[:3, 3])
    for _ in range(60):
        servo.update(q, target, forward(q + offset + servo.correction))
    reached = forward(q + offset + servo.correction)
    assert before > 0.5
    assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < 0.02
    assert np.allclose(body_pose_error(target, reached, 30.0), 0.0, atol=0.05)
    assert servo.n_updates == 60


def test_steps_and_correction_are_bounded_and_missing_holds() -> None:
    q = np.array([0.6, 0.2, 0.0, 0.0])
    target = forward(q)
    far = forward(q + np.array([0.5, -0.5, 0.5, 10.0]))
    cfg = PoseServoConfig(gain=1.0, max_step=(0.01, 0.01, 0.01, 0.1), max_correction=(0.03,) * 4)
    servo = TipPoseServo(cfg)
    c1 = servo.update(q, target, far)
    assert np.all(np.abs(c1) <= np.array(cfg.max_step) + 1e-12)
    for _ in range(20):
        c = servo.update(q, target, far)
    assert np.all(np.abs(c) <= 0.03 + 1e-12) and np.max(np.abs(c)) == pytest.approx(0.03)
    held = servo.update(q, target, None)
    assert np.array_equal(held, c) and servo.n_missing == 1
    servo.reset()
    assert np.array_equal(servo.correction, np.zeros(4)) and servo.n_updates == 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"gain": 0.0}, "gain"),
        ({"gain": 1.5}, "gain"),
        ({"rotation_weight_mm_per_rad": -1.0}, "rotation_weight"),
        ({"damping": math.nan}, "damping"),
        ({"max_step": (0.1, 0.1, 0.1)}, "max_step"),
        ({"max_correction": (0.1, 0.1, 0.0, 1.0)}, "max_correction"),
    ],
)
def test_bad_settings_are_refused(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        PoseServoConfig(**kwargs)  # type: ignore[arg-type]


def test_bad_inputs_are_refused() -> None:
    servo = TipPoseServo()
    q = np.zeros(4)
    with pytest.raises(ConfigurationError, match="q_model"):
        servo.update(np.zeros(3), np.eye(4), np.eye(4))
    with pytest.raises(InvalidValueError):
        servo.update(q, np.full((4, 4), np.nan), np.eye(4))
    with pytest.raises(ConfigurationError, match="PoseServoConfig"):
        TipPoseServo(config="fast")  # type: ignore[arg-type]

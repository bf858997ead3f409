"""Tests of icenav.compensation.tracker_bias: the affine field bias and the corrections it
makes (its fit from roll circles: tests/calibration/test_tracker_bias.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.compensation.elasticity import CalibrationSet
from icenav.compensation.tracker_bias import TrackerBias
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import forward


def test_shifted_path_puts_the_model_tip_at_p_minus_b() -> None:
    bias = TrackerBias(np.array([1.2, -0.7, 0.3]), np.diag([0.01, -0.02, 0.0]))
    t = np.linspace(0, 2 * math.pi, 50)
    q = np.stack([0.7 * np.cos(t), 0.7 * np.sin(t), -t, np.full_like(t, 3.0)], axis=-1)
    shifted = bias.shift_model_path(q)
    np.testing.assert_array_equal(shifted[:, 2:], q[:, 2:])
    p = forward(q, check=False)[:, :3, 3]
    want = p - bias.at(p)
    got = forward(shifted, check=False)[:, :3, 3]
    err = got - want
    # the two knobs move the tip on a surface: what is left is normal to it (least squares)
    for j in range(2):
        dq = shifted.copy()
        dq[:, j] += 1e-6
        tangent = (forward(dq, check=False)[:, :3, 3] - got) / 1e-6
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        assert np.max(np.abs(np.sum(err * tangent, axis=1))) < 1e-3
    assert np.max(np.linalg.norm(err, axis=1)) < 1.0
    assert np.max(np.linalg.norm(got - p, axis=1)) > 1.0  # it did move


def test_zero_bias_changes_nothing() -> None:
    q = np.array([[0.3, -0.2, 0.5, 1.0], [0.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(TrackerBias.none().shift_model_path(q), q, atol=1e-9)
    poses = forward(q)
    np.testing.assert_array_equal(TrackerBias.none().correct_poses(poses), poses)


def test_corrections_remove_the_bias_from_poses_and_sets() -> None:
    bias = TrackerBias(np.array([1.0, 2.0, -1.0]), np.zeros((3, 3)))
    q = np.array([[0.1, 0.2, 0.0, 0.0], [0.3, -0.1, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    poses = forward(q)
    measured = poses.copy()
    measured[:, :3, 3] += bias.offset_mm
    cal = CalibrationSet(q_motor=q, tip2base=measured, catheter_id="c1", method="dense-raster")
    fixed = bias.correct_calibration(cal)
    np.testing.assert_allclose(fixed.tip2base, poses, atol=1e-12)
    assert fixed.catheter_id == "c1" and fixed.method == "dense-raster+bias-removed"
    np.testing.assert_allclose(bias.correct_poses(measured), poses, atol=1e-12)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ShapeError):
        TrackerBias(np.zeros(2), np.zeros((3, 3)))
    with pytest.raises(ConfigurationError, match="mm/mm"):
        TrackerBias(np.zeros(3), np.eye(3))
    with pytest.raises(ShapeError):
        TrackerBias.none().shift_model_path(np.zeros((3, 3)))


def test_the_quadratic_term_adds_its_monomials_about_the_centre() -> None:
    quad = np.zeros((3, 6))
    quad[0, 0] = 1e-3  # x^2
    quad[1, 4] = -2e-3  # y z
    centre = np.array([5.0, -3.0, 60.0])
    bias = TrackerBias(
        np.array([0.5, 0.0, 0.0]), np.zeros((3, 3)), quadratic=quad, centre_mm=centre
    )
    x = np.array([[25.0, 7.0, 80.0], [5.0, -3.0, 60.0]])
    u = x - centre
    want = np.stack([0.5 + 1e-3 * u[:, 0] ** 2, -2e-3 * u[:, 1] * u[:, 2], 0 * u[:, 0]], axis=1)
    np.testing.assert_allclose(bias.at(x), want, atol=1e-12)
    # the correction still inverts x + b(x) = m
    m = x + bias.at(x)
    np.testing.assert_allclose(bias.correct_positions(m), x, atol=1e-6)


def test_a_bad_quadratic_term_is_refused() -> None:
    with pytest.raises(ShapeError, match="quadratic"):
        TrackerBias(np.zeros(3), np.zeros((3, 3)), quadratic=np.zeros((3, 3)))
    with pytest.raises(ConfigurationError, match="mm/mm\\^2"):
        TrackerBias(np.zeros(3), np.zeros((3, 3)), quadratic=np.full((3, 6), 0.1))
    with pytest.raises(ShapeError, match="centre_mm"):
        TrackerBias(np.zeros(3), np.zeros((3, 3)), centre_mm=np.zeros(2))

"""Tests of icenav.geometry.se3 against scipy's rotations and analytic cases (uniform,
near-identity and near-pi rotations)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from icenav.errors import ShapeError
from icenav.geometry.se3 import (
    body_pose_error,
    pose_mean,
    rigid_inverse,
    rotation_angle,
    rotation_log,
    rotvec_to_matrix,
    vee,
)


def _poses(rng: np.random.Generator, n: int, scale: float = math.pi) -> np.ndarray:
    """Random poses: rotation vectors of norm up to ``scale`` (uniform directions)."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0.0, scale, n)
    t = np.tile(np.eye(4), (n, 1, 1))
    t[:, :3, :3] = Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    t[:, :3, 3] = rng.uniform(-100.0, 100.0, (n, 3))
    return t


def test_rigid_inverse_is_the_matrix_inverse() -> None:
    t = _poses(np.random.default_rng(0), 50)
    np.testing.assert_allclose(rigid_inverse(t) @ t, np.tile(np.eye(4), (50, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(rigid_inverse(t[3]), np.linalg.inv(t[3]), atol=1e-12)


@pytest.mark.parametrize("scale", [1e-7, 1e-3, 1.0, math.pi - 1e-6])
def test_rotation_angle_and_log_match_scipy(scale: float) -> None:
    rng = np.random.default_rng(1)
    a = _poses(rng, 40)[:, :3, :3]
    rel = _poses(rng, 40, scale)[:, :3, :3]
    b = a @ rel
    want = Rotation.from_matrix(rel).magnitude()
    np.testing.assert_allclose(rotation_angle(a, b), want, rtol=1e-6, atol=1e-12)
    if scale < 3.0:  # the log's axis is not unique at pi
        np.testing.assert_allclose(
            rotation_log(rel), Rotation.from_matrix(rel).as_rotvec(), rtol=1e-6, atol=1e-12
        )


def test_rotvec_to_matrix_round_trips_with_the_log() -> None:
    rng = np.random.default_rng(2)
    for w in rng.normal(size=(50, 3)):
        w *= min(1.0, 3.0 / np.linalg.norm(w))
        r = rotvec_to_matrix(w)
        np.testing.assert_allclose(r, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(rotation_log(r), w, atol=1e-10)
    np.testing.assert_array_equal(rotvec_to_matrix(np.zeros(3)), np.eye(3))
    np.testing.assert_allclose(vee(rotvec_to_matrix(np.array([0.0, 0.0, 0.3]))),
                               [0.0, 0.0, 2 * math.sin(0.3)], atol=1e-12)  # fmt: skip


def test_body_pose_error_of_known_offsets_one_and_batch_agree() -> None:
    rng = np.random.default_rng(3)
    reached = _poses(rng, 30)
    twists = rng.normal(size=(30, 6)) * [2, 2, 2, 0.2, 0.2, 0.2]
    step = np.tile(np.eye(4), (30, 1, 1))
    step[:, :3, :3] = Rotation.from_rotvec(twists[:, 3:]).as_matrix()
    step[:, :3, 3] = twists[:, :3]
    target = reached @ step  # the twist expressed in the reached tip frame
    batch = body_pose_error(target, reached, 30.0)
    np.testing.assert_allclose(batch[:, :3], twists[:, :3], atol=1e-9)
    np.testing.assert_allclose(batch[:, 3:], 30.0 * twists[:, 3:], atol=1e-8)
    for i in range(30):
        np.testing.assert_allclose(body_pose_error(target[i], reached[i], 30.0), batch[i],
                                   atol=1e-10)  # fmt: skip
    np.testing.assert_array_equal(body_pose_error(reached[0], reached[0]), np.zeros(6))


def test_pose_mean_of_jittered_samples() -> None:
    rng = np.random.default_rng(4)
    centre = _poses(rng, 1)[0]
    jitter = np.tile(np.eye(4), (200, 1, 1))
    jitter[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.01, (200, 3))).as_matrix()
    jitter[:, :3, 3] = rng.normal(0, 0.5, (200, 3))
    mean = pose_mean(centre @ jitter)
    assert float(rotation_angle(mean[:3, :3], centre[:3, :3])) < 0.003
    assert np.linalg.norm(mean[:3, 3] - centre[:3, 3]) < 0.2
    np.testing.assert_allclose(mean[:3, :3] @ mean[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(mean[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_array_equal(pose_mean(centre[None]), centre)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ShapeError, match=r"\(n >= 1, 4, 4\)"):
        pose_mean(np.eye(4))
    with pytest.raises(ShapeError, match=r"\(3,\)"):
        rotvec_to_matrix(np.zeros(4))
    with pytest.raises(ShapeError, match=r"\(\.\.\., 3, 3\)"):
        rotation_angle(np.eye(4), np.eye(3))

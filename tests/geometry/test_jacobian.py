"""Tests of icenav.geometry.jacobian: the analytic body Jacobian against finite differences,
its fast path against the batch path, and the tip-frame jog."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from icenav.errors import ConfigurationError, JointLimitError, NonFiniteError, ShapeError
from icenav.geometry.jacobian import jacobian, tip_jog
from icenav.geometry.kinematics import CatheterGeometry, forward
from tests.support.geometry import random_q

G = CatheterGeometry()


def body_twist_fd(q: np.ndarray, j: int, h: float = 1e-6) -> np.ndarray:
    """Central finite difference of T^-1 dT/dq_j, read as (v, w) with scipy log maps."""
    dq = np.zeros(4)
    dq[j] = h
    t0_inv = np.linalg.inv(forward(q, check=False))
    tp = t0_inv @ forward(q + dq, check=False)
    tm = t0_inv @ forward(q - dq, check=False)
    v = (tp[:3, 3] - tm[:3, 3]) / (2 * h)
    w = (
        Rotation.from_matrix(tp[:3, :3]).as_rotvec() - Rotation.from_matrix(tm[:3, :3]).as_rotvec()
    ) / (2 * h)
    return np.concatenate([v, w])


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(6)
    qs = np.vstack([random_q(rng, 60), [[0.0, 0.0, 0.3, 1.0], [1e-4, -2e-4, 0.0, 0.0]]])
    for q in qs:
        jac = jacobian(q)
        fd = np.column_stack([body_twist_fd(q, j) for j in range(4)])
        np.testing.assert_allclose(jac, fd, atol=2e-6 * max(1.0, np.abs(fd).max()))
    batch = jacobian(qs)
    assert batch.shape == (len(qs), 6, 4)
    np.testing.assert_allclose(batch[5], jacobian(qs[5]), atol=1e-12)


def test_jacobian_scalar_path_equals_the_batch_path() -> None:
    """One joint state takes a plain-float fast path; it must agree with the batch path
    everywhere, including the series branch near the straight catheter."""
    rng = np.random.default_rng(16)
    qs = random_q(rng, 400)
    qs[:40, :2] *= 1e-5  # below the series threshold
    qs[40:45, :2] = 0.0
    batch = jacobian(qs)
    for q, jb in zip(qs, batch, strict=True):
        np.testing.assert_allclose(jacobian(q), jb, rtol=0, atol=1e-12)


def test_tip_jog_reproduces_achievable_twists() -> None:
    rng = np.random.default_rng(7)
    for q in random_q(rng, 40) * [0.9, 0.9, 1.0, 0.5]:
        dq_true = rng.normal(scale=[0.2, 0.2, 0.3, 2.0])
        twist = jacobian(q) @ dq_true
        dq = tip_jog(q, twist, dt=1e-3)
        np.testing.assert_allclose(jacobian(q) @ dq, twist, atol=1e-3 * np.abs(twist).max())


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_tip_jog_moves_tip_in_the_asked_direction(axis: int) -> None:
    q = np.array([0.5, 0.2, 0.3, 0.0])
    twist = np.zeros(6)
    twist[axis] = 5.0  # 5 mm/s along a tip axis
    dt = 1e-3
    dq = tip_jog(q, twist, dt=dt)
    t0 = forward(q)
    t1 = forward(q + dq * dt)
    moved_in_tip = t0[:3, :3].T @ (t1[:3, 3] - t0[:3, 3])
    direction = np.zeros(3)
    direction[axis] = 1.0
    # the tip moves mostly along the asked axis (4 joints cannot make every 6-D twist)
    assert moved_in_tip @ direction > 0.5 * np.linalg.norm(moved_in_tip)


def test_tip_jog_respects_joint_limits() -> None:
    q = np.array([G.knob_limit, 0.0, 0.0, 49.99])
    dt = 0.01
    rng = np.random.default_rng(8)
    for _ in range(50):
        twist = rng.normal(scale=[20, 20, 20, 1, 1, 1])
        dq = tip_jog(q, twist, dt=dt)
        nxt = q + dq * dt
        assert nxt[0] <= G.knob_limit + 1e-12
        assert nxt[3] <= 50.0 + 1e-12


def test_the_old_import_path_still_resolves() -> None:
    from icenav.geometry import kinematics

    assert kinematics.jacobian is jacobian and kinematics.tip_jog is tip_jog
    import icenav

    assert icenav.jacobian is jacobian and icenav.tip_jog is tip_jog


def test_bad_input_is_refused() -> None:
    with pytest.raises(JointLimitError, match="phi2"):
        jacobian([0, -1.6, 0, 0])
    with pytest.raises(ShapeError, match="twist_tip"):
        tip_jog([0, 0, 0, 0], [1.0, 2.0, 3.0])
    with pytest.raises(NonFiniteError, match="twist_tip"):
        tip_jog([0, 0, 0, 0], [np.nan] * 6)
    with pytest.raises(ConfigurationError, match="dt"):
        tip_jog([0, 0, 0, 0], [0] * 6, dt=0.0)

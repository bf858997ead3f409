"""Tests of icenav.geometry.kinematics against independent computations and analytic cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from icenav.errors import (
    ConfigurationError,
    JointLimitError,
    NonFiniteError,
    ShapeError,
    TransformError,
    UnreachablePoseError,
)
from icenav.geometry.kinematics import (
    CatheterGeometry,
    backbone,
    bend_to_knobs,
    forward,
    inverse,
    inverse_with_residual,
    knobs_to_bend,
)
from tests.support.geometry import random_q

G = CatheterGeometry()
HALF_PI = math.pi / 2


def rot_z(angle: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.from_rotvec([0.0, 0.0, angle]).as_matrix()
    return t


def trans_z(d: float) -> np.ndarray:
    t = np.eye(4)
    t[2, 3] = d
    return t


def integrate_arc(q: np.ndarray, geometry: CatheterGeometry, steps: int = 4000) -> np.ndarray:
    """Independent FK: walk the bending section as many small rigid steps.

    Each step rotates by half the step's bend about the bending axis, moves ds along the
    local z axis, and rotates the other half (a midpoint rule), using scipy's rotation
    vectors rather than the closed form.
    """
    k = geometry.knob_ratio
    alpha = k * math.hypot(q[0], q[1])
    theta = math.atan2(q[1], q[0])
    axis = np.array([-math.sin(theta), math.cos(theta), 0.0])
    ds = geometry.bending_length / steps
    half = Rotation.from_rotvec(axis * (alpha / steps) / 2).as_matrix()
    frame = np.eye(4)
    step = np.eye(4)
    step[2, 3] = ds
    half_t = np.eye(4)
    half_t[:3, :3] = half
    for _ in range(steps):
        frame = frame @ half_t @ step @ half_t
    return trans_z(q[3]) @ rot_z(q[2]) @ frame @ trans_z(geometry.us_offset)


# --- forward ---------------------------------------------------------------------------


def test_forward_matches_independent_arc_integration() -> None:
    rng = np.random.default_rng(1)
    geometries = [G, CatheterGeometry(bending_length=45.0, knob_radius=2.0, us_offset=4.0)]
    for geometry in geometries:
        for q in random_q(rng, 12, geometry):
            expected = integrate_arc(q, geometry)
            got = forward(q, geometry)
            np.testing.assert_allclose(got[:3, 3], expected[:3, 3], atol=1e-5)
            np.testing.assert_allclose(got[:3, :3], expected[:3, :3], atol=1e-7)


@pytest.mark.parametrize(
    ("q", "position"),
    [
        # straight: tip at L + us_offset along z
        ((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 70.0)),
        ((0.0, 0.0, 1.0, 12.5), (0.0, 0.0, 82.5)),
        # pure AP bend of 90 deg: r = 2L/pi, end of arc (r, 0, r), image centre +10 mm along x
        ((HALF_PI, 0.0, 0.0, 0.0), (120 / math.pi + 10, 0.0, 120 / math.pi)),
        ((-HALF_PI, 0.0, 0.0, 0.0), (-120 / math.pi - 10, 0.0, 120 / math.pi)),
        # pure RL bend of 90 deg bends in +y
        ((0.0, HALF_PI, 0.0, 0.0), (0.0, 120 / math.pi + 10, 120 / math.pi)),
        # AP bend of 90 deg rolled by 90 deg about the base z axis ends up in +y
        ((HALF_PI, 0.0, HALF_PI, 0.0), (0.0, 120 / math.pi + 10, 120 / math.pi)),
    ],
)
def test_forward_analytic_cases(q: tuple[float, ...], position: tuple[float, ...]) -> None:
    np.testing.assert_allclose(forward(q)[:3, 3], position, atol=1e-9)


def test_pure_ap_bend_orientation() -> None:
    # After a 90 deg AP bend the catheter axis (tip z) points along base +x.
    t = forward([HALF_PI, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(t[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(t[:3, 0], [0.0, 0.0, -1.0], atol=1e-12)


def test_forward_is_exact_and_smooth_at_zero_bend() -> None:
    t0 = forward([0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(t0[:3, :3], np.eye(3))
    for eps in [1e-14, 1e-10, 1e-7, 1e-4, 9.99e-3, 1.001e-2]:
        q = np.array([eps, -0.5 * eps, 0.2, 0.0])
        t = forward(q)
        assert np.all(np.isfinite(t))
        np.testing.assert_allclose(t, integrate_arc(q, G, steps=200), atol=1e-9)
    # continuity across the series/closed-form switch, in the batch and scalar paths
    qs = np.array([[x, 0.3 * x, 0.0, 0.0] for x in np.linspace(0.9e-3, 1.1e-2, 101)])
    tb = forward(qs)
    ts = np.array([forward(q) for q in qs])
    np.testing.assert_allclose(tb, ts, atol=1e-13)
    # no jump at the switch: third differences of the position stay at rounding level
    assert np.all(np.abs(np.diff(tb[:, :3, 3], n=3, axis=0)) < 1e-10)


def test_forward_batch_shapes_and_agreement() -> None:
    rng = np.random.default_rng(2)
    q = random_q(rng, 24).reshape(2, 3, 4, 4)
    t = forward(q)
    assert t.shape == (2, 3, 4, 4, 4)
    for idx in np.ndindex(2, 3, 4):
        np.testing.assert_allclose(t[idx], forward(q[idx]), atol=1e-12)


def test_forward_returns_rigid_transforms() -> None:
    t = forward(random_q(np.random.default_rng(3), 500))
    r = t[:, :3, :3]
    np.testing.assert_allclose(
        np.swapaxes(r, 1, 2) @ r, np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (500, 4)))


def test_bend_parameters_round_trip() -> None:
    alpha, theta = knobs_to_bend(0.3, -0.4)
    assert alpha == pytest.approx(0.5)
    phi1, phi2 = bend_to_knobs(alpha, theta)
    assert (float(phi1), float(phi2)) == pytest.approx((0.3, -0.4))


# --- inverse ---------------------------------------------------------------------------

knob = st.floats(-HALF_PI, HALF_PI, allow_nan=False)
roll = st.floats(-math.pi + 1e-9, math.pi, allow_nan=False)
trans = st.floats(-50.0, 50.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(knob, knob, roll, trans)
def test_inverse_of_forward_is_identity(phi1: float, phi2: float, phi3: float, d4: float) -> None:
    q = np.array([phi1, phi2, phi3, d4])
    t = forward(q)
    if math.hypot(phi1, phi2) > 1e-6:  # unique for alpha > 0
        q_back = inverse(t)
        np.testing.assert_allclose(q_back[[0, 1, 3]], q[[0, 1, 3]], atol=1e-7)
        assert math.remainder(q_back[2] - phi3, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
    # FK of IK of FK reproduces the pose everywhere, alpha = 0 included
    np.testing.assert_allclose(forward(inverse(t)), t, atol=1e-7)
    np.testing.assert_allclose(forward(inverse(t, check=False)), t, atol=1e-7)


def test_inverse_batch_and_scalar_agree() -> None:
    q = random_q(np.random.default_rng(4), 300)
    t = forward(q)
    qb = inverse(t)
    qs = np.array([inverse(x, check=False) for x in t])
    np.testing.assert_allclose(qb, qs, atol=1e-9)
    np.testing.assert_allclose(qb, q, atol=1e-8)


def test_inverse_zero_bend_convention() -> None:
    q = inverse(forward([0.0, 0.0, 0.7, -3.0]))
    np.testing.assert_allclose(q, [0.0, 0.0, 0.7, -3.0], atol=1e-12)


def test_inverse_phi3_near_picks_the_nearest_turn() -> None:
    t = forward([0.2, 0.1, 0.5, 0.0])
    q = inverse(t, phi3_near=4 * math.pi)
    assert q[2] == pytest.approx(4 * math.pi + 0.5)
    q = inverse(t, check=False, phi3_near=-2 * math.pi)
    assert q[2] == pytest.approx(-2 * math.pi + 0.5)


def test_unreachable_pose_raises_or_gives_nearest() -> None:
    t = forward([0.6, -0.3, 0.4, 5.0])
    off = t.copy()
    off[:3, 3] += 3.0 * t[:3, 1]  # move the image centre 3 mm sideways: off the 4-D set
    with pytest.raises(UnreachablePoseError, match="not reachable") as info:
        inverse(off)
    assert info.value.position_residual_mm > 0.5
    sol = inverse_with_residual(off)
    assert not sol.reachable

    # the answer is a local minimum of the documented metric |dp|^2 + (L |dr|)^2
    def cost(q: np.ndarray) -> float:
        reached = forward(q)
        dp = np.linalg.norm(reached[:3, 3] - off[:3, 3])
        rel = reached[:3, :3].T @ off[:3, :3]
        dr = Rotation.from_matrix(rel).magnitude()
        return float(dp**2 + (G.bending_length * dr) ** 2)

    best = cost(sol.q)
    rng = np.random.default_rng(5)
    for _ in range(50):
        dq = rng.normal(scale=[1e-3, 1e-3, 1e-3, 1e-2])
        assert cost(sol.q + dq) >= best - 1e-9
    closed_form = inverse(off, check=False)
    assert best <= cost(closed_form) + 1e-9
    np.testing.assert_allclose(inverse(off, unreachable="nearest"), sol.q)


def test_pose_beyond_knob_limit_is_unreachable() -> None:
    wide = CatheterGeometry(knob_limit=2.0)
    t = forward([1.9, 0.0, 0.0, 0.0], wide)
    with pytest.raises(UnreachablePoseError):
        inverse(t, G)
    q = inverse(t, G, unreachable="nearest")
    assert abs(q[0]) <= G.knob_limit + 1e-12


# --- Jacobian --------------------------------------------------------------------------


# --- tip_jog ---------------------------------------------------------------------------


# --- backbone --------------------------------------------------------------------------


def test_backbone_ends_at_the_bending_section_end() -> None:
    q = np.array([0.8, -0.4, 1.1, 7.0])
    bb = backbone(q, n=41)
    assert bb.points_in_base.shape == (41, 3)
    np.testing.assert_allclose(bb.points_in_base[0], [0.0, 0.0, 7.0], atol=1e-12)
    end = bb.tip2base[:3, 3] - G.us_offset * bb.tip2base[:3, 2]
    np.testing.assert_allclose(bb.points_in_base[-1], end, atol=1e-9)
    seg = np.linalg.norm(np.diff(bb.points_in_base, axis=0), axis=1)
    # equal arc-length spacing: chords of L/40 on a circle of radius L/alpha
    assert seg.sum() == pytest.approx(G.bending_length, rel=1e-3)
    np.testing.assert_allclose(seg, seg[0], rtol=1e-9)


# --- bad input -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("q", "error", "match"),
    [
        ([np.nan, 0, 0, 0], NonFiniteError, "finite"),
        ([0, np.inf, 0, 0], NonFiniteError, "finite"),
        ([0, 0, 0], ShapeError, r"shape \(4,\)"),
        ([[0, 0, 0]], ShapeError, "shape"),
        ("abc", ShapeError, "numeric"),
        ([1.7, 0, 0, 0], JointLimitError, r"phi1 = 1\.7 rad \(97\.40 deg\).*\[-90\.0, 90\.0\] deg"),
        ([0, -1.6, 0, 0], JointLimitError, "phi2"),
        ([0, 0, 0, 60.0], JointLimitError, r"d4 = 60 mm .*\[-50, 50\] mm"),
    ],
)
def test_bad_joint_states_are_rejected(q: object, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        forward(q)  # type: ignore[arg-type]


def test_joint_limit_error_carries_context() -> None:
    with pytest.raises(JointLimitError) as info:
        forward([0.0, 2.0, 0.0, 0.0])
    assert (info.value.joint, info.value.value) == ("phi2", 2.0)
    assert info.value.high == pytest.approx(HALF_PI)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    ("matrix", "error", "match"),
    [
        (np.eye(3), ShapeError, r"\(4, 4\)"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), TransformError, "not a rigid transform"),
        (np.diag([-1.0, 1.0, 1.0, 1.0]), TransformError, "det R"),
        (np.full((4, 4), np.nan), NonFiniteError, "finite"),
    ],
)
def test_bad_transforms_are_rejected(
    matrix: np.ndarray, error: type[Exception], match: str
) -> None:
    with pytest.raises(error, match=match):
        inverse(matrix)


def test_bad_options() -> None:
    with pytest.raises(ConfigurationError, match="unreachable"):
        inverse(np.eye(4), unreachable="maybe")  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="n must be"):
        backbone([0, 0, 0, 0], n=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bending_length": 0.0}, "bending_length must be finite and > 0 mm"),
        ({"knob_radius": -1.0}, "knob_radius"),
        ({"catheter_radius": float("nan")}, "catheter_radius"),
        ({"us_offset": -2.0}, "us_offset"),
        ({"knob_limit": 4.0}, r"knob_limit must be in \(0, pi\]"),
        ({"knob_limit": 3.0}, "180 deg"),
        ({"translation_limits": (10.0, 50.0)}, "lower <= 0 <= upper"),
        ({"translation_limits": "ab"}, "two numbers"),
    ],
)
def test_bad_geometry_is_rejected(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        CatheterGeometry(**kwargs)  # type: ignore[arg-type]


def test_geometry_limits_table() -> None:
    lim = G.joint_limits
    assert lim.shape == (4, 2)
    assert lim[2, 0] == -np.inf and lim[2, 1] == np.inf
    with pytest.raises(ValueError, match="read-only"):
        lim[0, 0] = 0.0

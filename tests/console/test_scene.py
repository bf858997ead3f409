"""Tests of the console's scene geometry (no browser, no server)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from viser import transforms as vtf

from icenav.console.scene import (
    MM_TO_SCENE,
    AnatomyMesh,
    RoadmapTrail,
    as_anatomy_meshes,
    catheter_scene,
    image_plane_pose,
    matrix_to_wxyz,
    pose_to_scene,
    subsample,
    tube_mesh,
    view_marker_positions,
)
from icenav.control.state import ControllerState, Mode, ViewSummary
from icenav.devices.robot import RobotStatus
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import backbone, forward


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def _state(q: np.ndarray, **kw: object) -> ControllerState:
    tip = forward(q)
    bb = backbone(q, n=20).points_in_base
    base: dict[str, object] = dict(
        time=1.0,
        cycle=100,
        mode=Mode.IDLE,
        robot_status=RobotStatus.ENABLED,
        q_motor=q,
        q_model=q,
        tip2base_model=tip,
        backbone_model=bb,
    )
    base.update(kw)
    return ControllerState(**base)  # type: ignore[arg-type]


def test_matrix_to_wxyz_matches_viser_on_random_and_special_rotations() -> None:
    rng = np.random.default_rng(0)
    rotations = [_random_rotation(rng) for _ in range(300)]
    # near the trace <= 0 branches: rotations by ~pi about each axis and a diagonal
    for axis in (np.eye(3)[0], np.eye(3)[1], np.eye(3)[2], np.ones(3) / math.sqrt(3)):
        for angle in (math.pi, math.pi - 1e-6, 2.5, 1e-9):
            rotations.append(vtf.SO3.exp(axis * angle).as_matrix())
    for r in rotations:
        q = matrix_to_wxyz(r)
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        # independent reference: viser's own SO3 back to a matrix
        np.testing.assert_allclose(vtf.SO3(q).as_matrix(), r, atol=1e-9)


def test_matrix_to_wxyz_rejects_bad_shape() -> None:
    with pytest.raises(ShapeError, match=r"\(3, 3\)"):
        matrix_to_wxyz(np.eye(4))


def test_pose_to_scene_scales_position_only() -> None:
    t = forward(np.array([0.4, -0.3, 1.0, 12.0]))
    p = pose_to_scene(t)
    np.testing.assert_allclose(p.position, t[:3, 3] * MM_TO_SCENE)
    np.testing.assert_allclose(vtf.SO3(p.wxyz).as_matrix(), t[:3, :3], atol=1e-12)
    with pytest.raises(ShapeError, match=r"\(4, 4\)"):
        pose_to_scene(np.eye(3))


def test_subsample_keeps_ends_and_bounds_count() -> None:
    rng = np.random.default_rng(1)
    for n in (1, 2, 5, 100, 1001):
        pts = rng.standard_normal((n, 3))
        for m in (2, 3, 50, 2000):
            out = subsample(pts, m)
            assert len(out) <= max(m, 0) or len(out) == n
            assert len(out) == min(n, m)
            np.testing.assert_array_equal(out[0], pts[0])
            np.testing.assert_array_equal(out[-1], pts[-1])
            # every output point is one of the input points, in order
            idx = [int(np.flatnonzero((pts == p).all(axis=1))[0]) for p in out]
            assert idx == sorted(idx)
    with pytest.raises(ConfigurationError, match="max_points"):
        subsample(np.zeros((3, 3)), 1)


@pytest.mark.parametrize("seed", range(5))
def test_tube_vertices_lie_on_the_circle_normal_to_the_backbone(seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = np.array([*rng.uniform(-1.4, 1.4, 2), rng.uniform(-3, 3), rng.uniform(-40, 40)])
    centre = backbone(q, n=25).points_in_base
    radius, sides = 1.65, 10
    v, f = tube_mesh(centre, radius, sides)
    assert v.shape == (25 * sides, 3) and f.shape == (2 * 24 * sides, 3)
    assert f.min() == 0 and f.max() == len(v) - 1
    rings = v.reshape(25, sides, 3).astype(np.float64)
    offsets = rings - centre[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=2), radius, rtol=1e-5)
    # each ring lies in the plane normal to the local tangent of the (smooth) arc
    tangent = np.gradient(centre, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    cos = np.abs(np.einsum("nsk,nk->ns", offsets / radius, tangent))
    assert cos[1:-1].max() < 0.05
    # faces point outwards: the normal of each triangle points away from the axis
    tri = v[f].astype(np.float64)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ring_of = f[:, 0] // sides
    outward = tri.mean(axis=1) - centre[ring_of]
    assert (np.einsum("nk,nk->n", normal, outward) > 0).mean() > 0.99


def test_tube_of_straight_and_degenerate_lines() -> None:
    straight = np.stack([np.zeros(5), np.zeros(5), np.linspace(0, 60, 5)], axis=1)
    v, _ = tube_mesh(straight, 2.0, 8)
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), 2.0, rtol=1e-6)
    repeated = np.vstack([straight[:1], straight])  # a zero-length segment
    v2, _ = tube_mesh(repeated, 2.0, 8)
    assert np.isfinite(v2).all()
    with pytest.raises(ShapeError, match="centerline"):
        tube_mesh(np.zeros((1, 3)), 1.0)
    with pytest.raises(ConfigurationError, match="radius"):
        tube_mesh(straight, -1.0)
    with pytest.raises(ConfigurationError, match="sides"):
        tube_mesh(straight, 1.0, 2)


def test_catheter_scene_from_a_state() -> None:
    q = np.array([0.5, 0.2, 0.3, 5.0])
    true_tip = forward(q + np.array([0.05, 0, 0, 0]))
    sensor = forward(q + np.array([0.0, 0.05, 0, 0]))
    s = _state(
        q,
        tip2base_true=true_tip,
        backbone_true=backbone(q + np.array([0.05, 0, 0, 0]), n=20).points_in_base,
        sensor2base=sensor,
    )
    cs = catheter_scene(s, radius_mm=1.5)
    assert cs.true_tube is not None and cs.model_tube is not None
    assert cs.tip_true is not None and cs.sensor is not None
    np.testing.assert_allclose(cs.tip_true.position, true_tip[:3, 3] * MM_TO_SCENE)
    np.testing.assert_allclose(cs.sensor.position, sensor[:3, 3] * MM_TO_SCENE)
    np.testing.assert_allclose(cs.tip_model.position, s.tip2base_model[:3, 3] * MM_TO_SCENE)
    # tube ends at the backbone end, in scene units
    end = cs.true_tube[0][-12:]  # last ring (12 sides)
    end = end.astype(np.float64).mean(axis=0)
    np.testing.assert_allclose(end, s.backbone_true[-1] * MM_TO_SCENE, atol=1e-6)  # type: ignore[index]
    # on hardware: no truth, sensor MISSING, no model backbone
    hw = _state(q, backbone_model=None)
    cs2 = catheter_scene(hw)
    assert cs2.true_tube is None and cs2.model_tube is None
    assert cs2.tip_true is None and cs2.sensor is None


def test_image_plane_pose_puts_pixel_corners_where_ijk2tip_says() -> None:
    rng = np.random.default_rng(3)
    s = 0.5  # mm per pixel; rows = depth along tip x, columns = lateral along tip z
    n_rows, n_cols = 128, 96
    ijk2tip = np.array(
        [[0, s, 0, 0.5 * s], [0, 0, 0, 0], [s, 0, 0, (0.5 - 0.5 * n_cols) * s], [0, 0, 0, 1.0]]
    )
    ijk2tip[1, 2] = 1.0  # k direction (unused by the plane)
    for _ in range(20):
        q = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-3, 3), rng.uniform(-30, 30)])
        tip2base = forward(q)
        pose, w, h = image_plane_pose(ijk2tip, tip2base, (n_rows, n_cols))
        assert w == pytest.approx(n_cols * s * MM_TO_SCENE)
        assert h == pytest.approx(n_rows * s * MM_TO_SCENE)
        rot = vtf.SO3(pose.wxyz).as_matrix()
        # viser's image plane: local x to the right (+i), local y up (row 0 at the top)
        for i, j in ((0, 0), (n_cols - 1, 0), (0, n_rows - 1), (n_cols - 1, n_rows - 1)):
            local = np.array([(i - (n_cols - 1) / 2) * s, -(j - (n_rows - 1) / 2) * s, 0.0])
            in_scene = pose.position + rot @ local * MM_TO_SCENE
            expected = (tip2base @ ijk2tip @ np.array([i, j, 0, 1.0]))[:3] * MM_TO_SCENE
            np.testing.assert_allclose(in_scene, expected, atol=1e-9)
    with pytest.raises(ConfigurationError, match="spacing"):
        image_plane_pose(np.zeros((4, 4)), np.eye(4), (4, 4))


def test_anatomy_meshes_accept_tuples_and_reject_bad_ones() -> None:
    verts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0.0]])
    faces = np.array([[0, 1, 2]])
    out = as_anatomy_meshes([("ra", verts, faces, (200, 80, 80), 0.3)])
    assert isinstance(out[0], AnatomyMesh) and out[0].faces.dtype == np.uint32
    assert as_anatomy_meshes(None) == ()
    again = as_anatomy_meshes(out)
    assert again[0].name == "ra" and again[0].rgb == (200, 80, 80)
    np.testing.assert_array_equal(again[0].vertices, verts)
    with pytest.raises(ConfigurationError, match=r"face indices must be in \[0, 2\]"):
        as_anatomy_meshes([("x", verts, np.array([[0, 1, 3]]), (1, 2, 3), 0.5)])
    with pytest.raises(ShapeError, match="vertices"):
        as_anatomy_meshes([("x", verts[:, :2], faces, (1, 2, 3), 0.5)])
    with pytest.raises(ConfigurationError, match="opacity"):
        as_anatomy_meshes([("x", verts, faces, (1, 2, 3), 1.5)])
    with pytest.raises(ConfigurationError, match="rgb"):
        as_anatomy_meshes([("x", verts, faces, (1, 2, 300), 0.5)])
    with pytest.raises(ConfigurationError, match="got 3 items"):
        as_anatomy_meshes([("x", verts, faces)])  # type: ignore[list-item]


def test_roadmap_trail_adds_a_point_per_growth_and_decimates() -> None:
    trail = RoadmapTrail(max_points=8)
    q = np.zeros(4)
    assert trail.update(_state(q, n_vertices=0)) is False
    for k in range(1, 30):
        qk = np.array([0.02 * k, 0, 0, 0.5 * k])
        true_tip = forward(qk)
        assert trail.update(_state(qk, n_vertices=k, tip2base_true=true_tip)) is True
        assert trail.update(_state(qk, n_vertices=k, tip2base_true=true_tip)) is False
    pts = trail.points()
    assert 4 <= len(pts) <= 8
    # the points are true tip positions, in order of time (d4 grows)
    assert np.all(np.diff(pts[:, 2]) > 0)
    # a smaller roadmap (new session) clears the trail
    assert trail.update(_state(q, n_vertices=1)) is True
    assert len(trail.points()) == 0


def test_view_markers_first_state_uses_the_model_later_views_the_tip() -> None:
    q_view = np.array([0.3, -0.2, 0.5, 4.0])
    v1 = ViewSummary("apex", q_view, 0.0)
    first = view_marker_positions([v1], {}, np.array([1.0, 2.0, 3.0]), first=True)
    np.testing.assert_allclose(first["apex"], forward(q_view)[:3, 3])
    v2 = ViewSummary("septum", np.zeros(4), 1.0)
    later = view_marker_positions([v1, v2], first, np.array([1.0, 2.0, 3.0]), first=False)
    np.testing.assert_allclose(later["apex"], first["apex"])
    np.testing.assert_allclose(later["septum"], [1.0, 2.0, 3.0])
    gone = view_marker_positions([v2], later, np.zeros(3), first=False)
    assert list(gone) == ["septum"]

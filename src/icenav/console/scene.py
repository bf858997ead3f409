"""Pure geometry for the console's 3-D scene: controller state in, scene-ready arrays out.

Nothing here imports viser; :mod:`icenav.console.app` hands the results to it.

Frames and units
----------------
The scene is the robot ``base`` frame (catheter axis = +z = up, as viser's default up
axis). One scene unit is one metre: lengths in mm are multiplied by :data:`MM_TO_SCENE`
(1e-3), so viser's default camera, grid and near/far planes suit a 10 cm heart.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav.control.state import ControllerState, ViewSummary
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = [
    "AnatomyMesh",
    "CatheterScene",
    "MM_TO_SCENE",
    "RoadmapTrail",
    "ScenePose",
    "as_anatomy_meshes",
    "catheter_scene",
    "image_plane_pose",
    "matrix_to_wxyz",
    "pose_to_scene",
    "subsample",
    "tube_mesh",
    "view_marker_positions",
]

MM_TO_SCENE = 1e-3
"""Scene units per mm (one scene unit = 1 m)."""


@dataclass(frozen=True)
class ScenePose:
    """A pose as viser takes it."""

    wxyz: Array
    """(4,) unit quaternion (w, x, y, z) of the rotation."""
    position: Array
    """(3,) position in scene units."""


@dataclass(frozen=True)
class AnatomyMesh:
    """One anatomy surface to show translucently."""

    name: str
    """Scene name (letters, digits, ``_``, ``-``)."""
    vertices: Array
    """(V, 3) vertices in the base frame (mm)."""
    faces: NDArray[np.uint32]
    """(F, 3) vertex indices of the triangles."""
    rgb: tuple[int, int, int]
    """Colour, 0-255 each."""
    opacity: float
    """0 (invisible) to 1 (opaque)."""


@dataclass(frozen=True)
class CatheterScene:
    """What the scene shows of the catheter in one state (scene units)."""

    true_tube: tuple[NDArray[np.float32], NDArray[np.uint32]] | None
    """(vertices, faces) of the true shape (twin only), None on hardware."""
    model_tube: tuple[NDArray[np.float32], NDArray[np.uint32]] | None
    """(vertices, faces) of the model's predicted shape (the ghost), None without one."""
    tip_true: ScenePose | None
    """True image-centre frame (twin only)."""
    tip_model: ScenePose
    """Image-centre frame the model predicts."""
    sensor: ScenePose | None
    """EM sensor pose, None when the tracker reports it MISSING (or there is none)."""


def matrix_to_wxyz(rotation: ArrayLike) -> Array:
    """Unit quaternion (w, x, y, z), w >= 0, of a (3, 3) rotation matrix (Shepperd's method)."""
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3):
        raise ShapeError(f"rotation must have shape (3, 3), got {r.shape}")
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = np.array(
            [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        )
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[k, k], 1e-300))
        q = np.empty(4)
        q[0] = (r[k, j] - r[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (r[j, i] + r[i, j]) / s
        q[1 + k] = (r[k, i] + r[i, k]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0.0 else -q


def pose_to_scene(a2b: ArrayLike, scale: float = MM_TO_SCENE) -> ScenePose:
    """A (4, 4) transform (mm) as a viser pose (quaternion, position in scene units)."""
    t = np.asarray(a2b, dtype=np.float64)
    if t.shape != (4, 4):
        raise ShapeError(f"transform must have shape (4, 4), got {t.shape}")
    return ScenePose(wxyz=matrix_to_wxyz(t[:3, :3]), position=t[:3, 3] * scale)


def subsample(points: ArrayLike, max_points: int) -> Array:
    """At most ``max_points`` of the (N, 3) ``points``, evenly strided, first and last kept."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if max_points < 2:
        raise ConfigurationError(f"max_points must be >= 2, got {max_points}")
    if len(p) <= max_points:
        return p
    idx = np.unique(np.round(np.linspace(0, len(p) - 1, max_points)).astype(np.int64))
    return p[idx]


def tube_mesh(
    centerline: ArrayLike, radius: float, sides: int = 12
) -> tuple[NDArray[np.float32], NDArray[np.uint32]]:
    """A closed-side tube of ``radius`` around a polyline (rotation-minimising frames).

    Parameters
    ----------
    centerline : array-like, shape (n, 3), n >= 2
        Points along the axis (any unit; the tube is in the same unit).
    radius : float
        Tube radius (same unit), > 0.
    sides : int
        Vertices around each ring (>= 3).

    Returns
    -------
    vertices : ndarray, shape (n * sides, 3), float32
        Ring ``i`` holds vertices ``i * sides ... i * sides + sides - 1``, each at distance
        ``radius`` from point ``i``, in the plane normal to the local tangent.
    faces : ndarray, shape (2 * (n - 1) * sides, 3), uint32
        Outward-facing triangles between consecutive rings.
    """
    c = np.asarray(centerline, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] < 2:
        raise ShapeError(f"centerline must have shape (n >= 2, 3), got {c.shape}")
    if not (math.isfinite(radius) and radius > 0):
        raise ConfigurationError(f"radius must be finite and > 0, got {radius}")
    if sides < 3:
        raise ConfigurationError(f"sides must be >= 3, got {sides}")
    n = c.shape[0]
    seg = np.diff(c, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    # Tangents: segment directions, averaged at inner points; zero-length segments reuse
    # the previous direction (a straight catheter gives a straight tube).
    dirs = np.zeros_like(seg)
    last = np.array([0.0, 0.0, 1.0])
    for i in range(n - 1):
        if seg_len[i] > 1e-12:
            last = seg[i] / seg_len[i]
        dirs[i] = last
    tangents = np.empty_like(c)
    tangents[0] = dirs[0]
    tangents[-1] = dirs[-1]
    mid = dirs[:-1] + dirs[1:]
    mid_norm = np.linalg.norm(mid, axis=1, keepdims=True)
    tangents[1:-1] = np.where(mid_norm > 1e-12, mid / np.maximum(mid_norm, 1e-300), dirs[1:])
    # Rotation-minimising normal by parallel transport (double reflection would do as well).
    helper = np.array([1.0, 0.0, 0.0]) if abs(tangents[0][0]) < 0.9 else np.array([0.0, 1.0, 0])
    normal = np.cross(tangents[0], helper)
    normal /= np.linalg.norm(normal)
    normals = np.empty_like(c)
    normals[0] = normal
    for i in range(1, n):
        t = tangents[i]
        nrm = normals[i - 1] - np.dot(normals[i - 1], t) * t
        length = np.linalg.norm(nrm)
        normals[i] = nrm / length if length > 1e-12 else normals[i - 1]
    binormals = np.cross(tangents, normals)
    ang = np.linspace(0.0, 2.0 * math.pi, sides, endpoint=False)
    ring = (
        np.cos(ang)[None, :, None] * normals[:, None, :]
        + np.sin(ang)[None, :, None] * (binormals[:, None, :])
    )
    vertices = (c[:, None, :] + radius * ring).reshape(-1, 3).astype(np.float32)
    ring_idx = np.arange(n - 1)[:, None]
    j = np.arange(sides)[None, :]
    a = ring_idx * sides + j
    b = ring_idx * sides + (j + 1) % sides
    a2 = a + sides
    b2 = b + sides
    faces = np.concatenate(
        [
            np.stack([a, b, b2], axis=-1).reshape(-1, 3),
            np.stack([a, b2, a2], axis=-1).reshape(-1, 3),
        ]
    ).astype(np.uint32)
    return vertices, faces


def catheter_scene(
    state: ControllerState,
    radius_mm: float = DEFAULT_GEOMETRY.catheter_radius,
    scale: float = MM_TO_SCENE,
    sides: int = 12,
) -> CatheterScene:
    """Turn a controller state into catheter tubes and frames in scene units.

    The true tube is drawn at the catheter's radius; the model's ghost slightly thinner so
    that, where both coincide, the true shape shows through the translucent ghost.
    """

    def tube(points: Array | None, r: float) -> tuple[NDArray[np.float32], NDArray[np.uint32]]:
        assert points is not None
        return tube_mesh(np.asarray(points, dtype=np.float64) * scale, r * scale, sides)

    true_tube = tube(state.backbone_true, radius_mm) if _usable(state.backbone_true) else None
    model_tube = (
        tube(state.backbone_model, 0.8 * radius_mm) if _usable(state.backbone_model) else None
    )
    return CatheterScene(
        true_tube=true_tube,
        model_tube=model_tube,
        tip_true=None if state.tip2base_true is None else pose_to_scene(state.tip2base_true, scale),
        tip_model=pose_to_scene(state.tip2base_model, scale),
        sensor=None if state.sensor2base is None else pose_to_scene(state.sensor2base, scale),
    )


def _usable(points: Array | None) -> bool:
    if points is None:
        return False
    p = np.asarray(points)
    return p.ndim == 2 and p.shape[1] == 3 and p.shape[0] >= 2 and bool(np.isfinite(p).all())


def image_plane_pose(
    ijk2tip: ArrayLike, tip2base: ArrayLike, shape: tuple[int, int], scale: float = MM_TO_SCENE
) -> tuple[ScenePose, float, float]:
    """Where to draw an ICE image in the scene (viser's image plane: centred, +y = row 0).

    Parameters
    ----------
    ijk2tip : array-like, shape (4, 4)
        Pixel (i = column, j = row, k = 0) to tip frame (mm); columns 0 and 1 must be
        orthogonal (square or rectangular pixels).
    tip2base : array-like, shape (4, 4)
        Tip pose in the base frame (mm).
    shape : (H, W)
        Image size in pixels.

    Returns
    -------
    pose : ScenePose
        Pose of the image plane centre in the scene.
    render_width, render_height : float
        Size of the drawn plane (scene units): W and H pixels times the pixel spacing.
    """
    m = np.asarray(tip2base, dtype=np.float64) @ np.asarray(ijk2tip, dtype=np.float64)
    h, w = shape
    ex, ey = m[:3, 0], m[:3, 1]
    sx, sy = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
    if sx <= 0 or sy <= 0:
        raise ConfigurationError(f"ijk2tip has a zero pixel spacing ({sx}, {sy} mm)")
    x_axis = ex / sx
    y_axis = -ey / sy  # row 0 is the top of the image, at +y of viser's plane
    z_axis = np.cross(x_axis, y_axis)
    rot = np.column_stack([x_axis, y_axis, z_axis])
    centre = m @ np.array([(w - 1) / 2.0, (h - 1) / 2.0, 0.0, 1.0])
    pose = ScenePose(wxyz=matrix_to_wxyz(rot), position=centre[:3] * scale)
    return pose, w * sx * scale, h * sy * scale


def as_anatomy_meshes(
    meshes: Sequence[AnatomyMesh | tuple[str, ArrayLike, ArrayLike, Sequence[int], float]] | None,
) -> tuple[AnatomyMesh, ...]:
    """Validate anatomy meshes given as :class:`AnatomyMesh` or ``(name, vertices, faces,
    rgb, opacity)`` tuples (vertices in the base frame, mm). None gives ()."""
    if meshes is None:
        return ()
    out: list[AnatomyMesh] = []
    for item in meshes:
        name: str
        verts: ArrayLike
        faces: ArrayLike
        rgb: Sequence[int]
        opacity: float
        if isinstance(item, AnatomyMesh):
            name, verts, faces, rgb, opacity = (
                item.name,
                item.vertices,
                item.faces,
                item.rgb,
                item.opacity,
            )
        else:
            if len(item) != 5:
                raise ConfigurationError(
                    f"an anatomy mesh is (name, vertices, faces, rgb, opacity), got {len(item)} "
                    "items"
                )
            name, verts, faces, rgb, opacity = item
        v = np.asarray(verts, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ShapeError(f"anatomy mesh {name!r}: vertices must be (V, 3) mm, got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise ShapeError(f"anatomy mesh {name!r}: faces must be (F, 3), got {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ConfigurationError(
                f"anatomy mesh {name!r}: face indices must be in [0, {len(v) - 1}], got "
                f"[{f.min()}, {f.max()}]"
            )
        if not np.isfinite(v).all():
            raise ConfigurationError(f"anatomy mesh {name!r}: vertices must be finite")
        col = tuple(int(c) for c in rgb)
        if len(col) != 3 or not all(0 <= c <= 255 for c in col):
            raise ConfigurationError(f"anatomy mesh {name!r}: rgb must be 3 values in 0-255")
        op = float(opacity)
        if not 0.0 <= op <= 1.0:
            raise ConfigurationError(
                f"anatomy mesh {name!r}: opacity must be in [0, 1], got {opacity}"
            )
        out.append(AnatomyMesh(str(name), v, f.astype(np.uint32), (col[0], col[1], col[2]), op))
    return tuple(out)


class RoadmapTrail:
    """Tip positions of the states the roadmap recorded, as the console saw them.

    The state carries the roadmap's size, not its vertices; each time ``n_vertices`` grows,
    the current tip position (true tip if the twin gives it, else the model's) is added.
    The console refreshes slower than the controller records, so this is a subsample of the
    roadmap, drawn where the tip actually was. Past ``max_points`` every other point is
    dropped (the trail stays spread over the whole session).
    """

    def __init__(self, max_points: int = 20_000):
        if max_points < 2:
            raise ConfigurationError(f"max_points must be >= 2, got {max_points}")
        self._max = max_points
        self._points: list[Array] = []
        self._n_seen = 0

    def update(self, state: ControllerState) -> bool:
        """Take one state; True when a point was added (or the trail was cleared)."""
        n = state.n_vertices
        if n < self._n_seen:  # roadmap replaced (new session)
            self._points.clear()
            self._n_seen = n
            return True
        if n == self._n_seen:
            return False
        self._n_seen = n
        tip = state.tip2base_true if state.tip2base_true is not None else state.tip2base_model
        self._points.append(np.asarray(tip, dtype=np.float64)[:3, 3].copy())
        if len(self._points) > self._max:
            self._points = self._points[::2]
        return True

    def points(self) -> Array:
        """(k, 3) positions in the base frame (mm)."""
        if not self._points:
            return np.zeros((0, 3))
        return np.array(self._points)


def view_marker_positions(
    views: Sequence[ViewSummary],
    known: dict[str, Array],
    current_tip_mm: ArrayLike,
    *,
    first: bool,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> dict[str, Array]:
    """Positions (mm, base frame) of the saved-view markers.

    A view seen for the first time while the console runs was saved at the current state,
    so it is placed at ``current_tip_mm`` (where the tip really is). Views already in the
    library when the console starts (``first=True``) are placed at the model tip of their
    motor joint state (the best the state says about them). Deleted views drop out.
    """
    tip = np.asarray(current_tip_mm, dtype=np.float64).reshape(3)
    out: dict[str, Array] = {}
    for v in views:
        if v.name in known:
            out[v.name] = known[v.name]
        elif first:
            out[v.name] = forward(v.q_motor, geometry, check=False)[:3, 3]
        else:
            out[v.name] = tip.copy()
    return out

"""The console's shared 3-D scene (viser): anatomy, catheter tubes and frames, EM sensor,
roadmap, saved-view markers and the ICE image in its plane.

:class:`SceneView` owns the scene handles of one running server and draws a controller
state into them (on the console's refresh thread); the geometry it draws comes from the
pure functions of :mod:`icenav.console.scene`. Scene units are metres (:data:`MM_TO_SCENE`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icenav.console.panels import display_factors, display_pixel_map
from icenav.console.scene import (
    MM_TO_SCENE,
    AnatomyMesh,
    RoadmapTrail,
    catheter_scene,
    image_plane_pose,
    subsample,
    view_marker_positions,
)
from icenav.control.state import ControllerState, ImageFrame
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import CatheterGeometry

__all__ = ["FAN_OPACITY", "SceneLabel", "SceneView", "as_scene_labels", "fan_rgba"]

TRUE_RGB = (230, 140, 40)
MODEL_RGB = (60, 120, 255)
VIEW_RGB = (40, 200, 90)
ROADMAP_RGB = (150, 150, 150)
IMAGE_MAX_WIDTH = 256
"""Widest ICE image drawn in the scene (pixels); wider ones are decimated."""
FAN_OPACITY = 0.8
"""Opacity of the ICE fan in the scene (the anatomy behind it shows through)."""
LABEL_RGB = (250, 250, 250)
ORIENTATION_MM = 15.0
"""Length of the orientation marker's arms (mm)."""


@dataclass(frozen=True)
class SceneLabel:
    """A label in the scene: a structure (RA, TV, ...) or a patient direction (A, P, ...)."""

    key: str
    """Structure key (``ra``, ``interatrial_septum``) or ``dir-<letter>`` for a direction."""
    label: str
    """Short text shown (``RA``, ``A``)."""
    name: str
    """Full name (``right atrium``, ``anterior``)."""
    point: tuple[float, float, float]
    """Anchor in the base frame (mm); for a direction, a unit vector in the base frame."""

    @property
    def is_direction(self) -> bool:
        return self.key.startswith("dir-")


def as_scene_labels(items: Sequence[Any] | None) -> tuple[SceneLabel, ...]:
    """Labels from landmark objects (``key``, ``label``, ``name``, ``point``) or
    ``(key, label, name, point)`` tuples; None gives ()."""
    out: list[SceneLabel] = []
    for item in items or ():
        if isinstance(item, tuple):
            key, label, name, point = item
        else:
            key, label, name, point = item.key, item.label, item.name, item.point
        p = np.asarray(point, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ConfigurationError(f"label {key!r}: point must be 3 finite values (mm)")
        out.append(SceneLabel(str(key), str(label), str(name), (p[0], p[1], p[2])))
    return tuple(out)


def fan_rgba(pixels: NDArray[np.uint8], opacity: float = FAN_OPACITY) -> NDArray[np.uint8]:
    """(H, W) B-mode image as (H, W, 4) RGBA: opaque ``opacity`` inside the sector (each row
    from its first to its last pixel with an echo), transparent outside it."""
    p = np.asarray(pixels, dtype=np.uint8)
    lit = p > 0
    cols = np.arange(p.shape[1])
    first = np.where(lit.any(axis=1), lit.argmax(axis=1), p.shape[1])
    last = np.where(lit.any(axis=1), p.shape[1] - 1 - lit[:, ::-1].argmax(axis=1), -1)
    inside = (cols[None, :] >= first[:, None]) & (cols[None, :] <= last[:, None])
    alpha = np.where(inside, round(255 * opacity), 0).astype(np.uint8)
    return np.dstack([p, p, p, alpha])


class SceneView:
    """The 3-D scene of one running viser server.

    Parameters
    ----------
    server : viser.ViserServer
        The server whose (shared) scene is drawn.
    anatomy : sequence of AnatomyMesh
        Surfaces in the base frame (mm), drawn translucently.
    geometry : CatheterGeometry
        Catheter radius (tubes) and the model pose of views loaded with a session.
    max_roadmap_points : int
        The roadmap drawn as at most this many points.
    labels : sequence of SceneLabel
        Anatomy labels and patient directions (the orientation marker).
    """

    def __init__(
        self,
        server: Any,
        anatomy: Sequence[AnatomyMesh],
        geometry: CatheterGeometry,
        max_roadmap_points: int,
        labels: Sequence[SceneLabel] = (),
    ):
        self.server = server
        self.geometry = geometry
        self.max_roadmap_points = max_roadmap_points
        self.trail = RoadmapTrail()
        self.markers: dict[str, np.ndarray] = {}
        """Saved-view marker positions (mm, base frame), by view name."""
        self.marker_handles: dict[str, tuple[Any, Any]] = {}
        """(sphere, label) scene handles of each saved view's marker."""
        self.image: Any = None
        """The scene's ICE image handle (None until an image with a placement came)."""
        self.on_view_click: Callable[[str, int | None], None] | None = None
        """Called with (view name, client id) when a browser clicks a view's marker."""
        self._first_state = True
        self._tubes: dict[str, Any] = {}
        self._tube_faces: dict[str, int] = {}
        self._roadmap_on = True
        self._image_on = True
        self.label_handles: list[Any] = []
        """Anatomy labels and the orientation marker's letters."""
        self._build(anatomy)
        self._build_labels(labels, anatomy)

    def _build_labels(self, labels: Sequence[SceneLabel], anatomy: Sequence[AnatomyMesh]) -> None:
        """Structure labels at their anchors; the orientation marker (A/P, L/R, S/I arms)
        beside the anatomy, at the corner of its bounding box nearest the viewer's start."""
        sc = self.server.scene
        for i, lab in enumerate(x for x in labels if not x.is_direction):
            h = sc.add_label(
                f"/labels/s{i}",
                lab.label,
                position=np.asarray(lab.point) * MM_TO_SCENE,
                font_screen_scale=1.1,
                anchor="center-center",
            )
            self.label_handles.append(h)
        dirs = [x for x in labels if x.is_direction]
        if not dirs:
            return
        pts = [m.vertices for m in anatomy] or [np.zeros((1, 3))]
        allp = np.concatenate(pts)
        corner = np.array([allp[:, 0].max(), allp[:, 1].min(), allp[:, 2].min()]) + 10.0
        origin = corner * MM_TO_SCENE
        segs = []
        for i, d in enumerate(dirs):
            u = np.asarray(d.point, dtype=np.float64)
            u = u / max(float(np.linalg.norm(u)), 1e-12)
            tip = origin + u * ORIENTATION_MM * MM_TO_SCENE
            segs.append([origin, tip])
            h = sc.add_label(
                f"/orientation/{i}",
                d.label,
                position=origin + u * (ORIENTATION_MM + 4.0) * MM_TO_SCENE,
                anchor="center-center",
            )
            self.label_handles.append(h)
        self.label_handles.append(
            sc.add_line_segments(
                "/orientation/arms",
                np.asarray(segs, dtype=np.float32),
                colors=(255, 200, 0),
                thickness=0.0006,
            )
        )

    def show_roadmap(self, on: bool) -> None:
        """Show or hide the roadmap's points."""
        self._roadmap_on = bool(on)
        self.roadmap.visible = self._roadmap_on and len(self.trail.points()) > 0

    def show_labels(self, on: bool) -> None:
        """Show or hide the anatomy labels and the orientation marker."""
        for h in self.label_handles:
            h.visible = bool(on)

    def show_image(self, on: bool) -> None:
        """Show or hide the ICE fan in the scene."""
        self._image_on = bool(on)
        if self.image is not None:
            self.image.visible = self._image_on

    def _build(self, anatomy: Sequence[AnatomyMesh]) -> None:
        s = self.server
        cam = s.initial_camera
        cam.position = (0.09, -0.09, 0.07)  # metres: the 60 mm bending section fills a third
        cam.look_at = (0.0, 0.0, 0.035)
        cam.near = 0.001
        if anatomy:  # the whole heart in view, from the same side
            pts = np.concatenate([m.vertices for m in anatomy]) * MM_TO_SCENE
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            centre = 0.5 * (lo + hi)
            away = np.array([0.09, -0.09, 0.07]) / np.linalg.norm([0.09, -0.09, 0.07])
            cam.look_at = tuple(centre)
            cam.position = tuple(centre + away * 0.9 * float(np.linalg.norm(hi - lo)))
        sc = s.scene
        sc.set_up_direction("+z")
        sc.configure_default_lights(enabled=True, cast_shadow=False)  # shadows cost frame rate
        sc.add_frame("/base", axes_length=0.01, axes_radius=0.0005)
        # the base plane: 1 cm cells, 5 cm sections (a scale for the eye)
        sc.add_grid(
            "/grid",
            width=0.2,
            height=0.2,
            cell_size=0.01,
            section_size=0.05,
            fade_distance=1.0,
            shadow_opacity=0.0,
        )
        for mesh in anatomy:
            sc.add_mesh_simple(
                f"/anatomy/{mesh.name}",
                vertices=(mesh.vertices * MM_TO_SCENE).astype(np.float32),
                faces=mesh.faces,
                color=mesh.rgb,
                opacity=mesh.opacity,
                side="double",
                cast_shadow=False,
                receive_shadow=False,
            )
        self.tip_true = sc.add_frame(
            "/catheter/tip_true", axes_length=0.008, axes_radius=0.0005, visible=False
        )
        self.tip_model = sc.add_frame(
            "/catheter/tip_model", axes_length=0.006, axes_radius=0.0003, visible=False
        )
        self._tip_ghost = sc.add_icosphere(
            "/catheter/tip_model/ghost", radius=0.0025, color=MODEL_RGB, opacity=0.35
        )
        self.sensor = sc.add_frame(
            "/catheter/sensor", axes_length=0.005, axes_radius=0.0004, visible=False
        )
        # the EM sensor as a red bead with its name (children follow and hide with the frame)
        sc.add_icosphere("/catheter/sensor/bead", radius=0.0014, color=(220, 30, 30))
        sc.add_label("/catheter/sensor/name", "EM", position=(0.0, 0.0, -0.004))
        self.roadmap = sc.add_point_cloud(
            "/roadmap",
            points=np.zeros((1, 3), np.float32),
            colors=ROADMAP_RGB,
            point_size=0.0012,
            visible=False,
        )

    def draw_state(self, state: ControllerState) -> None:
        """Catheter, sensor, roadmap and view markers of ``state``."""
        cs = catheter_scene(state, self.geometry.catheter_radius)
        self._set_tube("true", cs.true_tube, TRUE_RGB, None)
        self._set_tube("model", cs.model_tube, MODEL_RGB, 0.35)
        self.tip_model.wxyz, self.tip_model.position = cs.tip_model.wxyz, cs.tip_model.position
        self.tip_model.visible = True
        if cs.tip_true is not None:
            self.tip_true.wxyz, self.tip_true.position = cs.tip_true.wxyz, cs.tip_true.position
        self.tip_true.visible = cs.tip_true is not None
        if cs.sensor is not None:
            self.sensor.wxyz, self.sensor.position = cs.sensor.wxyz, cs.sensor.position
        self.sensor.visible = cs.sensor is not None
        if self.trail.update(state):
            pts = subsample(self.trail.points(), self.max_roadmap_points) * MM_TO_SCENE
            if len(pts):
                self.roadmap.points = pts.astype(np.float32)
                self.roadmap.colors = np.tile(np.array(ROADMAP_RGB, np.uint8), (len(pts), 1))
            self.roadmap.visible = self._roadmap_on and len(pts) > 0
        tip = state.tip2base_true if state.tip2base_true is not None else state.tip2base_model
        markers = view_marker_positions(
            state.views,
            self.markers,
            np.asarray(tip)[:3, 3],
            first=self._first_state,
            geometry=self.geometry,
        )
        self._first_state = False
        if markers.keys() != self.markers.keys():
            self._draw_markers(markers)
        self.markers = markers

    def _set_tube(self, key: str, tube: Any, rgb: tuple[int, int, int], op: float | None) -> None:
        handle = self._tubes.get(key)
        if tube is None:
            if handle is not None:
                handle.visible = False
            return
        vertices, faces = tube
        if handle is None or self._tube_faces.get(key) != len(faces):
            if handle is not None:
                handle.remove()
            self._tubes[key] = self.server.scene.add_mesh_simple(
                f"/catheter/{key}",
                vertices=vertices,
                faces=faces,
                color=rgb,
                opacity=op,
                cast_shadow=False,
                receive_shadow=False,
            )
            self._tube_faces[key] = len(faces)
        else:
            handle.vertices = vertices
            handle.visible = True

    def _draw_markers(self, markers: dict[str, np.ndarray]) -> None:
        sc = self.server.scene
        for name in list(self.marker_handles):
            if name not in markers:
                for h in self.marker_handles.pop(name):
                    h.remove()
        for i, (name, pos) in enumerate(markers.items()):
            if name in self.marker_handles:
                continue
            key = f"/views/v{i}_{abs(hash(name)) % 10**8}"
            p = np.asarray(pos) * MM_TO_SCENE
            sphere = sc.add_icosphere(key, radius=0.0025, color=VIEW_RGB, position=p)
            label = sc.add_label(key + "_label", name, position=p + np.array([0, 0, 0.005]))
            sphere.on_click(self._clicked(name))
            self.marker_handles[name] = (sphere, label)

    def _clicked(self, name: str) -> Callable[[Any], None]:
        def cb(ev: Any) -> None:
            if self.on_view_click is not None:
                self.on_view_click(name, getattr(ev, "client_id", None))

        return cb

    def draw_image(self, frame: ImageFrame, state: ControllerState | None) -> None:
        """The ICE image as its fan (translucent, transparent outside the sector) in its
        plane at the tip; nothing when its placement is unknown."""
        if state is None or np.array_equal(frame.ijk2tip, np.eye(4)):
            return  # identity: the imager did not say where its pixels are; panel only
        pixels = np.asarray(frame.pixels)
        if pixels.ndim == 3:
            pixels = pixels.mean(axis=2).astype(np.uint8)
        down, up = display_factors(pixels.shape[1], IMAGE_MAX_WIDTH, 0)
        rgba = fan_rgba(pixels[::down, ::down])
        tip = state.tip2base_true if state.tip2base_true is not None else state.tip2base_model
        ijk2tip = np.asarray(frame.ijk2tip, dtype=np.float64) @ display_pixel_map(down, up)
        pose, w, h = image_plane_pose(ijk2tip, tip, (rgba.shape[0], rgba.shape[1]))
        if self.image is None:
            self.image = self.server.scene.add_image(
                "/ice_image",
                rgba,
                w,
                h,
                format="png",
                wxyz=pose.wxyz,
                position=pose.position,
                cast_shadow=False,
                receive_shadow=False,
                visible=self._image_on,
            )
        else:
            self.image.image = rgba
            self.image.wxyz, self.image.position = pose.wxyz, pose.position
            self.image.render_width, self.image.render_height = w, h

"""Wiring: a controller on the digital twin (or emulated drives) with its store and imager.

:func:`make_sim_controller` builds what ``icenav demo`` runs: a catheter plant (seeded),
the simulated robot around it, the EM tracker, the beating-heart phantom with the ICE
renderer, and a session store (SQLite) that the controller records into, resumed when the
file exists.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.control.controller import Controller, ControllerConfig
from icenav.control.teleop import InputSource
from icenav.errors import ConfigurationError
from icenav.persistence.forces import load_forces
from icenav.persistence.recorder import StoreRecorder
from icenav.persistence.store import SessionStore
from icenav.recovery.roadmap import Roadmap, RoadmapConfig

__all__ = [
    "SimSession",
    "StoreRecorder",
    "anatomy_labels",
    "anatomy_meshes",
    "force_channel",
    "install_calibration",
    "install_compensation",
    "make_imager",
    "make_sim_controller",
    "resume_calibration",
]


@dataclass
class SimSession:
    """Everything :func:`make_sim_controller` built, to inspect or close."""

    controller: Controller
    plant: Any
    tracker: Any
    renderer: Any
    store: SessionStore | None
    recorder: StoreRecorder | None
    drives: Any = None
    """The emulated CANopen drives, when the robot is "emulated-canopen"."""
    resumed_calibration: str | None = None
    """What :func:`resume_calibration` re-installed from the session (or why it could not),
    for the operator; None: the session holds no calibration."""

    def close(self) -> None:
        """Stop the loop and flush the store."""
        self.controller.shutdown()
        try:
            if self.recorder is not None:
                self.recorder.close()  # a failure here must reach the operator: no silent loss
        finally:
            if self.store is not None:
                self.store.close()
        try:
            self.controller.robot.close()
            if self.drives is not None:
                self.drives.close()
        finally:
            stop = getattr(self.tracker, "stop", None)
            if callable(stop):  # an NDI Aurora releases its serial port
                stop()


def make_sim_controller(
    *,
    seed: int = 100,
    vessel: str = "straight",
    session: str | Path | None = None,
    config: ControllerConfig | None = None,
    input_source: InputSource | None = None,
    imaging: bool = True,
    robot: str = "sim",
    clock: Callable[[], float] = time.monotonic,
    roadmap_config: RoadmapConfig | None = None,
    plant: str | None = None,
    plant_family: str | None = None,
) -> SimSession:
    """A controller on the digital twin.

    Parameters
    ----------
    seed : int
        Catheter seed (seeds 0-9 tuned the twin; the default is one that did not).
    vessel : str
        "straight", "moderate" or "steep".
    session : path, optional
        SQLite session file; resumed (roadmap and views) if it exists, created otherwise.
        None: nothing persisted.
    imaging : bool
        Render the live ICE image (about 15-40 ms a frame, in its own thread when the
        controller runs in real time).
    robot : {"sim", "emulated-canopen"}
        "sim": the simulated robot moves the twin directly. "emulated-canopen": five
        emulated CiA 402 drives on a virtual CAN bus behind :class:`CANopenRobot` (the code
        path of real drives); the twin follows the drives' encoder positions.
    roadmap_config : RoadmapConfig, optional
        Settings of a new roadmap (epsilon, vertex budget, ...); a resumed session keeps
        the settings stored in its file.
    plant, plant_family : str, optional
        A plant plug-in ``MODULE:FACTORY`` or a plant family name
        (:func:`icenav.sim.plugins.resolve_factory`) instead of the default twin (with
        ``robot="sim"``); its own tracker comes with it.
    """
    from icenav.devices.sim_robot import SimulatedRobot
    from icenav.sim import CatheterPlant, EMTracker

    tracker: Any
    if plant is not None or plant_family is not None:
        if robot != "sim":
            raise ConfigurationError("a plant plug-in or family runs on robot 'sim' only")
        from icenav.sim.plugins import make_plant, resolve_factory

        # the clock goes to the factory only when it is not the wall clock (the factories'
        # default): a headless run drives a simulated one
        model, tracker = make_plant(
            resolve_factory(plant, plant_family),
            seed,
            vessel,
            clock=None if clock is time.monotonic else clock,
        )
    else:
        model = CatheterPlant(seed=seed, vessel=vessel)
        tracker = EMTracker(model, seed=seed, clock=clock)
    drives: Any = None
    backend: Any
    if robot == "sim":
        backend = SimulatedRobot(model, clock=clock, on_excess="clip")
        backend.record_commands = False
    elif robot == "emulated-canopen":
        from icenav.devices.canopen.emulated_drive import open_emulated_robot

        backend, drives = open_emulated_robot()
        backend.home()
    else:
        raise ConfigurationError(f"robot must be 'sim' or 'emulated-canopen', got {robot!r}")
    tracker.start()
    store = recorder = None
    roadmap = views = forces = None
    if session is not None:
        store = SessionStore(session, config=roadmap_config, clock=clock)
        roadmap = store.load_roadmap()
        roadmap.break_trace()  # the restart was not a travelled motion
        views = store.load_views()
        forces = load_forces(store)  # the operator's forces: returns checked as before
    elif roadmap_config is not None:
        roadmap = Roadmap(config=roadmap_config)
    renderer = imager = ijk2tip = None
    if imaging:
        renderer, imager, ijk2tip = make_imager()

    def truth() -> tuple[Array, Array]:
        if drives is not None:  # the twin follows the emulated drives' encoders
            model.move(backend.read_state().q)
        backbone = getattr(model, "backbone", None)  # optional for plug-ins
        points = backbone(30) if callable(backbone) else model.state.tip2base[None, :3, 3]
        return model.state.tip2base, points

    controller = Controller(
        backend,
        config,
        roadmap=roadmap,
        views=views,
        input_source=input_source,
        truth=truth,
        tracker=tracker,
        imager=imager,
        image_ijk2tip=ijk2tip,
        clock=clock,
        force_sensor=force_channel(model),
        forces=forces,
    )
    resumed = None
    if store is not None:
        resumed = resume_calibration(controller, store)
        recorder = StoreRecorder(store, controller.roadmap, threaded=True, forces=controller.forces)
        controller.set_recorder(recorder)
    return SimSession(controller, model, tracker, renderer, store, recorder, drives, resumed)


def force_channel(model: Any) -> Any:
    """The twin's contact-force channel when the plant has contact
    (:class:`icenav.sim.disturbed.TwinForceSensor`), else None: no force check, and the
    console says so."""
    if getattr(model, "contact", None) is None or not hasattr(model, "last_contact_force_n"):
        return None
    from icenav.sim.disturbed import TwinForceSensor

    return TwinForceSensor(model)


def install_calibration(
    controller: Controller, path: str | Path, store: SessionStore | None = None
) -> str:
    """Load a calibration file (:class:`icenav.calibration.files.CalibrationFile`, as
    ``icenav calibrate`` or the console write it) and install its compensation on
    ``controller`` (compensation on), before the controller starts: the stored model of a
    version 3 file (the ``dense+hysteresis`` knob map, relaxed where the robot is, or the
    fitted F), the paper's F built on the samples of an older file
    (:meth:`~icenav.calibration.files.CalibrationFile.compensation`). With ``store`` the
    file's document becomes the session's calibration in use (a reopened session installs it
    again). Returns what was loaded, for the operator."""
    from icenav.calibration.files import CalibrationFile

    loaded = CalibrationFile.load(path)
    install_compensation(controller, loaded)
    if store is not None:
        store.save_calibration_document(loaded.kind or "file", loaded.to_dict(), time.time())
    return f"compensation from {path}: {loaded.describe()}"


def resume_calibration(controller: Controller, store: SessionStore) -> str | None:
    """Install the session's calibration in use (stored when a calibration finished in the
    console, or a ``--calibration`` file was installed), as a reopened session (a restart
    after a crash) must; before the controller starts. Returns what was installed for the
    operator (also the controller's message), or why it could not be (compensation stays
    off), or None when the session holds no calibration."""
    from icenav.calibration.files import CalibrationFile
    from icenav.errors import IcenavError

    stored = store.calibration_document()
    if stored is None:
        return None
    source = f"{store.path}: calibration in use"
    try:
        loaded = CalibrationFile.from_dict(stored[1], source)
        install_compensation(controller, loaded)
    except IcenavError as exc:
        text = f"calibration of the session NOT installed (compensation off): {exc}"
    else:
        text = f"calibration re-installed from the session: {loaded.describe()}; compensation on"
    controller._message = text  # noqa: SLF001 (the console shows it before the first command)
    return text


def install_compensation(controller: Controller, loaded: Any) -> None:
    """Install a :class:`~icenav.calibration.files.CalibrationFile`'s compensation on
    ``controller`` (compensation on); a map with state follows the motor state the robot
    was last commanded from here (``observe``), as after a calibration in the console."""
    comp = loaded.compensation(controller.config.geometry)
    observe = getattr(comp, "observe", None)
    if callable(observe):
        observe(controller.q_command)
    controller.compensation = comp
    controller.compensation_enabled = True
    controller.calibration = loaded.calibration


def make_imager() -> tuple[Any, Callable[[Array, float], NDArray[np.uint8]], Array]:
    """The twin's ICE renderer, the controller's ``imager(tip2base_true, t)`` on the beating
    heart phantom, and the image's ``ijk2tip`` (4, 4) (pixel i = column, j = row, mm)."""
    from icenav.sim.anatomy import BASE2ANATOMY
    from icenav.sim.ultrasound import UltrasoundRenderer

    renderer = UltrasoundRenderer()
    px = renderer.config.pixel_mm
    n = renderer.config.image_size
    # pixel (i = column, j = row): x = (row + 0.5) px, z = (col + 0.5 - n / 2) px, y = 0
    ijk2tip = np.array(
        [
            [0.0, px, 0.0, 0.5 * px],
            [0.0, 0.0, px, 0.0],
            [px, 0.0, 0.0, (0.5 - n / 2) * px],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )

    def imager(tip2base: Array, t: float) -> NDArray[np.uint8]:
        return renderer.render(BASE2ANATOMY @ tip2base, t, check=False).image

    return renderer, imager, ijk2tip


_CHAMBER_RGB = {
    "ra": (70, 130, 220),
    "rv": (60, 90, 200),
    "rvot": (60, 90, 200),
    "la": (220, 90, 90),
    "lv": (200, 60, 60),
}
_VESSEL_RGB = {"aorta": (220, 60, 60), "lvot": (200, 60, 60), "pa": (60, 90, 200)}


def anatomy_meshes(phantom: Any = None) -> list[Any]:
    """Translucent surfaces of the heart phantom's chambers, vessels and valves for the console.

    Each chamber is its ellipsoid (an icosphere scaled by the semi-axes), each vessel its
    cylinder, each valve its annulus ring, mapped from the anatomy frame into the robot base
    frame (mm) through the phantom's registration (``BASE2ANATOMY``). Mesh names are
    ``anatomy-<key>`` with the keys of :func:`anatomy_labels`, which gives each structure's
    label and anchor point. The beating motion is not drawn.
    """
    import trimesh

    from icenav.console import AnatomyMesh
    from icenav.sim.anatomy import BASE2ANATOMY, default_phantom

    ph = phantom if phantom is not None else default_phantom()
    anatomy2base = np.linalg.inv(BASE2ANATOMY)

    def to_base(pts: Any) -> Any:
        return np.asarray(pts) @ anatomy2base[:3, :3].T + anatomy2base[:3, 3]

    out: list[Any] = []
    for ch in ph.chambers:
        sphere = trimesh.creation.icosphere(subdivisions=3)
        local = np.asarray(sphere.vertices) * np.asarray(ch.semi_axes)
        pts = local @ np.asarray(ch.rotation).T + np.asarray(ch.centre)
        out.append(
            AnatomyMesh(
                name=f"anatomy-{ch.name}",
                vertices=to_base(pts),
                faces=np.asarray(sphere.faces, dtype=np.uint32),
                rgb=_CHAMBER_RGB.get(ch.name, (180, 180, 180)),
                opacity=0.18,
            )
        )
    for v in ph.vessels:
        cyl = trimesh.creation.cylinder(
            radius=float(v.radius_mm), segment=np.array([v.start, v.end], dtype=np.float64)
        )
        out.append(
            AnatomyMesh(
                name=f"anatomy-{v.name}",
                vertices=to_base(cyl.vertices),
                faces=np.asarray(cyl.faces, dtype=np.uint32),
                rgb=_VESSEL_RGB.get(v.name, (150, 150, 200)),
                opacity=0.15,
            )
        )
    for valve in ph.valves:
        ring = trimesh.creation.annulus(
            r_min=0.8 * valve.radius_mm, r_max=valve.radius_mm, height=1.0, sections=32
        )
        normal = np.asarray(valve.normal, dtype=np.float64)
        align = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], normal / np.linalg.norm(normal))
        pts = np.asarray(ring.vertices) @ align[:3, :3].T + np.asarray(valve.centre)
        out.append(
            AnatomyMesh(
                name=f"anatomy-{valve.name}",
                vertices=to_base(pts),
                faces=np.asarray(ring.faces, dtype=np.uint32),
                rgb=(240, 220, 120),
                opacity=0.6,
            )
        )
    return out


def anatomy_labels(phantom: Any = None) -> list[Any]:
    """Labels of the anatomy for the console's 3-D scene, anchored in the base frame (mm).

    Returns :class:`icenav.sim.anatomy.Landmark` values (key, label such as ``RA``, full
    name, anchor point) for every chamber, vessel, valve and the interatrial septum, their
    points mapped from the anatomy frame into the robot base frame, followed by the six
    patient directions (keys ``dir-L``, ``dir-R``, ``dir-A``, ``dir-P``, ``dir-S``,
    ``dir-I``; points are unit vectors in the base frame) for an orientation marker.
    """
    from icenav.sim.anatomy import BASE2ANATOMY, PATIENT_DIRECTIONS, Landmark, default_phantom

    ph = phantom if phantom is not None else default_phantom()
    anatomy2base = np.linalg.inv(BASE2ANATOMY)
    out: list[Any] = []
    for lm in ph.landmarks():
        p = anatomy2base[:3, :3] @ np.asarray(lm.point) + anatomy2base[:3, 3]
        out.append(Landmark(lm.key, lm.label, lm.name, (float(p[0]), float(p[1]), float(p[2]))))
    names = {"L": "left", "R": "right", "A": "anterior", "P": "posterior"}
    names |= {"S": "superior", "I": "inferior"}
    for letter, vec in PATIENT_DIRECTIONS.items():
        d = anatomy2base[:3, :3] @ np.asarray(vec)
        out.append(
            Landmark(
                f"dir-{letter}", letter, names[letter], (float(d[0]), float(d[1]), float(d[2]))
            )
        )
    return out

"""Wiring on real drives: CiA 402 drives from a robot TOML, a tracker, the registration step.

What ``icenav run`` and ``icenav serve --robot-config`` build:

- :func:`load_tracker_config`: the tracker TOML (``examples/tracker.toml``): the NDI Aurora's
  serial port and tool, the sensor mount ``sensor2tip`` (mm), the registration's settings;
- :func:`make_hardware_controller`: a :class:`~icenav.devices.canopen.robot.CANopenRobot` from
  the robot TOML (homed: the current position becomes q = 0), the tracker (the twin's EM
  tracker on a catheter plant that follows the drives' encoders, an NDI Aurora, or none),
  the session store, and the controller;
- :func:`guided_registration`: the registration procedure of the control core
  (``make_procedure("registration")``, run by ``run_procedure``) on the robot, the sensor
  read in the tracker frame at each commanded state, the residual reported, the
  :class:`~icenav.devices.registration.Registration` set on the tracker and stored in the
  session.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav._validation import check_transform, read_toml
from icenav.apps.wiring import SimSession, resume_calibration
from icenav.control.controller import Controller, ControllerConfig
from icenav.control.teleop import InputSource
from icenav.devices.registration import Registration
from icenav.errors import (
    ConfigurationError,
    FileFormatError,
    HardwareError,
    IcenavError,
    MotionAborted,
    RegistrationError,
)
from icenav.persistence.recorder import StoreRecorder
from icenav.persistence.store import SessionStore

__all__ = [
    "FollowingTwin",
    "TrackerSettings",
    "guided_registration",
    "load_tracker_config",
    "make_hardware_controller",
    "move_and_wait",
]


@dataclass(frozen=True, eq=False)
class TrackerSettings:
    """The tracker TOML (``examples/tracker.toml``); every field has a default."""

    serial_port: str | None = None
    """NDI: serial device ("/dev/ttyUSB0"); None probes the ports."""
    tool_index: int = 0
    """NDI: which wired tool (in port-handle order) is the catheter's sensor."""
    sensor2tip: Array | None = None
    """(4, 4) pose of the sensor in the tip frame (mm), from the mount's drawing; None: the
    twin's mount with ``--tracker sim``, required with ``--tracker ndi``."""
    n_average: int = 8
    """Tracker samples averaged at each registration state."""
    max_residual_mm: float = 2.0
    """A registration whose RMS residual exceeds this is refused (mm)."""
    settle_s: float = 0.3
    """Wait after each registration state is reached, before reading (s)."""
    source: str = "defaults"
    """The file the settings came from (for messages)."""
    ndi_extra: Mapping[str, Any] = field(default_factory=dict)
    """Other keys of ``[ndi]`` (``ports_to_probe``, ``quality_scale_mm``,
    ``reads_per_sample``), passed to :class:`~icenav.devices.ndi.NDIAuroraConfig`."""

    def ndi_config(self) -> Any:
        """The :class:`~icenav.devices.ndi.NDIAuroraConfig` of these settings."""
        from icenav.devices.ndi import NDIAuroraConfig

        return NDIAuroraConfig(
            serial_port=self.serial_port, tool_index=self.tool_index, **dict(self.ndi_extra)
        )


_NDI_KEYS = {"serial_port", "tool_index", "ports_to_probe", "quality_scale_mm", "reads_per_sample"}
_REG_KEYS = {"n_average", "max_residual_mm", "settle_s"}


def load_tracker_config(path: str | Path | None) -> TrackerSettings:
    """Read a tracker TOML (tables ``[ndi]``, ``[mount]``, ``[registration]``); None: the
    defaults. FileFormatError naming the file and the key for anything unreadable, unknown or
    out of range."""
    if path is None:
        return TrackerSettings()
    p = Path(path)
    data = read_toml(p, "the tracker configuration")
    unknown = set(data) - {"ndi", "mount", "registration"}
    if unknown:
        raise FileFormatError(
            f"{p}: unknown table(s) {sorted(unknown)}; known: ndi, mount, registration"
        )
    ndi = dict(data.get("ndi", {}))
    mount = dict(data.get("mount", {}))
    reg = dict(data.get("registration", {}))
    for table, keys, known in (
        ("ndi", ndi, _NDI_KEYS),
        ("mount", mount, {"sensor2tip"}),
        ("registration", reg, _REG_KEYS),
    ):
        bad = set(keys) - known
        if bad:
            raise FileFormatError(
                f"{p}: [{table}] has unknown key(s) {sorted(bad)}; known: {sorted(known)}"
            )
    sensor2tip = None
    if "sensor2tip" in mount:
        try:
            sensor2tip = check_transform(np.asarray(mount["sensor2tip"], dtype=float), "sensor2tip")
        except (ValueError, TypeError, IcenavError) as exc:
            raise FileFormatError(
                f"{p}: [mount] sensor2tip must be a rigid (4, 4) transform (mm): {exc}"
            ) from exc
        if sensor2tip.shape != (4, 4):
            raise FileFormatError(f"{p}: [mount] sensor2tip must be one (4, 4) transform")
    try:
        settings = TrackerSettings(
            serial_port=ndi.pop("serial_port", None),
            tool_index=int(ndi.pop("tool_index", 0)),
            sensor2tip=sensor2tip,
            n_average=int(reg.get("n_average", 8)),
            max_residual_mm=float(reg.get("max_residual_mm", 2.0)),
            settle_s=float(reg.get("settle_s", 0.3)),
            source=str(p),
            ndi_extra=ndi,
        )
        settings.ndi_config()  # checks the NDI values
    except (TypeError, ValueError, ConfigurationError) as exc:
        raise FileFormatError(f"{p}: {exc}") from exc
    if settings.n_average < 1:
        raise FileFormatError(
            f"{p}: [registration] n_average must be >= 1 samples, got {settings.n_average}"
        )
    if not (math.isfinite(settings.max_residual_mm) and settings.max_residual_mm > 0):
        raise FileFormatError(
            f"{p}: [registration] max_residual_mm must be > 0 mm, got {settings.max_residual_mm}"
        )
    if not (math.isfinite(settings.settle_s) and 0 <= settings.settle_s <= 10):
        raise FileFormatError(
            f"{p}: [registration] settle_s must be in [0, 10] s, got {settings.settle_s}"
        )
    return settings


class FollowingTwin:
    """The twin's catheter plant following the drives' encoders, with its EM tracker (the
    ``--tracker sim`` of real or emulated drives: the whole chain but the catheter is real).

    :meth:`sync` moves the plant along the straight joint path from its last state to the
    robot's measured one (the plant is quasi-static: a long jump in one step would skip the
    hysteresis it passes through).
    """

    def __init__(self, robot: Any, seed: int, vessel: str, clock: Callable[[], float]):
        from icenav.sim import CatheterPlant, EMTracker

        self.robot = robot
        self.plant = CatheterPlant(seed=seed, vessel=vessel)
        self.tracker = EMTracker(self.plant, seed=seed, clock=clock)
        self.tracker.registration = None  # the lab registers it (guided_registration)
        self._q = np.zeros(4)

    def sync(self) -> None:
        """Move the plant to the robot's measured joint state."""
        q = np.asarray(self.robot.read_state().q, dtype=np.float64)
        n = int(min(200, max(1, math.ceil(float(np.max(np.abs(q - self._q))) / 0.02))))
        if n > 1:
            self.plant.move_along(np.linspace(self._q, q, n + 1)[1:])
        else:
            self.plant.move(q)
        self._q = q

    def truth(self) -> tuple[Array, Array]:
        """The controller's ``truth()``: the plant at the drives' state."""
        self.sync()
        return self.plant.state.tip2base, self.plant.backbone(30)


def move_and_wait(
    robot: Any,
    q: Array,
    *,
    tolerance: float = 2e-3,
    timeout_s: float = 60.0,
    poll_s: float = 0.005,
    stop: threading.Event | None = None,
) -> Array:
    """Command ``q`` (rad, rad, rad, mm) and wait until every joint is within ``tolerance``
    (rad or mm) of it; the measured state (4,). HardwareError naming the joints after
    ``timeout_s`` or when the robot leaves ENABLED; MotionAborted (the robot told to hold
    where it is) as soon as ``stop`` is set (Ctrl-C, SIGTERM)."""
    from icenav.devices.robot import RobotStatus

    target = np.asarray(q, dtype=np.float64)
    if stop is not None and stop.is_set():
        raise MotionAborted("stopped before the move (Ctrl-C or SIGTERM)")
    robot.command_position(target)
    deadline = time.monotonic() + timeout_s
    while True:
        if stop is not None and stop.is_set():
            robot.stop()  # hold where it is
            raise MotionAborted("the motion was stopped (Ctrl-C or SIGTERM): the robot holds")
        state = robot.read_state()
        err = np.abs(np.asarray(state.q) - target)
        if np.all(err <= tolerance):
            return np.asarray(state.q, dtype=np.float64)
        if state.status is not RobotStatus.ENABLED:
            raise HardwareError(f"the robot stopped while moving: {state.status.value}")
        if time.monotonic() > deadline:
            raise HardwareError(
                f"the robot did not reach {np.round(target, 4).tolist()} (rad, rad, rad, mm) "
                f"within {timeout_s:.0f} s: still {np.round(err, 4).tolist()} away"
            )
        time.sleep(poll_s)


def guided_registration(
    robot: Any,
    tracker: Any,
    sensor2tip: Array,
    *,
    n_average: int = 8,
    max_residual_mm: float = 2.0,
    settle_s: float = 0.3,
    twin: FollowingTwin | None = None,
    report: Callable[[str], None] = print,
    stop: threading.Event | None = None,
) -> Registration:
    """Register the tracker to the robot base (the control core's ``registration``
    procedure): the straight catheter translated and rolled, the sensor averaged over
    ``n_average`` samples in the tracker frame at each state, ``tracker2base`` fitted.

    Reports each state and the residual through ``report``; sets ``tracker.registration``.
    RegistrationError when the RMS residual exceeds ``max_residual_mm`` (a wrong mount, a
    moved field generator) or too few states were tracked; MotionAborted when ``stop`` is set
    (the robot holds where it is). The catheter ends at q = 0.
    """
    from icenav.calibration.procedure import run_procedure
    from icenav.calibration.procedures import RegistrationProcedure, make_procedure

    made = make_procedure("registration", sensor2tip=sensor2tip)
    assert isinstance(made, RegistrationProcedure)
    procedure = dataclasses.replace(made, n_average=int(n_average))

    def move(q: Array) -> None:
        move_and_wait(robot, q, stop=stop)
        if settle_s > 0:  # the catheter settles; a stop ends the wait (the next move raises)
            (stop or threading.Event()).wait(settle_s)
        if twin is not None:
            twin.sync()

    def progress(i: int, visit: Any) -> None:
        if visit.n_average > 0:
            q = visit.q_motor
            report(
                f"  registration state {i}: roll {math.degrees(q[2]):6.1f} deg, "
                f"translation {q[3]:6.1f} mm"
            )

    report(f"registration: {procedure.label}; keep the catheter free and the sensor in the field")
    try:
        outcome = procedure.fit(run_procedure(procedure, move, tracker, progress=progress))
    except MotionAborted:
        raise
    except IcenavError as exc:
        raise RegistrationError(f"registration failed: {exc}") from exc
    reg: Registration = outcome.details
    report(
        f"registration: residual {reg.rms_residual_mm:.2f} mm RMS (max "
        f"{reg.max_residual_mm:.2f} mm) over {reg.n_points} states"
    )
    if reg.rms_residual_mm > max_residual_mm:
        raise RegistrationError(
            f"registration residual {reg.rms_residual_mm:.2f} mm RMS exceeds the limit "
            f"{max_residual_mm:.2f} mm ([registration] max_residual_mm): check the mount "
            "sensor2tip and that the field generator did not move"
        )
    tracker.registration = reg
    return reg


def open_tracker(
    kind: str, settings: TrackerSettings, twin: FollowingTwin | None
) -> tuple[Any, Array | None]:
    """``(tracker, sensor2tip)`` for ``--tracker sim|ndi|none`` (started)."""
    if kind == "none":
        return None, None
    if kind == "sim":
        assert twin is not None
        tracker = twin.tracker
        mount = settings.sensor2tip
        if mount is None:
            mount = np.asarray(tracker.config.sensor2tip)
        tracker.start()
        return tracker, mount
    if kind == "ndi":
        from icenav.devices.ndi import NDIAuroraTracker

        if settings.sensor2tip is None:
            raise ConfigurationError(
                f"--tracker ndi needs the sensor mount: [mount] sensor2tip (4, 4, mm) in the "
                f"tracker configuration ({settings.source})"
            )
        from icenav.devices.tracker_feed import PolledTracker

        # read on its own thread: a BX round trip never runs on the control loop
        ndi = PolledTracker(NDIAuroraTracker(settings.ndi_config()))
        ndi.start()
        return ndi, settings.sensor2tip
    raise ConfigurationError(f"--tracker must be one of sim, ndi, none; got {kind!r}")


def make_hardware_controller(
    robot_config: str | Path,
    *,
    tracker: str = "sim",
    tracker_settings: TrackerSettings | None = None,
    session: str | Path | None = None,
    input_source: InputSource | None = None,
    config: ControllerConfig | None = None,
    seed: int = 100,
    vessel: str = "straight",
    register: bool | None = None,
    report: Callable[[str], None] = print,
    clock: Callable[[], float] = time.monotonic,
    stop: threading.Event | None = None,
) -> SimSession:
    """The controller on the drives of ``robot_config`` and a tracker.

    The drives are homed (their current position becomes q = 0: set the catheter to neutral
    first). The registration: with ``register`` True the guided step runs (and is stored in
    the session); False uses the session's stored one (RegistrationError when it has none);
    None (default) uses the stored one when there is one, else runs the step. With
    ``tracker="sim"`` the twin's plant follows the encoders and renders the ICE image.
    ``stop`` set (Ctrl-C, SIGTERM) ends the registration at once (MotionAborted).
    """
    from icenav.devices.canopen.config import load_robot_config
    from icenav.devices.canopen.robot import CANopenRobot

    settings = tracker_settings or TrackerSettings()
    cfg = load_robot_config(robot_config)
    report(
        f"robot: {len(cfg.motors)} CiA 402 drives on {cfg.bus.interface}:{cfg.bus.channel} "
        f"({cfg.mode.value}); homing: the current position becomes q = 0"
    )
    robot = CANopenRobot(cfg, clock=clock)
    store: SessionStore | None = None
    trk: Any = None
    try:
        robot.home()
        twin = FollowingTwin(robot, seed, vessel, clock) if tracker == "sim" else None
        trk, mount = open_tracker(tracker, settings, twin)
        if session is not None:
            store = SessionStore(session, clock=clock)
        stored = store.registration() if store is not None else None
        if trk is not None:
            if register is False or (register is None and stored is not None):
                if stored is None:
                    raise RegistrationError(
                        "the session holds no registration: run the registration step "
                        "(icenav run --registration new)"
                    )
                trk.registration = stored
                report(
                    f"registration: from the session ({stored.rms_residual_mm:.2f} mm RMS "
                    f"over {stored.n_points} states)"
                )
            else:
                assert mount is not None
                reg = guided_registration(
                    robot,
                    trk,
                    mount,
                    n_average=settings.n_average,
                    max_residual_mm=settings.max_residual_mm,
                    settle_s=settings.settle_s if tracker != "sim" else 0.0,
                    twin=twin,
                    report=report,
                    stop=stop,
                )
                if store is not None:
                    store.save_registration(reg, clock())
                    report(f"registration: stored in the session {store.path}")
        ctrl, renderer = _controller(robot, twin, trk, store, input_source, config, clock)
    except BaseException:
        if store is not None:
            store.close()
        if trk is not None:
            trk.stop()
        robot.close()
        raise
    recorder = resumed = None
    if store is not None:
        resumed = resume_calibration(ctrl, store)
        recorder = StoreRecorder(store, ctrl.roadmap, threaded=True)
        ctrl.set_recorder(recorder)
    plant = twin.plant if twin is not None else None
    return SimSession(ctrl, plant, trk, renderer, store, recorder, resumed_calibration=resumed)


def _controller(
    robot: Any,
    twin: FollowingTwin | None,
    tracker: Any,
    store: SessionStore | None,
    input_source: InputSource | None,
    config: ControllerConfig | None,
    clock: Callable[[], float],
) -> tuple[Controller, Any]:
    from icenav.apps.wiring import make_imager

    roadmap = views = None
    if store is not None:
        roadmap = store.load_roadmap()
        roadmap.break_trace()
        views = store.load_views()
    renderer = imager = ijk2tip = None
    if twin is not None:
        renderer, imager, ijk2tip = make_imager()
    ctrl = Controller(
        robot,
        config,
        roadmap=roadmap,
        views=views,
        input_source=input_source,
        truth=None if twin is None else twin.truth,
        tracker=tracker,
        imager=imager,
        image_ijk2tip=ijk2tip,
        clock=clock,
    )
    return ctrl, renderer

"""A disturbed plant: any catheter plant inside a moving heart, with contact, flow and a
shaft that sticks and slips; and a tracker that measures it over time.

:class:`DisturbedPlant` wraps a plant of the plug-in protocol (``move(q_motor) -> tip2base``,
``move_along(path)``, ``reset(q_motor=None)``, ``state.tip2base``) and is one itself, so the
simulated robot, the evaluations and the console drive it unchanged. The wrapped plant
gets the motor commands unchanged (its own laws stay as they are); around it:

1. the shaft's lost motion (:mod:`icenav.sim.introducer`) moves the bending section's base
   rigidly: translation ``s(t)`` along and roll ``rho(t)`` about the base axis,
   ``P0 = Trans_z(s) Rot_z(rho) P_plant``;
2. flow drag and contact with the moving walls (:mod:`icenav.sim.contact`) deflect it:
   ``P = deflect(P0, t)``.

The pose depends on time as well as on the motor state (the heart beats and breathes, the
shaft settles), so the plant reads a clock: ``state`` is the state now, :meth:`state_at`
the state at any time since the last move (the catheter held still since then).
:class:`DisturbedTracker` samples the pose over the measurement window as a tracker does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.devices.tracker import TrackerFrame
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY
from icenav.geometry.se3 import rigid_inverse
from icenav.sim.contact import ContactForce, ContactModel
from icenav.sim.introducer import ShaftFriction

__all__ = [
    "DisturbedPlant",
    "DisturbedState",
    "DisturbedTracker",
    "HELD_POSE_TOL_MM",
    "HELD_POSE_TOL_RAD",
    "TwinForceSensor",
    "mean_pose",
]

_DISTURBANCE_RATE_HZ = 40.0
"""Rate at which a tracker's averaged samples see the disturbance (Hz)."""


@dataclass(frozen=True)
class DisturbedState:
    """The disturbed catheter at one instant."""

    t: float
    """Time (s)."""
    q_motor: Array
    """(4,) motor joint state (rad, rad, rad, mm)."""
    tip2base: Array
    """(4, 4) true pose of the image centre frame (mm)."""
    plant_tip2base: Array
    """(4, 4) pose the wrapped plant gives for the motor state (mm), undisturbed."""
    contacts: tuple[ContactForce, ...]
    """Contacts with the walls (force > 0)."""
    shaft_translation_mm: float
    """Lost motion of the bending section's base along its axis (mm)."""
    shaft_roll_rad: float
    """Lost roll of the bending section's base (rad)."""
    deflection_mm: float
    """How far flow and contact move the image centre (mm)."""
    inner: Any
    """The wrapped plant's own state."""

    @property
    def contact_force_n(self) -> float:
        """Total normal contact force (N)."""
        return float(sum(c.force_n for c in self.contacts))


def _rigid_z(translation_mm: float, roll_rad: float) -> Array:
    c, s = math.cos(roll_rad), math.sin(roll_rad)
    return np.array(
        [[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, translation_mm], [0, 0, 0, 1.0]]
    )


HELD_POSE_TOL_MM = 1e-6
"""A held command whose inner plant re-solves to a tip within this distance (mm) ..."""
HELD_POSE_TOL_RAD = 1e-9
"""... and this rotation (rad, largest entry of the rotation matrices' difference) is no new
motor state: the re-solve of an unchanged plant differs by about 1e-15 mm, a settling one
moves by far more."""


def _moved(pose: Array, before: Array) -> bool:
    """Whether the inner plant's tip (4, 4) moved beyond the held-pose tolerances."""
    return bool(
        np.max(np.abs(pose[:3, 3] - before[:3, 3])) > HELD_POSE_TOL_MM
        or np.max(np.abs(pose[:3, :3] - before[:3, :3])) > HELD_POSE_TOL_RAD
    )


class DisturbedPlant:
    """A plant with the shaft's stick-slip, flow and contact (see the module docstring).

    Parameters
    ----------
    plant : plant of the plug-in protocol
        The catheter (e.g. :class:`icenav.sim.plant.CatheterPlant`).
    clock : callable returning s
        Simulation time.
    shaft : ShaftFriction, optional
        None: the base follows the motors exactly (the robot grips the shaft at the
        section).
    contact : ContactModel, optional
        None: no flow and no walls.
    solve_period_s : float
        While commands stream in, flow and contact are solved at most this often (s); in
        between, :meth:`move` returns the new undeflected pose with the last deflection held
        (a 25 Hz update of a catheter that moves a few mm/s). :attr:`state` and
        :meth:`state_at` always solve.
    """

    def __init__(
        self,
        plant: Any,
        clock: Callable[[], float],
        *,
        shaft: ShaftFriction | None = None,
        contact: ContactModel | None = None,
        solve_period_s: float = 0.04,
    ) -> None:
        for name in ("move", "reset"):
            if not callable(getattr(plant, name, None)):
                raise ConfigurationError(f"the plant must have a callable {name}()")
        if not (math.isfinite(solve_period_s) and solve_period_s >= 0.0):
            raise ConfigurationError(f"solve_period_s must be >= 0 s, got {solve_period_s}")
        self.inner = plant
        self.clock = clock
        self.shaft = shaft
        self.contact = contact
        self.solve_period_s = float(solve_period_s)
        self.geometry = getattr(plant, "geometry", DEFAULT_GEOMETRY)
        self.peak_contact_force_n = 0.0
        """Largest total contact force of a solved state since :meth:`reset_peak` (N)."""
        self._last_force = 0.0
        self._moves = 0
        self._cache: tuple[float, int, DisturbedState] | None = None
        self._solved: tuple[float, Array] = (-math.inf, np.eye(4))
        self.reset()

    # --- plug-in protocol -------------------------------------------------------------------

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        """Relax the catheter at ``q_motor`` (default zeros): the wrapped plant and the shaft."""
        self.inner.reset(q_motor)
        q = np.zeros(4) if q_motor is None else np.asarray(q_motor, np.float64).reshape(4)
        t = float(self.clock())
        if self.shaft is not None:
            self.shaft.reset(float(q[3]), float(q[2]), t)
        self._new_motor_state(q, t)
        self._solved = (-math.inf, np.eye(4))
        self.state_at(t)

    def move(self, q_motor: ArrayLike) -> Array:
        """Move the motors to ``q_motor`` (4,) now; returns the (4, 4) true tip2base (mm)."""
        q = np.asarray(q_motor, np.float64)
        t = float(self.clock())
        self.inner.move(q)  # the plant checks the command first
        if q.shape == (4,) and np.array_equal(q, self._q):
            # a held command: the motors stay, time goes on (the plant may still settle)
            pose = np.asarray(self.inner.state.tip2base, np.float64)
            if _moved(pose, self._pose_at_move):
                self._new_motor_state(q, t)
            elif not np.array_equal(pose, self._plant_pose):
                # round-off of the re-solve: the plant's latest pose, the same motor state
                self._set_inner_state(self.inner.state)
                self._cache = None
            return self._pose_for_move(t)
        if self.shaft is not None:
            self.shaft.drive(float(q[3]), float(q[2]), t)
        self._new_motor_state(q.reshape(4), t)
        return self._pose_for_move(t)

    def move_along(self, q_path: ArrayLike) -> Array:
        """:meth:`move` through the states of ``q_path`` (n, 4); returns (n, 4, 4)."""
        path = np.asarray(q_path, np.float64)
        if path.ndim != 2 or path.shape[1] != 4:
            raise ConfigurationError(f"q_path must have shape (n, 4), got {path.shape}")
        return np.stack([self.move(q) for q in path]) if len(path) else np.empty((0, 4, 4))

    @property
    def state(self) -> DisturbedState:
        """The state now."""
        return self.state_at(float(self.clock()))

    # --- time -------------------------------------------------------------------------------

    @property
    def last_move_s(self) -> float:
        """Time (s) of the last move or reset."""
        return self._t_move

    def reset_peak(self) -> None:
        """Start a new peak of :attr:`peak_contact_force_n`."""
        self.peak_contact_force_n = 0.0

    @property
    def last_contact_force_n(self) -> float:
        """Total contact force of the last solved state (N): free to read while commands
        stream in (solved at most every ``solve_period_s``)."""
        return self._last_force

    def anatomy_moved(self) -> None:
        """Forget the solved states: the walls moved (a patient shift), the next state is
        solved anew."""
        self._cache = None
        self._solved = (-math.inf, np.eye(4))

    def _new_motor_state(self, q: Array, t: float) -> None:
        self._q = q.copy()
        self._q.setflags(write=False)
        self._t_move = t
        self._moves += 1
        self._set_inner_state(self.inner.state)
        self._pose_at_move = self._plant_pose
        self._shape: Any = None

    def _set_inner_state(self, inner_state: Any) -> None:
        self._inner_state = inner_state
        self._plant_pose = np.array(inner_state.tip2base, np.float64)
        self._plant_pose.setflags(write=False)

    def _pose_for_move(self, t: float) -> Array:
        """The pose :meth:`move` returns: solved at most every ``solve_period_s``."""
        t_solved, deflection = self._solved
        if t - t_solved >= self.solve_period_s or self.contact is None:
            return self.state_at(t).tip2base.copy()
        s, rho = self._lost_motion(t)
        out: Array = deflection @ (
            _rigid_z(s, rho) @ self._plant_pose if (s or rho) else self._plant_pose
        )
        return out

    def _lost_motion(self, t: float) -> tuple[float, float]:
        if self.shaft is None:
            return 0.0, 0.0
        self.shaft.advance(max(t, self.shaft.time))
        return self.shaft.lost_motion(t)

    def state_at(self, t: float) -> DisturbedState:
        """The state at time ``t`` (s); times before the last move give the state just after
        it (the catheter has been still since then)."""
        t = max(float(t), self._t_move)
        if self._cache is not None and self._cache[0] == t and self._cache[1] == self._moves:
            return self._cache[2]
        s, rho = self._lost_motion(t)
        frame = _rigid_z(s, rho)
        free = frame @ self._plant_pose if (s or rho) else self._plant_pose.copy()
        contacts: tuple[ContactForce, ...] = ()
        deflection = 0.0
        pose = free
        if self.contact is not None:
            if self._shape is None:
                self._shape = self.contact.shape(self._plant_pose)
            sol = self.contact.solve(self._shape, self._plant_pose, t, frame)
            pose, contacts, deflection = sol.tip2base, sol.contacts, sol.deflection_mm
            inv = np.eye(4)
            inv[:3, :3] = free[:3, :3].T
            inv[:3, 3] = -free[:3, :3].T @ free[:3, 3]
            self._solved = (t, pose @ inv)
        pose.setflags(write=False)
        st = DisturbedState(
            t, self._q, pose, self._plant_pose, contacts, s, rho, deflection, self._inner_state
        )
        self.peak_contact_force_n = max(self.peak_contact_force_n, st.contact_force_n)
        self._last_force = st.contact_force_n
        self._cache = (t, self._moves, st)
        return st

    def pose_at(self, t: float) -> Array:
        """(4, 4) true tip2base at time ``t`` (s) (see :meth:`state_at`)."""
        return self.state_at(t).tip2base


def mean_pose(poses: Array) -> Array:
    """Mean of poses (n, 4, 4): mean position, chordal mean rotation (as the EM tracker
    averages its samples)."""
    stack = np.asarray(poses, np.float64)
    out = np.eye(4)
    out[:3, 3] = stack[:, :3, 3].mean(axis=0)
    u, _, vt = np.linalg.svd(stack[:, :3, :3].sum(axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    out[:3, :3] = u @ np.diag([1.0, 1.0, d]) @ vt
    return out


class TwinForceSensor:
    """The robot's contact-force reading on the twin: the total contact force of the
    catheter now (N), as a force/tension channel of a robot would estimate it (e.g. from the
    drive currents or a load cell at the sheath); ``noise_n`` adds Gaussian noise (seeded).

    Parameters
    ----------
    plant : DisturbedPlant
    noise_n : float
        Standard deviation of the reading's noise (N).
    seed : int
    """

    def __init__(self, plant: DisturbedPlant, noise_n: float = 0.0, seed: int = 0) -> None:
        if not (math.isfinite(noise_n) and noise_n >= 0):
            raise ConfigurationError(f"noise_n must be >= 0 N, got {noise_n}")
        self.plant = plant
        self.noise_n = float(noise_n)
        self._rng = np.random.default_rng([int(seed), 0xF0])

    def contact_force_n(self) -> float | None:
        """Total contact force now (N)."""
        f = self.plant.last_contact_force_n
        if self.noise_n:
            f = max(0.0, f + self.noise_n * float(self._rng.standard_normal()))
        return float(f)


class DisturbedTracker:
    """A tracker of a :class:`DisturbedPlant`: the wrapped plant's tracker, with each sample
    taken at its own time over the measurement window.

    A sample of the wrapped tracker measures the undisturbed pose ``P_plant`` with the
    tracker's error ``E`` (``m = E P_plant``); the disturbance is a rigid motion
    ``D(t) = P(t) P_plant^-1`` in the base frame, applied to the sample: ``D(t_k) m_k``. The
    field distortion is evaluated where the undisturbed tip is; over the millimetres the
    disturbances move the tip, the twin's field (about 250 mm wavelength) changes by a few
    hundredths of a millimetre.

    Parameters
    ----------
    tracker : object with ``measure_tip2base(n_average=1)``
        The plant's tracker (e.g. :class:`icenav.sim.tracker.EMTracker`).
    plant : DisturbedPlant
    rate_hz : float
        Sample rate: ``n`` averaged samples span the last ``n / rate_hz`` s.
    """

    def __init__(self, tracker: Any, plant: DisturbedPlant, rate_hz: float = 80.0) -> None:
        if not callable(getattr(tracker, "measure_tip2base", None)):
            raise ConfigurationError("the tracker must have measure_tip2base(n_average)")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigurationError(f"rate_hz must be > 0 Hz, got {rate_hz}")
        self.inner = tracker
        self.plant = plant
        self.rate_hz = float(rate_hz)
        self._last_frame: tuple[float, TrackerFrame] | None = None

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """Tracked tip pose (4, 4) in the base frame averaged over the last ``n_average``
        samples (mm); None if every sample dropped out."""
        if isinstance(n_average, bool) or int(n_average) != n_average or n_average < 1:
            raise ConfigurationError(f"n_average must be an integer >= 1, got {n_average!r}")
        n = int(n_average)
        now = float(self.plant.clock())
        plant_inv = self._plant_inverse(now)
        samples = []
        disturbance: dict[int, Array] = {}
        for k in range(n):
            m = self.inner.measure_tip2base(1)
            if m is None:
                continue
            # the disturbance is evaluated on a 40 Hz grid (it varies with the heart beat)
            key = round((now - (n - 1 - k) / self.rate_hz) * _DISTURBANCE_RATE_HZ)
            if key not in disturbance:
                disturbance[key] = self.plant.pose_at(key / _DISTURBANCE_RATE_HZ) @ plant_inv
            samples.append(disturbance[key] @ np.asarray(m, np.float64))
        if not samples:
            return None
        return mean_pose(np.stack(samples))

    def sample_window(self, duration_s: float, rate_hz: float | None = None) -> tuple[Array, Array]:
        """The individual samples of the last ``duration_s`` (s) at ``rate_hz`` (default the
        tracker's rate), as a tracker's sample buffer holds them: (n,) times (s) and
        (n, 4, 4) tip2base (mm); dropped samples left out. The catheter is assumed still
        over the window (each sample at its own time of the disturbance)."""
        rate = self.rate_hz if rate_hz is None else float(rate_hz)
        if not (math.isfinite(rate) and rate > 0):
            raise ConfigurationError(f"rate_hz must be > 0 Hz, got {rate_hz}")
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ConfigurationError(f"duration_s must be > 0 s, got {duration_s}")
        n = max(1, int(round(float(duration_s) * rate)))
        now = float(self.plant.clock())
        plant_inv = self._plant_inverse(now)
        times, poses = [], []
        for k in range(n):
            m = self.inner.measure_tip2base(1)
            if m is None:
                continue
            t = now - (n - 1 - k) / rate
            times.append(t)
            poses.append(self.plant.pose_at(t) @ plant_inv @ np.asarray(m, np.float64))
        if not poses:
            return np.zeros(0), np.zeros((0, 4, 4))
        return np.asarray(times), np.stack(poses)

    def get_frame(self) -> TrackerFrame:
        """The wrapped tracker's newest frame, moved by the disturbance at its acquisition
        time ``t``: ``sensor2tracker' = base2tracker D(t) tracker2base sensor2tracker`` with
        the tracker's true placement (its ``config.tracker2base``), as the product's control
        loop reads the tracker (:class:`icenav.devices.tracker.PoseSampleBuffer`). A frame
        without a pose, or a wrapped tracker without a known placement, is returned as is."""
        frame: TrackerFrame = self.inner.get_frame()
        if frame.sensor2tracker is None:
            return frame
        if self._last_frame is not None and frame.timestamp == self._last_frame[0]:
            return self._last_frame[1]
        tracker2base = getattr(getattr(self.inner, "config", None), "tracker2base", None)
        if tracker2base is None:
            return frame
        t2b = np.asarray(tracker2base, np.float64)
        d = self.plant.pose_at(float(frame.timestamp)) @ self._plant_inverse(
            float(self.plant.clock())
        )
        s2t = rigid_inverse(t2b) @ d @ t2b @ np.asarray(frame.sensor2tracker, np.float64)
        s2t.setflags(write=False)
        out = TrackerFrame(frame.timestamp, s2t, frame.status, frame.quality)
        self._last_frame = (frame.timestamp, out)
        return out

    def _plant_inverse(self, t: float) -> Array:
        """inv(P_plant) (4, 4) at time ``t``: the undisturbed pose the wrapped tracker
        measures, removed before the disturbed one is applied (``D = P(t) P_plant^-1``)."""
        return rigid_inverse(self.plant.state_at(t).plant_tip2base)

    def __getattr__(self, name: str) -> Any:
        # registration, start, stop, ... of the wrapped tracker
        return getattr(self.inner, name)

"""The catheter plant: a quasi-static physical model of one ICE catheter.

Motor joint state ``q_motor = (phi1, phi2, phi3, d4)`` (rad, rad, rad, mm) in, true pose of the
image centre frame out. The chain (equations numbered as in ``docs/digital-twin.md``):

1. Handle (T1): knob j pulls tendon i by ``p_i = s_i r_h phi_j - slack_j`` (s_i = +-1, the
   antagonistic pair); ``p_i < 0`` means the tendon is slack: a dead-zone of
   ``+- slack_j / r_h`` around the cross-over where neither tendon of the pair is taut.
2. Sheath (T2)-(T4): capstan friction along the tendon's path, with the exponent
   ``x_i = mu (shaft + bend) + mu_lumen vessel``, makes the distal pull ``d_i`` stick inside a
   band ``[p_i - c T_i g+(x_i) - w0, p_i + c T_i g-(x_i) + w0]`` (a play operator whose
   width grows with tension and curvature): hysteresis, path dependent, so the plant keeps
   internal state.
3. Bending section (T5)-(T8): moment balance with anisotropic, coupled, strain-stiffening
   bending stiffness and compliant one-sided tendons (:mod:`icenav.sim.bending`).
4. Roll and translation (T9): torsional and axial play between the robot's front unit (which
   grips the shaft just proximal of the bending section, the paper's Section II) and the
   section, so the vessel, which lies between the front and back units, does not widen it;
   (T9b) a distal torsional play of the bent section turns the image frame about its own
   axis.
5. Pose (T10): constant-curvature arc of the solved curvature, then the roll, the translation
   and the ultrasound offset, as in :func:`icenav.geometry.kinematics.forward`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_joint_state
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.sim.bending import PAIR, PULL_SIGN, Section
from icenav.sim.params import PlantParams, Vessel

__all__ = [
    "CatheterPlant",
    "MAX_SUBSTEP_RAD",
    "PlantState",
    "backbone_points",
    "elastic_tip2base",
    "elastic_tip2base_from_tensions",
    "move_path",
    "snapshot_state",
]

MAX_SUBSTEP_RAD = 0.02
"""A move is split into substeps of at most this knob change (rad) so the play follows the
path (about 1.1 deg; a 360-sample spin at 60 deg needs 1 substep per sample)."""


@dataclass(frozen=True)
class PlantState:
    """Snapshot of the plant after a move (all arrays read-only)."""

    q_motor: Array
    """(4,) motor joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm)."""
    tip2base: Array
    """(4, 4) true pose of the image centre frame in the base frame (mm)."""
    bend_angle: float
    """True bending angle alpha (rad)."""
    bend_plane: float
    """True bending-plane angle theta (rad), from base x about base z (before roll)."""
    curvature_per_mm: Array
    """(2,) body curvature (u_x, u_y) of the bending section (1/mm)."""
    tendon_tensions_n: Array
    """(4,) tension of tendons A (+x), B (-x), C (+y), D (-y) at the bending section (N)."""
    tendon_pulls_mm: Array
    """(4,) distal pull of each tendon after slack and sheath play (mm)."""
    effective_knobs: Array
    """(2,) model knob angles (rad) that would give the true bend in the constant-curvature
    model: what the motor knobs effectively achieved after slack, play and elasticity."""
    roll: float
    """True roll of the bending section's base (rad), after torsional play."""
    twist: float
    """Twist of the image frame about its own axis relative to the bending section (rad):
    the distal torsional play."""
    translation_mm: float
    """True translation of the bending section's base (mm), after axial lost motion."""


def _g_plus(x: float) -> float:
    """Extra sheath stretch factor when the tendon is pulled: (e^x - 1)/x - 1 (T3)."""
    if x < 1e-6:
        return 0.5 * x
    return math.expm1(x) / x - 1.0


def _g_minus(x: float) -> float:
    """Stretch deficit factor when the tendon is released: 1 - (1 - e^-x)/x (T4)."""
    if x < 1e-6:
        return 0.5 * x
    return 1.0 + math.expm1(-x) / x


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def snapshot_state(plant: Any) -> PlantState:
    """The frozen :class:`PlantState` of a plant built on the twin's section (the default
    twin and the plant families): its motor state ``_q``, pose ``_pose``, curvature ``_u``,
    tensions ``_t``, pulls ``_d``, bending length ``_length``, ``geometry``, ``_roll``,
    ``_twist`` and ``_trans``."""
    ux, uy = plant._u
    L = plant._length
    k = plant.geometry.knob_ratio
    arrays = [
        np.array(plant._q),
        plant._pose.copy(),
        np.array(plant._u),
        np.array(plant._t),
        np.array(plant._d),
        np.array([L * uy / k, -L * ux / k]),
    ]
    for a in arrays:
        a.setflags(write=False)
    return PlantState(
        q_motor=arrays[0],
        tip2base=arrays[1],
        bend_angle=L * math.hypot(ux, uy),
        bend_plane=math.atan2(-ux, uy),
        curvature_per_mm=arrays[2],
        tendon_tensions_n=arrays[3],
        tendon_pulls_mm=arrays[4],
        effective_knobs=arrays[5],
        roll=plant._roll,
        twist=plant._twist,
        translation_mm=plant._trans,
    )


def move_path(plant: Any, q_path: ArrayLike) -> Array:
    """Move a twin-section plant (the default twin, the plant families) through the joint
    states ``q_path`` (n, 4) in order, as n moves; its poses (n, 4, 4) (mm, base frame)."""
    path = plant._check(q_path)
    if path.ndim != 2:
        raise ShapeError(f"q_path must have shape (n, 4), got {path.shape}")
    out = np.empty((path.shape[0], 4, 4))
    for i, row in enumerate(path.tolist()):
        plant._goto(row[0], row[1], row[2], row[3])
        out[i] = plant._pose
    return out


def backbone_points(plant: Any, n: int) -> Array:
    """True shape of a twin-section plant's bending section: (n, 3) points from its base to
    its end (mm, base frame), from its curvature ``_u``, ``_length``, ``_roll``, ``_trans``."""
    if isinstance(n, bool) or int(n) != n or int(n) < 2:
        raise ConfigurationError(f"n must be an integer >= 2 points, got {n!r}")
    s = np.linspace(0.0, plant._length, int(n))
    ux, uy = plant._u
    kappa = math.hypot(ux, uy)
    if kappa * plant._length < 1e-9:
        pts = np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=-1)
    else:
        # arc in the bending plane theta: lateral (1 - cos(kappa s))/kappa, axial sin/kappa
        theta = math.atan2(-ux, uy)
        lat = (1.0 - np.cos(kappa * s)) / kappa
        ax = np.sin(kappa * s) / kappa
        pts = np.stack([lat * math.cos(theta), lat * math.sin(theta), ax], axis=-1)
    c, sn = math.cos(plant._roll), math.sin(plant._roll)
    rz = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    pts = pts @ rz.T
    pts[:, 2] += plant._trans
    return pts


class CatheterPlant:
    """One simulated ICE catheter in a vessel (see the module docstring for the physics).

    Parameters
    ----------
    seed : int
        Catheter identity: parameters are ``PlantParams.sample(seed)`` unless ``params`` given.
    vessel : "straight" | "moderate" | "steep" | Vessel
        Path of the shaft; the paper's phantom conditions by name.
    params : PlantParams, optional
        Explicit parameters (e.g. ``PlantParams.nominal()``); overrides ``seed``.
    geometry : CatheterGeometry
        Nominal geometry and joint limits (motor commands are checked against them).
    """

    def __init__(
        self,
        seed: int = 0,
        vessel: str | Vessel = "straight",
        params: PlantParams | None = None,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        if params is None:
            params = PlantParams.sample(seed)
        elif not isinstance(params, PlantParams):
            raise ConfigurationError(f"params must be a PlantParams, got {type(params).__name__}")
        if not isinstance(geometry, CatheterGeometry):
            raise ConfigurationError(
                f"geometry must be a CatheterGeometry, got {type(geometry).__name__}"
            )
        self.seed = seed
        self.params = params
        self.geometry = geometry
        self.vessel = vessel if isinstance(vessel, Vessel) else Vessel.named(vessel)
        p = params
        self._length = geometry.bending_length * p.bending_length_scale
        self._section = Section(p, self._length)
        self._handle = (p.handle_radius_ap_mm, p.handle_radius_rl_mm)
        self._slack = (p.slack_ap_mm, p.slack_ap_mm, p.slack_rl_mm, p.slack_rl_mm)
        # Eq. (T2): the vessel's wrap at the lumen's coefficient (0 in the straight vessel)
        self._x_vessel = p.lumen_friction_coefficient * self.vessel.total_curvature_rad
        self.reset()

    # --- state ---------------------------------------------------------------------------

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        """Relax the catheter at ``q_motor`` (default zeros): history cleared, no friction
        stored, the tendons in the equilibrium a friction-free transmission would give."""
        q = np.zeros(4) if q_motor is None else self._check(q_motor)
        self._q = [float(x) for x in q]
        d = self._pulls(self._q[0], self._q[1])
        self._d = list(d)
        self._u = self._section.solve_pulls(tuple(d), 0.0, 0.0)
        self._t = self._section.tensions(tuple(d), *self._u)
        self._roll = self._q[2]
        self._twist = 0.0
        self._trans = self._q[3]
        self._pose = self._pose_now()

    @property
    def state(self) -> PlantState:
        """The current state (a frozen snapshot)."""
        return snapshot_state(self)

    # --- motion --------------------------------------------------------------------------

    def move(self, q_motor: ArrayLike) -> Array:
        """Move the motors from the current state to ``q_motor`` along a straight joint path.

        Parameters
        ----------
        q_motor : array-like, shape (4,)
            Motor joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm) within the geometry's limits.

        Returns
        -------
        tip2base : ndarray, shape (4, 4)
            True pose of the image centre frame in the base frame (mm).
        """
        q = self._check(q_motor)
        if q.shape != (4,):
            raise ShapeError(f"move takes one joint state of shape (4,), got {q.shape}")
        self._goto(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        return self._pose.copy()

    def move_along(self, q_path: ArrayLike) -> Array:
        """Move through the joint states of ``q_path`` in order; same as ``n`` calls of move.

        Parameters
        ----------
        q_path : array-like, shape (n, 4)
            Motor joint states (rad, rad, rad, mm).

        Returns
        -------
        tip2base : ndarray, shape (n, 4, 4)
            True pose after each move (mm, base frame).
        """
        return move_path(self, q_path)

    def backbone(self, n: int = 50) -> Array:
        """True shape of the bending section: (n, 3) points from its base to its end (mm, base)."""
        return backbone_points(self, n)

    # --- internals -----------------------------------------------------------------------

    def _check(self, q: ArrayLike) -> Array:
        return check_joint_state(q, self.geometry.joint_limits, name="q_motor")

    def _pulls(self, phi1: float, phi2: float) -> tuple[float, float, float, float]:
        """Eq. (T1): proximal pull of each tendon (mm) for knob angles (rad)."""
        r = self._handle
        phis = (phi1, phi2)
        return tuple(  # type: ignore[return-value]
            PULL_SIGN[i] * r[PAIR[i]] * phis[PAIR[i]] - self._slack[i] for i in range(4)
        )

    def _goto(self, phi1: float, phi2: float, phi3: float, d4: float) -> None:
        q0 = self._q
        n = max(1, math.ceil(max(abs(phi1 - q0[0]), abs(phi2 - q0[1])) / MAX_SUBSTEP_RAD))
        a1, a2 = q0[0], q0[1]
        for j in range(1, n + 1):
            f = j / n
            self._substep(a1 + f * (phi1 - a1), a2 + f * (phi2 - a2))
        # Eq. (T9): roll and translation follow the front unit through a play
        bend = self._length * math.hypot(*self._u)
        h = self.params.roll_play_rad + self.params.roll_play_per_bend * bend
        tip_roll = self._roll + self._twist
        self._roll = _clip(self._roll, phi3 - h, phi3 + h)
        # the image frame follows the section's roll through the distal play (T9b)
        h = self.params.twist_play_per_bend * bend
        tip_roll = _clip(tip_roll, self._roll - h, self._roll + h)
        self._twist = tip_roll - self._roll
        h = self.params.translation_play_mm
        self._trans = _clip(self._trans, d4 - h, d4 + h)
        self._q = [phi1, phi2, phi3, d4]
        self._pose = self._pose_now()

    def _substep(self, phi1: float, phi2: float) -> None:
        p = self.params
        c = p.tendon_compliance_mm_per_n
        mu = p.friction_coefficient
        w0 = p.seal_play_mm
        ux, uy = self._u
        bend = self._length * math.hypot(ux, uy)
        # Eq. (T2): capstan exponent of the handle, the section's own bend and the vessel
        x = mu * (p.shaft_curvature_rad + bend) + self._x_vessel
        gp = _g_plus(x)
        gm = _g_minus(x)
        pulls = self._pulls(phi1, phi2)
        d = self._d
        for i in range(4):
            t = self._t[i]
            # Eqs. (T3)-(T4): the distal pull sticks inside the friction band
            d[i] = _clip(d[i], pulls[i] - c * t * gp - w0, pulls[i] + c * t * gm + w0)
        dt = tuple(d)
        self._u = self._section.solve_pulls(dt, ux, uy)
        self._t = self._section.tensions(dt, *self._u)

    def _pose_now(self) -> Array:
        """Eq. (T10): pose of the true arc, roll, translation and ultrasound offset."""
        ux, uy = self._u
        L = self._length
        k = self.geometry.knob_ratio
        scale = L / self.geometry.bending_length
        # the kinematics' arc with the true length: scale the position of the tilt part
        q_eq = np.array([L * uy / k, -L * ux / k, self._roll, 0.0])
        pose = forward(q_eq, self.geometry, check=False)
        if scale != 1.0:
            # forward() used the nominal length L0: tip = R_z(roll) P_tilt(L0) + off * z_tip;
            # the true arc is P_tilt(L) = (L / L0) P_tilt(L0)
            z = pose[:3, 2]
            arc = pose[:3, 3] - self.geometry.us_offset * z
            pose[:3, 3] = scale * arc + self.geometry.us_offset * z
        if self._twist != 0.0:
            # Eq. (T9b): rotate the image frame about its own z axis (the centre stays put)
            c, s = math.cos(self._twist), math.sin(self._twist)
            x = pose[:3, 0].copy()
            y = pose[:3, 1].copy()
            pose[:3, 0] = c * x + s * y
            pose[:3, 1] = -s * x + c * y
        pose[2, 3] += self._trans
        return pose


def elastic_tip2base(
    params: PlantParams, phi1: float, phi2: float, geometry: CatheterGeometry = DEFAULT_GEOMETRY
) -> Array:
    """The plant's elastic response alone: no slack, no friction, no play (roll 0, d4 0).

    The tendon pulls are ``+- r_h phi`` exactly; what remains is the bending section's
    elasticity (T5)-(T8). The tuning oracle (``icenav.sim.tuning``) inverts this map.
    Returns the (4, 4) tip2base (mm).
    """
    plant = CatheterPlant(params=params.elastic_only(), geometry=geometry)
    plant.reset(np.array([phi1, phi2, 0.0, 0.0]))
    return plant.state.tip2base.copy()


def elastic_tip2base_from_tensions(
    params: PlantParams,
    tensions_n: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> Array:
    """Tip pose (4, 4) of the bending section held by given tendon tensions (N), roll 0, d4 0.

    The plant's moment balance (T6)-(T7) alone, for validation against
    :func:`icenav.sim.reference.solve_tendon_rod` (tensions of A, B, C, D).
    """
    t = np.asarray(tensions_n, dtype=np.float64)
    if t.shape != (4,) or not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ConfigurationError(f"tensions_n must be 4 finite values >= 0 N, got {t}")
    plant = CatheterPlant(params=params, geometry=geometry)
    ux, uy = plant._section.solve_tensions(tuple(float(x) for x in t))
    plant._u = (ux, uy)
    plant._roll = 0.0
    plant._twist = 0.0
    plant._trans = 0.0
    return plant._pose_now()

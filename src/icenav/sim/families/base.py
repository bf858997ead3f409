"""What the plant families share: the handle, the bending section's statics and the pose.

A family plant keeps the default twin's handle (T1), elastic bending section (T5)-(T8)
(:class:`icenav.sim.bending.Section`) and arc pose (T10), and brings its own laws for what
lies between: the tendons' transmission through the sheath (proximal pull ``p_i`` in,
distal pull ``d_i`` out) and the roll and twist of the section (the front unit's roll
``phi3`` in, the section's roll and the image frame's twist out). A family subclasses
:class:`SectionPlant` and implements the four hooks::

    _reset_transmission(pulls) -> distal pulls      # relaxed, friction-free equilibrium
    _transmit(pulls, dt) -> distal pulls            # one substep; dt (s) of its duration
    _reset_turn(phi3)                               # relaxed roll and twist
    _turn(phi3, dt) -> (roll, twist)                # one substep

``dt`` is 0 for rate-independent families (the default plant's quasi-static substeps);
a rate-dependent family drives its own clock (:mod:`icenav.sim.families.rate_dependent`).
Parameters of a family are drawn per catheter with :func:`sample_params` (the elastic
:class:`~icenav.sim.params.PlantParams` from a stream of the family's own, so family
catheter ``s`` is not the default twin's catheter ``s``).
"""

from __future__ import annotations

import math
from dataclasses import fields, replace
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_joint_state
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.sim.bending import PAIR, PULL_SIGN, Section
from icenav.sim.params import TOLERANCES, PlantParams, Vessel
from icenav.sim.plant import (
    MAX_SUBSTEP_RAD,
    PlantState,
    backbone_points,
    move_path,
    snapshot_state,
)

__all__ = [
    "SectionPlant",
    "check_seed",
    "draw",
    "family_rng",
    "sample_params",
]

Pulls = tuple[float, float, float, float]


def check_seed(seed: object) -> int:
    """A catheter seed: an integer >= 0 (ConfigurationError otherwise)."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigurationError(f"seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def family_rng(seed: int, tag: int) -> np.random.Generator:
    """The random stream of catheter ``seed`` in the family with ``tag`` (a fixed integer
    per family, so two families' catheters of one seed are independent draws)."""
    return np.random.default_rng([check_seed(seed), int(tag)])


def draw(
    rng: np.random.Generator, nominal: float, tolerance: float, relative: bool = True
) -> float:
    """One parameter uniform within ``nominal`` +- ``tolerance`` (a fraction if relative)."""
    x = float(rng.uniform(-1.0, 1.0))
    return nominal * (1.0 + tolerance * x) if relative else nominal + tolerance * x


def sample_params(
    rng: np.random.Generator, spread: tuple[float, float] = (0.0, 1.0)
) -> PlantParams:
    """Elastic and handle parameters of one catheter, drawn around the nominal ones.

    Each field of :class:`PlantParams` moves from its nominal value by ``m * tolerance``
    (:data:`icenav.sim.params.TOLERANCES`, relative or absolute) with ``m`` uniform in
    ``spread`` (in multiples of today's tolerance) and a random sign: ``(0, 1)`` is today's
    band (the default twin's distribution, from another stream), ``(2, 3)`` lies outside it.
    """
    lo, hi = (float(spread[0]), float(spread[1]))
    if not (0.0 <= lo <= hi):
        raise ConfigurationError(f"spread must be 0 <= low <= high (tolerances), got {spread}")
    nom = PlantParams.nominal()
    values: dict[str, float] = {}
    for f in fields(PlantParams):
        base = float(getattr(nom, f.name))
        kind, tol = TOLERANCES[f.name]
        m = float(rng.uniform(lo, hi)) * (1.0 if rng.random() < 0.5 else -1.0)
        values[f.name] = base * (1.0 + m * tol) if kind == "rel" else base + m * tol
    return replace(nom, **values)


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class SectionPlant:
    """Base of the family plants: handle (T1), section (T5)-(T8), pose (T10); the family
    brings the transmission and the roll (see the module docstring).

    Parameters
    ----------
    seed : int
        Catheter identity (kept as ``self.seed``; the subclass draws its parameters).
    vessel : "straight" | "moderate" | "steep" | Vessel
        Path of the shaft between the robot's units (the paper's phantom conditions).
    params : PlantParams
        Handle, tendon routing and bending-section parameters (the frictions and plays of
        :class:`PlantParams` are not used: the family has its own).
    geometry : CatheterGeometry
        Nominal geometry and joint limits (motor commands are checked against them).
    """

    family: ClassVar[str] = ""
    """The family's registry name."""

    def __init__(
        self,
        seed: int,
        vessel: str | Vessel,
        params: PlantParams,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        if not isinstance(params, PlantParams):
            raise ConfigurationError(f"params must be a PlantParams, got {type(params).__name__}")
        if not isinstance(geometry, CatheterGeometry):
            raise ConfigurationError(
                f"geometry must be a CatheterGeometry, got {type(geometry).__name__}"
            )
        self.seed = check_seed(seed)
        self.params = params
        self.geometry = geometry
        self.vessel = vessel if isinstance(vessel, Vessel) else Vessel.named(vessel)
        p = params
        self._length = geometry.bending_length * p.bending_length_scale
        self._section = Section(p, self._length)
        self._handle = (p.handle_radius_ap_mm, p.handle_radius_rl_mm)
        self._slack = (p.slack_ap_mm, p.slack_ap_mm, p.slack_rl_mm, p.slack_rl_mm)
        self._q = [0.0, 0.0, 0.0, 0.0]
        self._d: list[float] = [0.0, 0.0, 0.0, 0.0]
        self._u = (0.0, 0.0)
        self._t: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
        self._roll = 0.0
        self._twist = 0.0
        self._trans = 0.0
        self._pose = np.eye(4)

    # --- family hooks ---------------------------------------------------------------------

    def _reset_transmission(self, pulls: Pulls) -> Pulls:
        raise NotImplementedError

    def _transmit(self, pulls: Pulls, dt: float) -> Pulls:
        raise NotImplementedError

    def _reset_turn(self, phi3: float) -> None:
        raise NotImplementedError

    def _turn(self, phi3: float, dt: float) -> tuple[float, float]:
        raise NotImplementedError

    # --- what the families' laws may read --------------------------------------------------

    @property
    def bend(self) -> float:
        """True bending angle of the section now (rad)."""
        return self._length * math.hypot(*self._u)

    @property
    def tension_sum_n(self) -> float:
        """Sum of the four tendon tensions at the section now (N)."""
        return float(sum(self._t))

    # --- the protocol ---------------------------------------------------------------------

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        """Relax the catheter at ``q_motor`` (default zeros): every friction and history
        state cleared, the tendons in the friction-free equilibrium."""
        q = np.zeros(4) if q_motor is None else self._check(q_motor)
        self._q = [float(x) for x in q]
        d = self._reset_transmission(self._pulls(self._q[0], self._q[1]))
        self._d = list(d)
        self._u = self._section.solve_pulls(tuple(d), 0.0, 0.0)
        self._t = self._section.tensions(tuple(d), *self._u)
        self._reset_turn(self._q[2])
        self._roll = self._q[2]
        self._twist = 0.0
        self._trans = self._q[3]
        self._pose = self._pose_now()

    @property
    def state(self) -> PlantState:
        """The current state (a frozen snapshot; the same fields as the default twin's)."""
        return snapshot_state(self)

    def move(self, q_motor: ArrayLike) -> Array:
        """Move the motors to ``q_motor`` (4,) (rad, rad, rad, mm) along a straight joint path;
        return the (4, 4) true tip2base (mm)."""
        q = self._check(q_motor)
        if q.shape != (4,):
            raise ShapeError(f"move takes one joint state of shape (4,), got {q.shape}")
        self._goto(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        return self._pose.copy()

    def move_along(self, q_path: ArrayLike) -> Array:
        """Move through ``q_path`` (n, 4) in order (same as n moves); poses (n, 4, 4) (mm)."""
        return move_path(self, q_path)

    def backbone(self, n: int = 50) -> Array:
        """True shape of the bending section: (n, 3) points from its base to its end (mm)."""
        return backbone_points(self, n)

    # --- internals ------------------------------------------------------------------------

    def _check(self, q: ArrayLike) -> Array:
        return check_joint_state(q, self.geometry.joint_limits, name="q_motor")

    def _pulls(self, phi1: float, phi2: float) -> Pulls:
        """Eq. (T1): proximal pull of each tendon (mm) for knob angles (rad)."""
        r = self._handle
        phis = (phi1, phi2)
        return tuple(  # type: ignore[return-value]
            PULL_SIGN[i] * r[PAIR[i]] * phis[PAIR[i]] - self._slack[i] for i in range(4)
        )

    def _substeps(self, q0: list[float], q1: tuple[float, float, float, float]) -> int:
        """Substeps of a move: knob and roll changes of at most MAX_SUBSTEP_RAD each."""
        step = max(abs(q1[0] - q0[0]), abs(q1[1] - q0[1]), abs(q1[2] - q0[2]))
        return max(1, math.ceil(step / MAX_SUBSTEP_RAD))

    def _goto(
        self, phi1: float, phi2: float, phi3: float, d4: float, dt_total: float = 0.0
    ) -> None:
        """Walk the joints to the command in substeps (each substep lasting
        ``dt_total / n`` s), the family's transmission and roll at each."""
        q0 = list(self._q)
        target = (phi1, phi2, phi3, d4)
        n = self._substeps(q0, target)
        for j in range(1, n + 1):
            f = j / n
            self._substep(
                q0[0] + f * (phi1 - q0[0]),
                q0[1] + f * (phi2 - q0[1]),
                q0[2] + f * (phi3 - q0[2]),
                dt_total / n,
            )
        # axial lost motion of the front unit (the default twin's translation play)
        h = self.params.translation_play_mm
        self._trans = _clip(self._trans, d4 - h, d4 + h)
        self._q = [phi1, phi2, phi3, d4]
        self._pose = self._pose_now()

    def _substep(self, phi1: float, phi2: float, phi3: float, dt: float) -> None:
        d = self._transmit(self._pulls(phi1, phi2), dt)
        self._d = list(d)
        self._u = self._section.solve_pulls(d, *self._u)
        self._t = self._section.tensions(d, *self._u)
        self._roll, self._twist = self._turn(phi3, dt)

    def _pose_now(self) -> Array:
        """Eq. (T10): the true arc, roll, twist, translation and ultrasound offset."""
        ux, uy = self._u
        L = self._length
        k = self.geometry.knob_ratio
        scale = L / self.geometry.bending_length
        pose = forward(
            np.array([L * uy / k, -L * ux / k, self._roll, 0.0]), self.geometry, check=False
        )
        if scale != 1.0:
            z = pose[:3, 2]
            arc = pose[:3, 3] - self.geometry.us_offset * z
            pose[:3, 3] = scale * arc + self.geometry.us_offset * z
        if self._twist != 0.0:
            c, s = math.cos(self._twist), math.sin(self._twist)
            x = pose[:3, 0].copy()
            y = pose[:3, 1].copy()
            pose[:3, 0] = c * x + s * y
            pose[:3, 1] = -s * x + c * y
        pose[2, 3] += self._trans
        return pose

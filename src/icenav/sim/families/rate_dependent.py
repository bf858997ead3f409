"""Family ``rate-dependent``: Dahl friction with Stribeck and viscous terms, friction
relaxation and tendon creep; the reached pose depends on the motor speed and drifts after a
stop.

Every joint's transmission (each tendon: proximal pull in, distal pull out; the roll: the
front unit's angle in, the section's roll out; the twist: the section's roll in, the image
frame's roll out) is a spring whose stretch ``x_in - x_out`` carries a dynamic friction
state ``zeta`` (the Dahl model, the LuGre model without its bristle damping: Dahl 1968;
Canudas de Wit, Olsson, Astrom & Lischinsky 1995) and a viscous drag (lubricated sheath)::

    x_in - x_out = zeta + tau_v v,                v = d x_out / dt               (R1)
    d zeta/dt = v (1 - sgn(v) zeta / w(v)) / lam - (zeta - zeta_r) / tau_rel      (R2)
    zeta_r = sgn(zeta) min(|zeta|, r_h w(v))                                      (R2b)
    w(v) = w_c (1 + s exp(-(v / v_s)^2))                                          (R3) Stribeck

``zeta`` is the stretch the friction holds (bounded by ``w``, reached after an output travel
of about ``lam w``: rounded loops); ``w_c`` is the Coulomb level (as a stretch), ``s`` the
static excess; ``tau_v`` the viscous time constant: the faster the motion the more the
output lags (rate dependence); ``tau_rel`` the slow relaxation of held friction down to a
fraction ``r_h`` of its level (contact creep of the polymer lumen: static friction that
held a tendon at the Coulomb level holds only part of it after a while), through which a
wound-up joint keeps creeping after a stop, and then stops.
The Coulomb level grows with the tension (normal force; linear, no capstan form)::

    w_c,i = (w0 + c_f T_i)(1 + g_v Theta_vessel)                                   (R4) tendon i
    w_c,roll = h0 + c_r sum_i T_i,   w_c,twist = c_t sum_i T_i                      (R5)

The tendons are viscoelastic (a standard linear solid, Zener 1948; polymer tendons creep):
an extra elongation ``e_i`` follows the tension with a retardation time ``tau_c``, and the
section sees ``d_i - e_i``::

    de_i/dt = (c_c T_i - e_i) / tau_c                                               (R6)

So the bend sags while a knob is held, and the wound-up roll relaxes, between moves.

**Time** comes from the plant's own clock, never from wall time: a move ramps the motors to
the command at ``motor_speed`` (rad/s, rad/s, rad/s, mm/s; the controller's path speed, half
its limit), then (own clock) holds for ``settle_s`` (the calibration's settle before a
tracker reading, 0.3 s). With an injected ``clock`` the plant holds, before each move and
whenever its state is read, until the clock's time (a simulated clock advanced by the
controller). :meth:`RateDependentPlant.wait` holds for a given time. (R1)-(R3) are
integrated implicitly (a closed-form root per step), (R6) exactly for each step's tension.

How it differs from the default twin and our compensation: no model of ours has time in
it; the default's and ``compensation/``'s plays are rate-independent sharp plays
(``transmission.py``'s capstan band, ``hysteresis.py``'s ``h0 + h1 bend``); here a loop's
width depends on the speed, corners are rounded, and the pose keeps moving after the
motors stop.

Magnitudes (assumptions, not tuned to any method): the Coulomb levels equal the default
twin's plays at a 50 deg bend (about 11 N of total tension); ``tau_v`` = 0.05 s gives a lag
of 1.5 deg of knob at the controller's 30 deg/s; creep ``c_c`` = 15 % of the tendon
compliance with ``tau_c`` = 4 s (a polymer tendon); ``tau_rel`` = 20 s (tendons), 10 s
(roll, twist), to ``r_h`` = 50 % of the level.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.sim.families.base import Pulls, SectionPlant, draw, family_rng, sample_params
from icenav.sim.params import PlantParams, Vessel
from icenav.sim.plant import PlantState

__all__ = [
    "DEFAULT_MOTOR_SPEED",
    "DahlJoint",
    "RateDependentPlant",
    "RateParams",
]

TAG = 0x7A7E
"""Random-stream tag of the family."""

DEFAULT_MOTOR_SPEED = (math.radians(30.0), math.radians(30.0), math.radians(45.0), 5.0)
"""Motor speed of a move (rad/s, rad/s, rad/s, mm/s): half the controller's speed limit, as
its path tasks drive."""
MAX_DT_S = 0.02
"""Longest integration step while the motors move (s)."""
FIRST_HOLD_DT_S = 0.02
"""First step of a hold (s); the steps double, up to a quarter of the slowest time
constant."""


@dataclass(frozen=True)
class RateParams:
    """Dynamic parameters of one catheter (lengths mm, angles rad, forces N, times s)."""

    tendon_level_mm: float = 0.03
    """w0 (R4): tension-free Coulomb level of a tendon (mm of stretch)."""
    tendon_level_per_n: float = 0.02
    """c_f (R4): Coulomb level per N of the tendon's tension (mm/N)."""
    vessel_gain_per_rad: float = 0.25
    """g_v (R4): growth of the tendon levels per rad of vessel curvature."""
    roll_level_rad: float = 0.015
    """h0 (R5): Coulomb level of the roll (rad)."""
    roll_level_per_n: float = 0.007
    """c_r (R5): roll level per N of total tension (rad/N)."""
    twist_level_per_n: float = 0.012
    """c_t (R5): twist level per N of total tension (rad/N)."""
    presliding: float = 0.3
    """lam (R2): output travel to reach the Coulomb level, in units of the level."""
    static_excess: float = 0.3
    """s (R3): static friction above Coulomb (fraction)."""
    stribeck_speed_mm_s: float = 0.5
    """v_s of the tendons (R3) (mm/s)."""
    stribeck_speed_rad_s: float = 0.1
    """v_s of the roll and twist (R3) (rad/s)."""
    tendon_viscous_s: float = 0.05
    """tau_v of the tendons (R1) (s)."""
    roll_viscous_s: float = 0.1
    """tau_v of the roll and the twist (R1) (s)."""
    tendon_relaxation_s: float = 20.0
    """tau_rel of the tendons (R2) (s)."""
    roll_relaxation_s: float = 10.0
    """tau_rel of the roll and the twist (R2) (s)."""
    held_fraction: float = 0.5
    """r_h (R2b): fraction of the friction level that held friction relaxes to."""
    creep_compliance_mm_per_n: float = 0.006
    """c_c (R6): the tendon's extra compliance after creep (mm/N)."""
    creep_time_s: float = 4.0
    """tau_c (R6): retardation time of the tendon's creep (s)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            positive = f.name.endswith("_s") or f.name in ("presliding",)
            if not math.isfinite(v) or v < 0.0 or (positive and v <= 0.0):
                raise ConfigurationError(
                    f"{f.name} must be finite and {'> 0' if positive else '>= 0'}, got {v}"
                )
        if self.held_fraction > 1.0:
            raise ConfigurationError(f"held_fraction must be in [0, 1], got {self.held_fraction}")

    @classmethod
    def sample(cls, rng: np.random.Generator) -> RateParams:
        """A catheter's draw: every value +-20 % (uniform)."""
        n = cls()
        return cls(**{f.name: draw(rng, float(getattr(n, f.name)), 0.2) for f in fields(cls)})


class DahlJoint:
    """One joint's transmission (R1)-(R3): state ``x_out``, ``zeta``, last speed ``v``."""

    __slots__ = ("lam", "tau_v", "tau_rel", "held", "s", "v_s", "x_out", "zeta", "v")

    def __init__(
        self, lam: float, tau_v: float, tau_rel: float, held: float, s: float, v_s: float
    ) -> None:
        self.lam = lam
        self.tau_v = tau_v
        self.tau_rel = tau_rel
        self.held = held
        self.s = s
        self.v_s = v_s
        self.x_out = 0.0
        self.zeta = 0.0
        self.v = 0.0

    def reset(self, x: float) -> None:
        """At rest at x, no friction held."""
        self.x_out = x
        self.zeta = 0.0
        self.v = 0.0

    def step(self, x_in: float, dt: float, w_c: float) -> float:
        """Advance by ``dt`` (s > 0) with the input at ``x_in`` at the end of the step and
        Coulomb level ``w_c``; returns ``x_out``. Implicit Euler: (R1) with (R2) is a
        quadratic in the new speed v on each side of 0, with one root there ((R3) and the
        floor of (R2b) taken at the step's start)."""
        w = max(w_c * (1.0 + self.s * math.exp(-((self.v / self.v_s) ** 2))), 1e-12)  # (R3)
        a_ = x_in - self.x_out
        c = dt + self.tau_v
        b = 1.0 + dt / self.tau_rel
        a = dt / (self.lam * w)
        e = dt / self.lam
        # (R2b), from the step's start: the relaxation's floor enters as a constant
        floor = math.copysign(min(abs(self.zeta), self.held * w), self.zeta)
        z = self.zeta + floor * (dt / self.tau_rel)
        rhs = a_ * b - z  # sign of the residual at v = 0 (times b)
        ca = c * a
        if rhs >= 0.0:
            b1 = c * b + e - a_ * a
            v = 2.0 * rhs / (b1 + math.sqrt(b1 * b1 + 4.0 * ca * rhs))
        else:
            b2 = a_ * a + c * b + e
            v = -2.0 * (-rhs) / (b2 + math.sqrt(b2 * b2 + 4.0 * ca * (-rhs)))
        self.v = v
        self.x_out += v * dt
        self.zeta = (z + e * v) / (b + a * abs(v))
        return self.x_out


class RateDependentPlant(SectionPlant):
    """A catheter with dynamic (Dahl-Stribeck-viscous) friction and creep; see the module
    docstring for the law and the clock.

    Parameters
    ----------
    seed : int
        Catheter identity (elastic parameters within today's tolerances, dynamics +-20 %,
        from the family's stream of this seed unless given).
    vessel : "straight" | "moderate" | "steep" | Vessel
        Path of the shaft.
    clock : callable returning s, optional
        An injected (simulated) clock; default: the plant's own clock, advanced by the moves.
    motor_speed : 4 floats
        Speed of the motors during a move (rad/s, rad/s, rad/s, mm/s).
    settle_s : float
        Own clock only: time held after each move before it returns (s).
    params, dynamics : optional
        Explicit parameters (override the seed's draw).
    """

    family = "rate-dependent"

    def __init__(
        self,
        seed: int = 0,
        vessel: str | Vessel = "straight",
        *,
        clock: Callable[[], float] | None = None,
        motor_speed: ArrayLike = DEFAULT_MOTOR_SPEED,
        settle_s: float = 0.3,
        params: PlantParams | None = None,
        dynamics: RateParams | None = None,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> None:
        rng = family_rng(seed, TAG)
        drawn = sample_params(rng)
        drawn_dyn = RateParams.sample(rng)
        self.dynamics = drawn_dyn if dynamics is None else dynamics
        self.clock = clock
        self.motor_speed = motor_speed  # validated by the setter
        s = float(settle_s)
        if not (math.isfinite(s) and s >= 0.0):
            raise ConfigurationError(f"settle_s must be >= 0 s, got {settle_s!r}")
        self.settle_s = s
        self.time = 0.0 if clock is None else float(clock())
        """The plant's time (s): its own clock, or the injected clock's at the last update."""
        r = self.dynamics
        self._joints = [
            DahlJoint(
                r.presliding,
                r.tendon_viscous_s,
                r.tendon_relaxation_s,
                r.held_fraction,
                r.static_excess,
                r.stribeck_speed_mm_s,
            )
            for _ in range(4)
        ] + [
            DahlJoint(
                r.presliding,
                r.roll_viscous_s,
                r.roll_relaxation_s,
                r.held_fraction,
                r.static_excess,
                v_s,
            )
            for v_s in (r.stribeck_speed_rad_s, r.stribeck_speed_rad_s)
        ]
        self._creep = [0.0, 0.0, 0.0, 0.0]
        self._max_hold_dt = 0.25 * min(r.tendon_relaxation_s, r.roll_relaxation_s, r.creep_time_s)
        super().__init__(seed, vessel, drawn if params is None else params, geometry)
        self._vessel_gain = 1.0 + r.vessel_gain_per_rad * self.vessel.total_curvature_rad
        self.reset()

    # --- the clock ------------------------------------------------------------------------

    @property
    def motor_speed(self) -> Array:
        """(4,) speed of the motors during a move (rad/s, rad/s, rad/s, mm/s)."""
        return self._speed.copy()

    @motor_speed.setter
    def motor_speed(self, value: ArrayLike) -> None:
        v = np.asarray(value, dtype=np.float64)
        if v.shape != (4,) or not np.all(np.isfinite(v)) or np.any(v <= 0.0):
            raise ConfigurationError(
                f"motor_speed must be 4 values > 0 (rad/s, rad/s, rad/s, mm/s), got {value!r}"
            )
        self._speed = v

    def wait(self, seconds: float) -> Array:
        """Hold the motors for ``seconds`` (s >= 0) of the plant's time; return the (4, 4)
        tip2base after it (the pose drifts: creep and relaxation)."""
        s = float(seconds)
        if not (math.isfinite(s) and s >= 0.0):
            raise ConfigurationError(f"wait needs seconds >= 0 s, got {seconds!r}")
        self._hold(s)
        self._pose = self._pose_now()
        return self._pose.copy()

    @property
    def state(self) -> PlantState:
        """The current state; with an injected clock, after holding until its time."""
        if self.clock is not None:
            self._catch_up()
        return super().state

    def _catch_up(self) -> None:
        now = float(self.clock()) if self.clock is not None else self.time
        if now > self.time:
            self._hold(now - self.time)
            self._pose = self._pose_now()

    def _hold(self, duration: float) -> None:
        """Hold the motors at the current command for ``duration`` s (steps doubling from
        FIRST_HOLD_DT_S up to a quarter of the slowest time constant)."""
        q = self._q
        left = duration
        dt = FIRST_HOLD_DT_S
        while left > 1e-12:
            step = min(dt, left)
            self._substep(q[0], q[1], q[2], step)
            self.time += step
            left -= step
            dt = min(2.0 * dt, self._max_hold_dt)

    def _goto(
        self, phi1: float, phi2: float, phi3: float, d4: float, dt_total: float = 0.0
    ) -> None:
        """Ramp the motors at ``motor_speed``, then settle (own clock)."""
        if self.clock is not None:
            self._catch_up()
        dq = np.abs(np.array([phi1, phi2, phi3, d4]) - np.array(self._q))
        ramp = float(np.max(dq / self._speed))
        q0 = list(self._q)
        n = max(self._substeps(q0, (phi1, phi2, phi3, d4)), math.ceil(ramp / MAX_DT_S))
        if ramp > 0.0:
            for j in range(1, n + 1):
                f = j / n
                self._substep(
                    q0[0] + f * (phi1 - q0[0]),
                    q0[1] + f * (phi2 - q0[1]),
                    q0[2] + f * (phi3 - q0[2]),
                    ramp / n,
                )
            self.time += ramp
        self._q = [phi1, phi2, phi3, d4]
        h = self.params.translation_play_mm
        self._trans = min(max(self._trans, d4 - h), d4 + h)
        if self.clock is None and self.settle_s > 0.0:
            self._hold(self.settle_s)
        self._pose = self._pose_now()

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        """Relax the catheter at ``q_motor`` (default zeros): no friction held, no creep yet;
        with an injected clock, relaxed as of its time now."""
        if self.clock is not None:
            self.time = max(self.time, float(self.clock()))
        super().reset(q_motor)

    # --- the family's laws ----------------------------------------------------------------

    def _reset_transmission(self, pulls: Pulls) -> Pulls:
        for joint, p in zip(self._joints, pulls, strict=False):
            joint.reset(p)
        self._creep = [0.0, 0.0, 0.0, 0.0]
        return pulls

    def _transmit(self, pulls: Pulls, dt: float) -> Pulls:
        if dt <= 0.0:
            return tuple(self._d)  # type: ignore[return-value]
        r = self.dynamics
        decay = math.exp(-dt / r.creep_time_s)
        out = []
        for i in range(4):
            t = self._t[i]
            level = (r.tendon_level_mm + r.tendon_level_per_n * t) * self._vessel_gain  # (R4)
            d = self._joints[i].step(pulls[i], dt, level)  # (R1)-(R3)
            goal = r.creep_compliance_mm_per_n * t
            self._creep[i] = goal + (self._creep[i] - goal) * decay  # (R6), exact for T fixed
            out.append(d - self._creep[i])
        return tuple(out)  # type: ignore[return-value]

    def _reset_turn(self, phi3: float) -> None:
        self._joints[4].reset(phi3)
        self._joints[5].reset(phi3)

    def _turn(self, phi3: float, dt: float) -> tuple[float, float]:
        if dt <= 0.0:
            return self._roll, self._twist
        r = self.dynamics
        tension = self.tension_sum_n
        roll = self._joints[4].step(phi3, dt, r.roll_level_rad + r.roll_level_per_n * tension)
        tip = self._joints[5].step(roll, dt, r.twist_level_per_n * tension)  # (R5)
        return roll, tip - roll

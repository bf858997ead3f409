"""Stick-slip of the catheter shaft in the introducer sheath and the vessel, and its slow
settling.

The robot's front unit drives the shaft's proximal end (translation ``d``, roll ``psi``);
between it and the bending section the shaft is a compliant rod held by friction in the
introducer's seal and along the vessel. Its distal end (the base of the bending section)
therefore lags the drive by a lost motion that depends on where the last slip ended, and in
vivo the vessel wall, moving with breathing, drags it. Equations as in
``docs/digital-twin.md``, section 9:

* (S1) Elastic load on the distal shaft, as one force vector (N):
  ``f = (k_a (d - x), k_t (psi - phi) / r)`` (axial; torsional as the tangential force at the
  shaft's surface).
* (S2) Stick: the distal end moves with the wall, ``x = x_w + w(t)``, ``phi`` fixed, while
  ``|f| <= F_s`` (a friction disc: axial and torsional slip share one friction budget).
* (S3) Slip: when ``|f| > F_s`` the end slides until ``|f| = F_k`` in the direction of
  ``f`` (quasi-static, heavily damped in blood); a new stick starts.
* (S4) Static friction grows with the time ``t_s`` stuck (frictional ageing, Dieterich;
  Rabinowicz): ``F_s = F_s0 xi (1 + beta ln(1 + t_s / t_a))``, ``xi`` drawn per stick
  (``1 + sigma_s N(0, 1)``, at least ``F_k / F_s0``): asperity junctions renew at each slip.
* (S5) Wall: ``w(t) = e (z_b . u(X_j, t))``, the displacement of the IVC-RA junction
  (the beat and breathing) along the base axis times the entrainment ``e`` of the vessel
  at the shaft's friction contact.
* (S6) Settling: the bending section's base follows the quasi-static end with a first-order
  lag ``tau`` (the long shaft is damped by the blood and the vessel): after a slip that
  moves the end by ``J`` the base is ``J exp(-(t - t_slip) / tau)`` behind.

The lost motion reported to the plant wrapper is ``(x - d, phi - psi)`` plus the lag.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from icenav._validation import check_positive
from icenav.errors import ConfigurationError

__all__ = ["ShaftFriction", "ShaftParams"]

_WALL_MEMO = 512
"""Times whose wall displacement is remembered (then forgotten all at once)."""


@dataclass(frozen=True)
class ShaftParams:
    """Shaft between the front unit and the bending section (sources in the docs)."""

    axial_stiffness_n_per_mm: float = 1.0
    """k_a: axial stiffness of the shaft between the front unit and its friction contact
    (N/mm), including the slack of its path through a wide vessel."""
    torsional_stiffness_nmm_per_rad: float = 20.0
    """k_t: torsional stiffness of that length (N mm/rad)."""
    radius_mm: float = 1.65
    """r: shaft radius (mm), the lever of the torsional friction."""
    static_friction_n: float = 0.3
    """F_s0: static friction after a fresh slip (N)."""
    kinetic_friction_n: float = 0.2
    """F_k: sliding friction (N)."""
    static_friction_sd: float = 0.0
    """sigma_s: relative spread of the static friction drawn at each new stick (S4)."""
    ageing: float = 0.0
    """beta: growth of static friction per e-fold of stick time (S4)."""
    ageing_time_s: float = 1.0
    """t_a: time scale of the ageing (s)."""
    entrainment: float = 0.0
    """e: fraction of the IVC-RA junction's motion (beat and breathing) that the vessel wall
    at the shaft's friction contact follows along the base axis (S5)."""
    settling_time_s: float = 0.0
    """tau: time constant of the bending section's base following the shaft's end (S6)."""
    wall_step_s: float = 0.04
    """Time step at which the moving wall is followed (s)."""

    def __post_init__(self) -> None:
        check_positive(self.axial_stiffness_n_per_mm, "axial_stiffness_n_per_mm", "N/mm")
        check_positive(
            self.torsional_stiffness_nmm_per_rad, "torsional_stiffness_nmm_per_rad", "N mm/rad"
        )
        check_positive(self.radius_mm, "radius_mm", "mm")
        check_positive(self.ageing_time_s, "ageing_time_s", "s")
        check_positive(self.wall_step_s, "wall_step_s", "s")
        fs, fk = float(self.static_friction_n), float(self.kinetic_friction_n)
        if not (math.isfinite(fs) and math.isfinite(fk) and 0.0 <= fk <= fs):
            raise ConfigurationError(
                f"need 0 <= kinetic_friction_n <= static_friction_n (N), got {fk}, {fs}"
            )
        for name, hi in (("static_friction_sd", 1.0), ("ageing", 1.0), ("entrainment", 1.0)):
            v = float(getattr(self, name))
            if not math.isfinite(v) or not 0.0 <= v <= hi:
                raise ConfigurationError(f"{name} must be in [0, {hi}], got {v}")
        if not (math.isfinite(self.settling_time_s) and self.settling_time_s >= 0.0):
            raise ConfigurationError(
                f"settling_time_s must be >= 0 s, got {self.settling_time_s} s"
            )


class ShaftFriction:
    """The shaft's state (S1)-(S6): the lost motion of the bending section's base.

    Parameters
    ----------
    params : ShaftParams
    seed : sequence of int
        Seeds the static friction of each stick (per catheter and patient).
    wall_mm : callable t -> float, optional
        The wall's axial displacement w(t) (S5) (mm); None: a fixed wall.
    """

    def __init__(
        self,
        params: ShaftParams,
        seed: tuple[int, ...],
        wall_mm: Callable[[float], float] | None = None,
    ) -> None:
        self.params = params
        self._rng = np.random.default_rng([*seed, 0x5F])
        self._wall = wall_mm if params.entrainment > 0.0 else None
        self._wall_memo: dict[float, float] = {}
        """w(t) of the times asked lately: a slip's check, the state and the tracker's samples
        ask the same times again (w is a function of time alone)."""
        self.reset(0.0, 0.0, 0.0)

    def reset(self, d_mm: float, psi_rad: float, t: float) -> None:
        """Relax the shaft at drive (d, psi) at time ``t``: no stored load, no lag."""
        self._d = float(d_mm)
        self._psi = float(psi_rad)
        self._t = float(t)
        w = self._wall_at(t)
        self._xw = self._d - w  # stuck position relative to the wall
        self._phi = self._psi
        self._new_stick(t)
        self._lag = (0.0, 0.0)  # base behind the quasi-static end at the last event (mm, rad)
        self._t_event = float(t)
        self._history: list[tuple[float, float, float, tuple[float, float]]] = []
        self._snapshot()
        self.slips = 0
        """Number of slip events so far."""

    def _snapshot(self) -> None:
        """Remember the state from ``t_event`` on (queries of past times read it)."""
        self._history.append((self._t_event, self._xw, self._phi, self._lag))

    def _wall_at(self, t: float) -> float:
        if self._wall is None:
            return 0.0
        w = self._wall_memo.get(t)
        if w is None:
            if len(self._wall_memo) >= _WALL_MEMO:
                self._wall_memo.clear()
            w = self._wall_memo[t] = self.params.entrainment * float(self._wall(t))
        return w

    def _new_stick(self, t: float) -> None:
        p = self.params
        xi = 1.0 + p.static_friction_sd * float(self._rng.standard_normal())
        floor = p.kinetic_friction_n / p.static_friction_n if p.static_friction_n > 0 else 1.0
        self._xi = max(xi, floor)
        self._t_stick = float(t)

    def _threshold(self, t: float) -> float:
        """Eq. (S4): static friction after ``t - t_stick`` s stuck (N)."""
        p = self.params
        age = 1.0 + p.ageing * math.log1p(max(t - self._t_stick, 0.0) / p.ageing_time_s)
        return p.static_friction_n * self._xi * age

    def _check(self, t: float) -> None:
        """Eqs. (S1)-(S3) at time ``t`` with the current drive."""
        p = self.params
        x = self._xw + self._wall_at(t)
        fa = p.axial_stiffness_n_per_mm * (self._d - x)
        ft = p.torsional_stiffness_nmm_per_rad * (self._psi - self._phi) / p.radius_mm
        f = math.hypot(fa, ft)
        if f <= self._threshold(t):
            return
        scale = p.kinetic_friction_n / f
        x_new = self._d - fa * scale / p.axial_stiffness_n_per_mm
        phi_new = self._psi - ft * scale * p.radius_mm / p.torsional_stiffness_nmm_per_rad
        # Eq. (S6): the base keeps its position for now and follows with the lag
        lag_a, lag_r = self._lag_at(t)
        self._lag = (lag_a - (x_new - x), lag_r - (phi_new - self._phi))
        self._t_event = t
        self._xw = x_new - self._wall_at(t)
        self._phi = phi_new
        self._new_stick(t)
        self._snapshot()
        self.slips += 1

    def _lag_at(self, t: float) -> tuple[float, float]:
        return self._lag_pair_at(t)

    def _lag_pair_at(
        self, t: float, t_event: float | None = None, lag: tuple[float, float] | None = None
    ) -> tuple[float, float]:
        tau = self.params.settling_time_s
        if tau <= 0.0:
            return 0.0, 0.0
        t0 = self._t_event if t_event is None else t_event
        lag0 = self._lag if lag is None else lag
        k = math.exp(-max(t - t0, 0.0) / tau)
        return lag0[0] * k, lag0[1] * k

    def advance(self, t: float) -> None:
        """Follow the moving wall (S5) up to time ``t`` (s) with the drive held."""
        if t <= self._t:
            return
        if self._wall is not None:
            step = self.params.wall_step_s
            n = math.ceil((t - self._t) / step - 1e-9)
            for i in range(1, n + 1):
                self._check(min(self._t + i * step, t))
        self._t = t

    def drive(self, d_mm: float, psi_rad: float, t: float) -> None:
        """The front unit moves to (d, psi) at time ``t`` (after :meth:`advance` to ``t``)."""
        self.advance(t)
        if d_mm == self._d and psi_rad == self._psi:
            return
        self._d = float(d_mm)
        self._psi = float(psi_rad)
        self._check(t)
        # the past under the old drive is no longer asked for: keep the state from now on
        self._lag = self._lag_pair_at(t)
        self._t_event = t
        self._history = [(t, self._xw, self._phi, self._lag)]

    def lost_motion(self, t: float) -> tuple[float, float]:
        """Offset of the bending section's base from the drive at time ``t`` (s), at or after
        the last drive change and at most :attr:`time`: translation (mm) along the base
        axis and roll (rad) about it."""
        h = self._history
        i = bisect.bisect_right([e[0] for e in h], t) - 1
        t_ev, xw, phi, lag = h[max(i, 0)]
        x = xw + self._wall_at(t)
        lag_a, lag_r = self._lag_pair_at(t, t_ev, lag)
        return x + lag_a - self._d, phi + lag_r - self._psi

    @property
    def time(self) -> float:
        """Time (s) up to which the shaft has been followed."""
        return self._t

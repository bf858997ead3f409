"""Elastic statics of the bending section (equations (T5)-(T8) of docs/digital-twin.md).

The bending section is a rod of length L with constant body curvature
``u = (u_x, u_y)`` (1/mm): with tendons routed parallel to the axis and no external load the
moment in the body frame is the same at every cross-section, so the curvature is constant
(Rucker & Webster 2011; checked against a Cosserat-rod shooting solution in
``tests/sim/test_reference.py``). ``u_y > 0`` bends toward +x (the AP plane), ``u_x < 0``
toward +y (the RL plane).

Tendon i sits at ``r_i = (r_ix, r_iy)`` (mm) relative to the neutral axis. Its moment arm in
curvature space is ``a_i = (-r_iy, r_ix)`` (mm)::

    shortening_i = L a_i . u                                   # (T5) tendon path shortening
    m(u) = (1 + beta (L |u|)^2) K u,  K = [[EI_rl, EI_c], [EI_c, EI_ap]]   # (T6) strain stiffening
    m(u) = sum_i T_i a_i                                       # (T7) moment balance
    T_i = k softplus_eps(d_i - L a_i . u),  k = 1 / compliance  # (T8) one-sided tendon spring

Pure float math (no arrays in the loop) so one solve costs a few microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from icenav.sim.params import PlantParams

__all__ = ["SOFTPLUS_EPS_MM", "Section", "Tendons"]

SOFTPLUS_EPS_MM = 0.005
"""Smoothing length of the one-sided tendon spring (mm): smooths the slack/taut transition."""

PULL_SIGN = (1.0, -1.0, 1.0, -1.0)
"""Knob 1 pulls tendon A (+) and releases B (-); knob 2 pulls C (+) and releases D (-)."""
PAIR = (0, 0, 1, 1)
"""Knob (0: AP, 1: RL) driving each tendon A, B, C, D."""


@dataclass(frozen=True)
class Tendons:
    """Moment arms of the four tendons A (+x), B (-x), C (+y), D (-y)."""

    arms: tuple[tuple[float, float], ...]
    """a_i = (-r_iy, r_ix) for each tendon (mm), in curvature space (u_x, u_y)."""

    @classmethod
    def from_params(cls, p: PlantParams) -> Tendons:
        rhos = (
            p.tendon_offset_ap_mm,
            p.tendon_offset_ap_mm,
            p.tendon_offset_rl_mm,
            p.tendon_offset_rl_mm,
        )
        angles = (
            p.routing_error_ap_rad,
            math.pi + p.routing_error_ap_rad,
            0.5 * math.pi + p.routing_error_rl_rad,
            -0.5 * math.pi + p.routing_error_rl_rad,
        )
        arms = []
        for rho, ang in zip(rhos, angles, strict=True):
            rx = rho * math.cos(ang) - p.neutral_axis_x_mm
            ry = rho * math.sin(ang) - p.neutral_axis_y_mm
            arms.append((-ry, rx))
        return cls(tuple(arms))


def _softplus(x: float) -> tuple[float, float]:
    """eps * log(1 + exp(x / eps)) and its derivative (a sigmoid), overflow-safe."""
    z = x / SOFTPLUS_EPS_MM
    if z > 30.0:
        return x, 1.0
    if z < -30.0:
        e = math.exp(z)
        return SOFTPLUS_EPS_MM * e, e
    e = math.exp(z)
    return SOFTPLUS_EPS_MM * math.log1p(e), e / (1.0 + e)


class Section:
    """Solver of the bending-section equilibrium for one catheter."""

    __slots__ = ("k00", "k01", "k11", "beta_l2", "length", "stiff_n_per_mm", "arms")

    def __init__(self, p: PlantParams, bending_length_mm: float) -> None:
        self.k00 = p.ei_rl_nmm2
        self.k01 = p.ei_coupling_nmm2
        self.k11 = p.ei_ap_nmm2
        self.length = bending_length_mm
        self.beta_l2 = p.stiffening * bending_length_mm**2
        self.stiff_n_per_mm = 1.0 / p.tendon_compliance_mm_per_n
        self.arms = Tendons.from_params(p).arms

    def moment(self, ux: float, uy: float) -> tuple[float, float]:
        """m(u) of Eq. (T6), N mm, in body axes (x, y)."""
        s = 1.0 + self.beta_l2 * (ux * ux + uy * uy)
        return s * (self.k00 * ux + self.k01 * uy), s * (self.k01 * ux + self.k11 * uy)

    def tensions(self, d: tuple[float, ...], ux: float, uy: float) -> tuple[float, ...]:
        """Tendon tensions (N) of Eq. (T8) for distal pulls d (mm) and curvature u (1/mm)."""
        out = []
        for (ax, ay), di in zip(self.arms, d, strict=True):
            sp, _ = _softplus(di - self.length * (ax * ux + ay * uy))
            out.append(self.stiff_n_per_mm * sp)
        return tuple(out)

    def solve_pulls(
        self, d: tuple[float, ...], ux: float, uy: float, tol: float = 1e-11, max_iter: int = 40
    ) -> tuple[float, float]:
        """Curvature u (1/mm) in equilibrium with distal tendon pulls d (mm), Eqs. (T5)-(T8).

        Damped Newton from the previous curvature (ux, uy); the Jacobian is symmetric positive
        definite, so it converges in 2-4 iterations for quasi-static steps.
        """
        L = self.length
        k = self.stiff_n_per_mm
        for _ in range(max_iter):
            s = 1.0 + self.beta_l2 * (ux * ux + uy * uy)
            kux = self.k00 * ux + self.k01 * uy
            kuy = self.k01 * ux + self.k11 * uy
            gx = s * kux
            gy = s * kuy
            # Jacobian of m(u): s K + 2 beta L^2 (K u) u^T
            j00 = s * self.k00 + 2.0 * self.beta_l2 * kux * ux
            j01 = s * self.k01 + 2.0 * self.beta_l2 * kux * uy
            j10 = s * self.k01 + 2.0 * self.beta_l2 * kuy * ux
            j11 = s * self.k11 + 2.0 * self.beta_l2 * kuy * uy
            for (ax, ay), di in zip(self.arms, d, strict=True):
                sp, sig = _softplus(di - L * (ax * ux + ay * uy))
                t = k * sp
                gx -= t * ax
                gy -= t * ay
                c = k * sig * L
                j00 += c * ax * ax
                j01 += c * ax * ay
                j10 += c * ay * ax
                j11 += c * ay * ay
            det = j00 * j11 - j01 * j10
            dx = (j11 * gx - j01 * gy) / det
            dy = (j00 * gy - j10 * gx) / det
            # limit a Newton step to 0.3 rad of bend so a large jump cannot overshoot
            step = L * math.hypot(dx, dy)
            if step > 0.3:
                dx *= 0.3 / step
                dy *= 0.3 / step
            ux -= dx
            uy -= dy
            if step < tol:
                break
        return ux, uy

    def solve_tensions(
        self, tensions: tuple[float, ...], ux: float = 0.0, uy: float = 0.0
    ) -> tuple[float, float]:
        """Curvature u (1/mm) in equilibrium with given tendon tensions (N): Eqs. (T6)-(T7)."""
        mx = sum(t * a[0] for t, a in zip(tensions, self.arms, strict=True))
        my = sum(t * a[1] for t, a in zip(tensions, self.arms, strict=True))
        for _ in range(60):
            s = 1.0 + self.beta_l2 * (ux * ux + uy * uy)
            kux = self.k00 * ux + self.k01 * uy
            kuy = self.k01 * ux + self.k11 * uy
            gx = s * kux - mx
            gy = s * kuy - my
            j00 = s * self.k00 + 2.0 * self.beta_l2 * kux * ux
            j01 = s * self.k01 + 2.0 * self.beta_l2 * kux * uy
            j10 = s * self.k01 + 2.0 * self.beta_l2 * kuy * ux
            j11 = s * self.k11 + 2.0 * self.beta_l2 * kuy * uy
            det = j00 * j11 - j01 * j10
            dx = (j11 * gx - j01 * gy) / det
            dy = (j00 * gy - j10 * gx) / det
            ux -= dx
            uy -= dy
            if self.length * math.hypot(dx, dy) < 1e-13:
                break
        return ux, uy

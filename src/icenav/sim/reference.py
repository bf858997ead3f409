"""Independent reference: Cosserat-rod statics of a tendon-driven rod (Rucker & Webster 2011).

A shooting solution of the Kirchhoff rod equations (inextensible, unshearable) with the
distributed and tip loads of tendons routed at fixed positions in the cross-section, written
from the paper (D. C. Rucker, R. J. Webster III, "Statics and dynamics of continuum robots
with general tendon routing and external loading", IEEE T-RO 27(6), 2011), not from the
plant's equations. In the body frame, with curvature ``u``, internal force ``n`` and moment
``m = M(u)``::

    p' = R e3,  R' = R [u]x
    n' = -u x n - f,          f = sum_i T_i (u x t_i + t_i')       (tendon i presses on the rod)
    m' = -u x m - e3 x n - l, l = sum_i r_i x T_i (u x t_i + t_i')
    t_i = q_i / |q_i|,  q_i = u x r_i + e3,  t_i' = (I - t_i t_i^T)(u' x r_i) / |q_i|
    m' = dM/du u'  =>  a 3x3 linear system for u'

Tip (s = L), where the tendons end: ``n = -sum_i T_i t_i``, ``M(u) = -sum_i T_i r_i x t_i``.
The base (s = 0) is clamped; the unknown ``n(0), u(0)`` are shot with ``scipy.optimize.root``
over ``scipy.integrate.solve_ivp``. The constitutive law may be anisotropic, coupled and
curvature-stiffening: ``M(u) = (s K_b u_b, GJ u_z)``, ``s = 1 + beta L^2 |u_b|^2``.
Slow (tens of ms); used only by tests and the figure script.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root

from icenav._typing import Array

__all__ = ["RodSolution", "solve_tendon_rod"]


@dataclass(frozen=True)
class RodSolution:
    """Result of :func:`solve_tendon_rod`."""

    s: Array
    """(n,) arc length of the output samples (mm)."""
    positions: Array
    """(n, 3) backbone positions in the base frame (mm)."""
    tip_rotation: Array
    """(3, 3) orientation of the rod's end in the base frame."""
    residual: float
    """Norm of the tip boundary-condition residual of the shooting (N and N mm)."""


def _hat(v: Array) -> Array:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def solve_tendon_rod(
    tendon_positions_mm: Array,
    tensions_n: Array,
    bending_stiffness_nmm2: Array,
    torsional_stiffness_nmm2: float,
    stiffening: float,
    length_mm: float,
    n_out: int = 41,
) -> RodSolution:
    """Shape of a clamped rod bent by tendons that end at its tip (Rucker-Webster statics).

    Parameters
    ----------
    tendon_positions_mm : array, shape (k, 2)
        Position (x, y) of each tendon in the cross-section, relative to the centroid (mm);
        the tendons run parallel to the backbone.
    tensions_n : array, shape (k,)
        Tendon tensions (N, >= 0).
    bending_stiffness_nmm2 : array, shape (2, 2)
        Bending stiffness matrix for body curvature (u_x, u_y) at zero curvature (N mm^2).
    torsional_stiffness_nmm2 : float
        GJ (N mm^2).
    stiffening : float
        beta: the bending stiffness is multiplied by 1 + beta (L |u_b|)^2.
    length_mm : float
        Rod length L (mm).
    """
    r = np.zeros((len(tendon_positions_mm), 3))
    r[:, :2] = np.asarray(tendon_positions_mm, dtype=np.float64)
    tens = np.asarray(tensions_n, dtype=np.float64)
    kb = np.asarray(bending_stiffness_nmm2, dtype=np.float64)
    gj = float(torsional_stiffness_nmm2)
    bl2 = float(stiffening) * float(length_mm) ** 2
    e3 = np.array([0.0, 0.0, 1.0])

    def moment(u: Array) -> Array:
        s = 1.0 + bl2 * (u[0] ** 2 + u[1] ** 2)
        mb = s * (kb @ u[:2])
        return np.array([mb[0], mb[1], gj * u[2]])

    def dmoment(u: Array) -> Array:
        s = 1.0 + bl2 * (u[0] ** 2 + u[1] ** 2)
        ku = kb @ u[:2]
        j = np.zeros((3, 3))
        j[:2, :2] = s * kb + 2.0 * bl2 * np.outer(ku, u[:2])
        j[2, 2] = gj
        return j

    def tangents(u: Array) -> tuple[Array, Array]:
        q = np.cross(u, r) + e3
        qn = np.linalg.norm(q, axis=1)
        return q / qn[:, None], qn

    def rhs(_s: float, y: Array) -> Array:
        rot = y[3:12].reshape(3, 3)
        n = y[12:15]
        u = y[15:18]
        m = moment(u)
        t, qn = tangents(u)
        # m' = J u' = -u x m - e3 x n - sum r_i x T_i (u x t_i + P_i (u' x r_i) / |q_i|)
        lhs = dmoment(u)
        rhs_v = -np.cross(u, m) - np.cross(e3, n)
        f_known = np.zeros(3)
        a_terms = []
        for i in range(len(r)):
            ti = t[i]
            proj = (np.eye(3) - np.outer(ti, ti)) / qn[i]
            # t_i' = proj (u' x r_i) = -proj [r_i]x u' = A_i u'
            a_i = -proj @ _hat(r[i])
            known = tens[i] * np.cross(u, ti)
            f_known += known
            rhs_v -= np.cross(r[i], known)
            lhs = lhs + tens[i] * _hat(r[i]) @ a_i
            a_terms.append(a_i)
        du = np.linalg.solve(lhs, rhs_v)
        f = f_known + sum(tens[i] * (a_terms[i] @ du) for i in range(len(r)))
        dn = -np.cross(u, n) - f
        dp = rot @ e3
        drot = rot @ _hat(u)
        return np.concatenate([dp, drot.ravel(), dn, du])

    def integrate(x: Array, dense: bool = False) -> object:
        y0 = np.concatenate([np.zeros(3), np.eye(3).ravel(), x[:3], x[3:]])
        return solve_ivp(
            rhs,
            (0.0, float(length_mm)),
            y0,
            method="DOP853",
            rtol=1e-10,
            atol=1e-12,
            dense_output=dense,
        )

    def bc(x: Array) -> Array:
        sol = integrate(x)
        y = sol.y[:, -1]  # type: ignore[attr-defined]
        n = y[12:15]
        u = y[15:18]
        t, _ = tangents(u)
        n_err = n + (tens[:, None] * t).sum(axis=0)
        m_err = moment(u) + np.cross(r, tens[:, None] * t).sum(axis=0)
        return np.concatenate([n_err, m_err / float(length_mm)])

    # initial guess: the curvature whose moment balances the tendons' tip moments
    m0 = -np.cross(r, tens[:, None] * e3).sum(axis=0)
    u_lin = np.zeros(3)
    u_lin[:2] = np.linalg.solve(kb, m0[:2])
    u0 = root(lambda u: moment(u) - m0, u_lin, jac=dmoment, method="hybr").x
    x0 = np.concatenate([-tens.sum() * e3, u0])
    res = root(bc, x0, method="hybr", options={"xtol": 1e-12})
    sol = integrate(res.x, dense=True)
    s_out = np.linspace(0.0, float(length_mm), int(n_out))
    ys = sol.sol(s_out)  # type: ignore[attr-defined]
    return RodSolution(
        s=s_out,
        positions=ys[0:3].T.copy(),
        tip_rotation=ys[3:12, -1].reshape(3, 3),
        residual=float(np.linalg.norm(bc(res.x))),
    )

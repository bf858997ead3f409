"""Body Jacobian of the image centre frame and the tip-frame jog (the paper's "intuitive"
control), on the constant-curvature kinematics of :mod:`icenav.geometry.kinematics`.

With ``u = k phi1``, ``v = k phi2`` and the stable forms ``s1(a) = sin(a)/a``,
``c2(a) = (1 - cos a)/a^2`` of the forward kinematics, the derivatives of ``R_tilt`` and
``P_tilt`` are analytic (``ds1/du = (ds1/da)/a * u``, likewise ``c2``), exact at alpha = 0 by
their Taylor series. Column j of the body Jacobian is ``vee(tip2base^-1 d tip2base / d q_j)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state, check_positive
from icenav.errors import ShapeError
from icenav.geometry.kinematics import (
    _SERIES_BELOW,
    DEFAULT_GEOMETRY,
    CatheterGeometry,
    _c2,
    _c2_scalar,
    _s1,
    _s1_scalar,
    _skew,
    _tilt,
)

__all__ = ["jacobian", "tip_jog"]


def _ds1_over_a(a: Array) -> Array:
    """(d/da sin(a)/a) / a = (a cos a - sin a) / a^3."""
    a2 = a * a
    small = a < _SERIES_BELOW
    safe = np.where(small, 1.0, a)
    exact = (safe * np.cos(safe) - np.sin(safe)) / safe**3
    series = -1.0 / 3.0 + a2 / 30.0 - a2 * a2 / 840.0
    return np.where(small, series, exact)


def _dc2_over_a(a: Array) -> Array:
    """(d/da (1 - cos a)/a^2) / a = (a sin a - 2 (1 - cos a)) / a^4."""
    a2 = a * a
    small = a < _SERIES_BELOW
    safe = np.where(small, 1.0, a)
    exact = (safe * np.sin(safe) - 2.0 * (1.0 - np.cos(safe))) / safe**4
    series = -1.0 / 12.0 + a2 / 180.0 - a2 * a2 / 6720.0
    return np.where(small, series, exact)


# --- Jacobian ----------------------------------------------------------------------------


def _tilt_derivatives(u: Array, v: Array, length: float) -> tuple[Array, Array, Array, Array]:
    """Analytic d/du and d/dv of R_tilt and P_tilt (u = k phi1, v = k phi2)."""
    a = np.hypot(u, v)
    s1 = _s1(a)
    c2 = _c2(a)
    ds1 = _ds1_over_a(a)  # (ds1/da) / a, so ds1/du = ds1 * u
    dc2 = _dc2_over_a(a)
    w = np.stack([-v, u, np.zeros_like(u)], axis=-1)
    wx = _skew(w)
    wx2 = wx @ wx
    e_u = _skew(np.broadcast_to(np.array([0.0, 1.0, 0.0]), w.shape))  # dW/du
    e_v = _skew(np.broadcast_to(np.array([-1.0, 0.0, 0.0]), w.shape))  # dW/dv

    def d_rot(x: Array, ex: Array) -> Array:
        return (
            (ds1 * x)[..., None, None] * wx
            + s1[..., None, None] * ex
            + (dc2 * x)[..., None, None] * wx2
            + c2[..., None, None] * (ex @ wx + wx @ ex)
        )

    dr_u = d_rot(u, e_u)
    dr_v = d_rot(v, e_v)
    dp_u = length * np.stack([c2 + dc2 * u * u, dc2 * u * v, ds1 * u], axis=-1)
    dp_v = length * np.stack([dc2 * u * v, c2 + dc2 * v * v, ds1 * v], axis=-1)
    return dr_u, dp_u, dr_v, dp_v


def _ds1_over_a_scalar(a: float) -> float:
    if a < _SERIES_BELOW:
        a2 = a * a
        return -1.0 / 3.0 + a2 / 30.0 - a2 * a2 / 840.0
    return (a * math.cos(a) - math.sin(a)) / (a * a * a)


def _dc2_over_a_scalar(a: float) -> float:
    if a < _SERIES_BELOW:
        a2 = a * a
        return -1.0 / 12.0 + a2 / 180.0 - a2 * a2 / 6720.0
    return (a * math.sin(a) - 2.0 * (1.0 - math.cos(a))) / (a * a * a * a)


def _mat3(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    return [
        [a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)]
        for i in range(3)
    ]


def _jacobian_scalar(q: Array, g: CatheterGeometry) -> Array:
    """Fast path of :func:`jacobian` for one joint state, in plain floats: the same analytic
    derivatives as the batch path (about 10x faster than it on one state; numpy's per-call
    overhead on 3 x 3 arrays dominates there). Tested equal to the batch path."""
    k = g.knob_ratio
    u = k * float(q[0])
    v = k * float(q[1])
    a = math.hypot(u, v)
    s1 = _s1_scalar(a)
    c2 = _c2_scalar(a)
    ds1 = _ds1_over_a_scalar(a)
    dc2 = _dc2_over_a_scalar(a)
    length = g.bending_length
    off = g.us_offset
    uu, vv, uv = u * u, v * v, u * v
    w = [[0.0, 0.0, u], [0.0, 0.0, v], [-u, -v, 0.0]]
    w2 = [[-uu, -uv, 0.0], [-uv, -vv, 0.0], [0.0, 0.0, -(uu + vv)]]
    r = [
        [
            1.0 + s1 * w[i][j] + c2 * w2[i][j] if i == j else s1 * w[i][j] + c2 * w2[i][j]
            for j in range(3)
        ]
        for i in range(3)
    ]
    e_u = [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]
    e_v = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]

    def column(x: float, e: list[list[float]], dp: tuple[float, float, float]) -> list[float]:
        ew, we = _mat3(e, w), _mat3(w, e)
        dr = [
            [
                ds1 * x * w[i][j] + s1 * e[i][j] + dc2 * x * w2[i][j] + c2 * (ew[i][j] + we[i][j])
                for j in range(3)
            ]
            for i in range(3)
        ]
        # omega^ = R^T dR (skew): entries (2, 1), (0, 2), (1, 0)
        om_x = r[0][2] * dr[0][1] + r[1][2] * dr[1][1] + r[2][2] * dr[2][1]
        om_y = r[0][0] * dr[0][2] + r[1][0] * dr[1][2] + r[2][0] * dr[2][2]
        om_z = r[0][1] * dr[0][0] + r[1][1] * dr[1][0] + r[2][1] * dr[2][0]
        vel = [r[0][i] * dp[0] + r[1][i] * dp[1] + r[2][i] * dp[2] for i in range(3)]
        return [
            k * (vel[0] + off * om_y),
            k * (vel[1] - off * om_x),
            k * vel[2],
            k * om_x,
            k * om_y,
            k * om_z,
        ]

    col1 = column(u, e_u, (length * (c2 + dc2 * uu), length * dc2 * uv, length * ds1 * u))
    col2 = column(v, e_v, (length * dc2 * uv, length * (c2 + dc2 * vv), length * ds1 * v))
    px = length * c2 * u + off * r[0][2]
    py = length * c2 * v + off * r[1][2]
    e = (-py, px, 0.0)  # e_z x p_tip
    v_roll = [r[0][i] * e[0] + r[1][i] * e[1] + r[2][i] * e[2] for i in range(3)]
    w_roll = [r[2][0], r[2][1], r[2][2]]
    out = np.empty((6, 4))
    out[:, 0] = col1
    out[:, 1] = col2
    out[:, 2] = v_roll + w_roll
    out[:, 3] = [*w_roll, 0.0, 0.0, 0.0]
    return out


def jacobian(
    q: ArrayLike, geometry: CatheterGeometry = DEFAULT_GEOMETRY, *, check: bool = True
) -> Array:
    """Body Jacobian of the image centre frame (analytic).

    Parameters
    ----------
    q : array-like, shape (4,) or (..., 4)
        Model joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).

    Returns
    -------
    jac : ndarray, shape (6, 4) or (..., 6, 4)
        Maps joint velocities (rad/s, rad/s, rad/s, mm/s) to the twist of the tip *in the tip
        frame*: rows 0-2 linear velocity (mm/s), rows 3-5 angular velocity (rad/s). Column j
        is vee(tip2base^-1 d tip2base / d q_j).
    """
    g = geometry
    arr = check_joint_state(q, g.joint_limits) if check else np.asarray(q, dtype=np.float64)
    if arr.shape == (4,):
        return _jacobian_scalar(arr, g)
    k = g.knob_ratio
    u = k * arr[..., 0]
    v = k * arr[..., 1]
    rt, pt, _, _ = _tilt(u, v, g.bending_length)
    dr_u, dp_u, dr_v, dp_v = _tilt_derivatives(u, v, g.bending_length)
    # Body Jacobian of T_tilt @ T_US, then the proximal joints.
    # For a distal offset z_us: T = T_tilt @ Trans_z(us) -> dT = dT_tilt @ Trans_z(us)
    # T^-1 dT = Tus^-1 (T_tilt^-1 dT_tilt) Tus.
    off = g.us_offset
    rt_t = np.swapaxes(rt, -1, -2)
    ez = np.array([0.0, 0.0, 1.0])

    def body_col(dr: Array, dp: Array) -> Array:
        omega_hat = rt_t @ dr  # skew, angular velocity in the bend-end frame
        vel = (rt_t @ dp[..., None])[..., 0]  # linear velocity of the bend-end origin
        omega = np.stack([omega_hat[..., 2, 1], omega_hat[..., 0, 2], omega_hat[..., 1, 0]], -1)
        # shift to the image centre: v_tip = v + omega x (-off ez) ... in body terms:
        # Tus^-1 [w, v] Tus -> w, v + w x (off ez)
        # omega x (off ez) = off (omega_y, -omega_x, 0), written out (np.cross is slow)
        vel_tip = vel + off * np.stack(
            [omega[..., 1], -omega[..., 0], np.zeros_like(omega[..., 0])], -1
        )
        return np.concatenate([vel_tip, omega], axis=-1)

    col1 = k * body_col(dr_u, dp_u)
    col2 = k * body_col(dr_v, dp_v)
    # full rotation of the image centre frame relative to the rolled base
    r_full = rt  # Rz(phi3) cancels in body terms except for the joint axes below
    p_tip = pt + off * rt[..., :, 2]  # image centre in the rolled base frame
    r_full_t = np.swapaxes(r_full, -1, -2)
    # roll joint: spatial twist about z through the origin of the rolled base: w = ez, v = 0
    # body: w_b = R^T ez, v_b = R^T (ez x ... ) -> v_b = R^T (w x p)?  For T^-1 dT with
    # dT = [ez]x T (left-multiplied): body = R^T ez, R^T (ez x p)
    w_roll = r_full_t @ ez
    ez_x_p = np.stack([-p_tip[..., 1], p_tip[..., 0], np.zeros_like(p_tip[..., 0])], -1)
    v_roll = (r_full_t @ ez_x_p[..., None])[..., 0]
    col3 = np.concatenate([v_roll, w_roll], axis=-1)
    col4 = np.concatenate([r_full_t @ ez, np.zeros_like(w_roll)], axis=-1)
    return np.stack([col1, col2, col3, col4], axis=-1)


# --- tip-frame jog (the paper's "intuitive" control) -------------------------------------


def tip_jog(
    q: ArrayLike,
    twist_tip: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    *,
    dt: float = 0.01,
    rotation_weight: float = 10.0,
    damping: float = 0.05,
    singular_threshold: float = 0.05,
    check: bool = True,
) -> Array:
    """Joint velocities that move the tip with a twist given in its own frame.

    Four joints cannot follow every 6-D twist, so the answer is the weighted least-squares
    one: angular velocity errors count as ``rotation_weight`` mm/s per rad/s (the default,
    10 mm/rad, puts the position first, which is what an operator pushing the tip sideways
    expects; ``bending_length`` weighs both alike). Damped least squares (adaptive damping
    below ``singular_threshold``) in scaled units, the three angle joints counting as ``L``
    mm per rad, so the scaled Jacobian's singular values are of order 1 and ``damping`` and
    ``singular_threshold`` are dimensionless. Joints that would cross their limit within
    ``dt`` are frozen and the others re-solved; the result never takes q past a limit in
    one step of ``dt``.

    Parameters
    ----------
    q : array-like, shape (4,)
        Model joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).
    twist_tip : array-like, shape (6,)
        Desired linear velocity (mm/s) and angular velocity (rad/s) of the image centre
        frame, expressed in the tip frame.
    dt : float
        Control period (s) over which the joint limits are respected.

    Returns
    -------
    dq : ndarray, shape (4,)
        Joint velocities (rad/s, rad/s, rad/s, mm/s).
    """
    g = geometry
    if check:
        qa = check_joint_state(q, g.joint_limits)
        tw = check_finite(twist_tip, "twist_tip", "mm/s and rad/s")
        if qa.shape != (4,) or tw.shape != (6,):
            raise ShapeError(
                f"tip_jog takes q of shape (4,) and twist_tip of shape (6,): "
                f"(vx, vy, vz mm/s, wx, wy, wz rad/s), got {qa.shape} and {tw.shape}"
            )
        check_positive(dt, "dt", "s")
        check_positive(rotation_weight, "rotation_weight", "mm/rad")
    else:
        qa = np.asarray(q, dtype=np.float64)
        tw = np.asarray(twist_tip, dtype=np.float64)
    L = g.bending_length
    rw = rotation_weight
    row_w = np.array([1.0, 1.0, 1.0, rw, rw, rw])
    col_s = np.array([L, L, L, 1.0])  # scaled joint = col_s * joint
    jac = jacobian(qa, g, check=False) * row_w[:, None] / col_s[None, :]
    target = tw * row_w
    free = np.ones(4, dtype=bool)
    limits = g.joint_limits
    dq = np.zeros(4)
    for _ in range(4):
        jf = jac[:, free]
        sv = np.linalg.svd(jf, compute_uv=False)
        smin = float(sv[-1]) if sv.size else 0.0
        lam2 = 0.0
        if smin < singular_threshold:
            lam2 = damping**2 * (1.0 - (smin / singular_threshold) ** 2)
        lhs = jf.T @ jf + (lam2 + 1e-12) * np.eye(int(free.sum()))
        xs = np.linalg.solve(lhs, jf.T @ target)
        dq = np.zeros(4)
        dq[free] = xs / col_s[free]
        nxt = qa + dq * dt
        crossing = free & (((nxt < limits[:, 0]) & (dq < 0)) | ((nxt > limits[:, 1]) & (dq > 0)))
        if not np.any(crossing):
            return dq
        free &= ~crossing
        if not np.any(free):
            return np.zeros(4)
    # last resort: scale down to stop exactly at the limit
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(dq > 0, limits[:, 1] - qa, np.where(dq < 0, limits[:, 0] - qa, np.inf))
        frac = np.where(dq != 0, room / (dq * dt), np.inf)
    scale = float(np.clip(np.min(frac), 0.0, 1.0))
    return dq * scale

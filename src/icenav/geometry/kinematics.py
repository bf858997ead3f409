"""Constant-curvature kinematics of a 4-DOF ICE catheter (the paper's Section III-B).

Joint vector ``q = (phi1, phi2, phi3, d4)``: anterior-posterior knob (rad), right-left knob
(rad), bulk rotation (rad), translation (mm). The knob angles here are *model* knob angles
(what the constant-curvature model needs); the elasticity map of
:mod:`icenav.compensation.elasticity` turns them into *motor* knob angles.

Frames (see ``docs/kinematics.md``):

- ``base``: bottom of the bending section at q = 0, z along the catheter axis.
- ``tip``: the ultrasound image centre frame; x = image facing direction, z = catheter axis.

The forward kinematics (paper Eqs. (1)-(2) and the Rodrigues rotation that follows them)::

    alpha = (knob_radius / catheter_radius) * hypot(phi1, phi2)      # bending angle
    theta = atan2(phi2, phi1)                                        # bending-plane angle
    P_tilt = r (1 - cos a) cos t, r (1 - cos a) sin t, r sin a      # r = L / alpha
    R_tilt = Rodrigues(n_bend = (-sin t, cos t, 0), alpha)
    tip2base = Trans_z(d4) @ Rot_z(phi3) @ [R_tilt | P_tilt] @ Trans_z(us_offset)

is evaluated here in a form that is exact at alpha = 0 and smooth near it: with
``u = k phi1``, ``v = k phi2`` (``k = knob_radius / catheter_radius``) and the bend vector
``w = alpha * n_bend = (-v, u, 0)``::

    P_tilt = L * (c2(alpha) u, c2(alpha) v, s1(alpha))
    R_tilt = I + s1(alpha) [w]x + c2(alpha) [w]x^2
    s1(a) = sin(a) / a,   c2(a) = (1 - cos a) / a^2

which equals the paper's expressions for alpha > 0 and has the right limit (0, 0, L), I at
alpha = 0, with no division by zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state, check_positive, check_transform
from icenav.errors import ConfigurationError, UnreachablePoseError

__all__ = [
    "Backbone",
    "CatheterGeometry",
    "InverseSolution",
    "backbone",
    "bend_to_knobs",
    "forward",
    "inverse",
    "inverse_with_residual",
    "jacobian",
    "knobs_to_bend",
    "tip_jog",
]

_SERIES_BELOW = 1e-2  # bending angle (rad) below which the Taylor series are used


@dataclass(frozen=True)
class CatheterGeometry:
    """Geometry and joint limits of one catheter (lengths in mm, angles in rad)."""

    bending_length: float = 60.0
    """L: length of the bending section (mm)."""
    knob_radius: float = 1.65
    """r_knob: radius at which a knob pulls its tendon (mm)."""
    catheter_radius: float = 1.65
    """r_catheter: radius of the tendon routing in the bending section (mm)."""
    us_offset: float = 10.0
    """Distance along the catheter axis from the end of the bending section to the image
    centre frame (mm); the paper's T_US."""
    knob_limit: float = math.pi / 2
    """Each knob turns within [-knob_limit, +knob_limit] (rad)."""
    translation_limits: tuple[float, float] = (-50.0, 50.0)
    """Allowed translation d4 (mm), lower and upper."""
    joint_limits: Array = field(init=False, repr=False, compare=False)
    """(4, 2) array of lower/upper limits (rad, rad, rad, mm); roll is unlimited."""

    def __post_init__(self) -> None:
        check_positive(self.bending_length, "bending_length", "mm")
        check_positive(self.knob_radius, "knob_radius", "mm")
        check_positive(self.catheter_radius, "catheter_radius", "mm")
        off = float(self.us_offset)
        if not math.isfinite(off) or off < 0:
            raise ConfigurationError(f"us_offset must be finite and >= 0 mm, got {off} mm")
        lim = check_positive(self.knob_limit, "knob_limit", "rad")
        if lim > math.pi:
            raise ConfigurationError(
                f"knob_limit must be in (0, pi] rad, got {lim} rad ({math.degrees(lim):.1f} deg)"
            )
        try:
            lo, hi = (float(x) for x in self.translation_limits)
        except (TypeError, ValueError) as exc:
            raise ConfigurationError(
                f"translation_limits must be two numbers (mm), got {self.translation_limits!r}"
            ) from exc
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= 0.0 <= hi and lo < hi):
            raise ConfigurationError(
                f"translation_limits must be finite with lower <= 0 <= upper (mm), "
                f"got ({lo}, {hi}) mm"
            )
        if self.knob_ratio * math.hypot(lim, lim) >= math.pi:
            raise ConfigurationError(
                "knob_limit * knob_radius / catheter_radius allows a bend of 180 deg or more "
                f"(knob_limit={lim} rad, ratio={self.knob_ratio}); the inverse would not be unique"
            )
        limits = np.array([[-lim, lim], [-lim, lim], [-np.inf, np.inf], [lo, hi]])
        limits.setflags(write=False)
        object.__setattr__(self, "joint_limits", limits)

    @property
    def knob_ratio(self) -> float:
        """k = knob_radius / catheter_radius: bend angle per knob angle (rad/rad)."""
        return self.knob_radius / self.catheter_radius


DEFAULT_GEOMETRY = CatheterGeometry()


# --- scalar helpers (stable near alpha = 0) ---------------------------------------------


def _s1(a: Array) -> Array:
    """sin(a) / a."""
    return np.sinc(a / np.pi)


def _c2(a: Array) -> Array:
    """(1 - cos a) / a^2."""
    return 0.5 * np.sinc(a / (2.0 * np.pi)) ** 2


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


def _s1_scalar(a: float) -> float:
    if a < _SERIES_BELOW:
        a2 = a * a
        return 1.0 - a2 / 6.0 + a2 * a2 / 120.0
    return math.sin(a) / a


def _c2_scalar(a: float) -> float:
    if a < _SERIES_BELOW:
        a2 = a * a
        return 0.5 - a2 / 24.0 + a2 * a2 / 720.0
    h = math.sin(0.5 * a) / a
    return 2.0 * h * h


def _skew(w: Array) -> Array:
    """[w]x for w of shape (..., 3) -> (..., 3, 3)."""
    out = np.zeros((*w.shape[:-1], 3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def knobs_to_bend(
    phi1: ArrayLike, phi2: ArrayLike, geometry: CatheterGeometry = DEFAULT_GEOMETRY
) -> tuple[Array, Array]:
    """Bending angle and bending-plane angle of model knob angles.

    Parameters
    ----------
    phi1, phi2 : array-like, same shape
        Model knob angles (rad).

    Returns
    -------
    alpha : ndarray
        Bending angle (rad), >= 0. Paper: alpha = sqrt((L_ap/r_cath)^2 + (L_rl/r_cath)^2).
    theta : ndarray
        Bending-plane angle (rad) from the base x axis about the base z axis, in (-pi, pi];
        0 where alpha = 0. Paper Eq. (1).
    """
    p1 = np.asarray(phi1, dtype=np.float64)
    p2 = np.asarray(phi2, dtype=np.float64)
    k = geometry.knob_ratio
    return k * np.hypot(p1, p2), np.arctan2(p2, p1)


def bend_to_knobs(
    alpha: ArrayLike, theta: ArrayLike, geometry: CatheterGeometry = DEFAULT_GEOMETRY
) -> tuple[Array, Array]:
    """Model knob angles (phi1, phi2) in rad for a bend (alpha, theta) in rad (paper IK)."""
    a = np.asarray(alpha, dtype=np.float64)
    t = np.asarray(theta, dtype=np.float64)
    k = geometry.knob_ratio
    return a * np.cos(t) / k, a * np.sin(t) / k


# --- forward kinematics ------------------------------------------------------------------


def _tilt(u: Array, v: Array, length: float) -> tuple[Array, Array, Array, Array]:
    """R_tilt (..., 3, 3), P_tilt (..., 3), alpha, and [w]x for bend vector w = (-v, u, 0)."""
    a = np.hypot(u, v)
    s1 = _s1(a)
    c2 = _c2(a)
    w = np.stack([-v, u, np.zeros_like(u)], axis=-1)
    wx = _skew(w)
    rot = np.eye(3) + s1[..., None, None] * wx + c2[..., None, None] * (wx @ wx)
    pos = length * np.stack([c2 * u, c2 * v, s1], axis=-1)
    return rot, pos, a, wx


def _forward_scalar(q: Array, g: CatheterGeometry) -> Array:
    """Fast path for a single joint state (about 10x faster than the batch path)."""
    k = g.knob_ratio
    u = k * float(q[0])
    v = k * float(q[1])
    a = math.hypot(u, v)
    s1 = _s1_scalar(a)
    c2 = _c2_scalar(a)
    L = g.bending_length
    # R_tilt = I + s1 W + c2 W^2 with W = [(-v, u, 0)]x  (Rodrigues, paper Sec. III-B)
    uu, vv, uv = u * u, v * v, u * v
    r00 = 1.0 - c2 * uu
    r01 = -c2 * uv
    r02 = s1 * u
    r10 = -c2 * uv
    r11 = 1.0 - c2 * vv
    r12 = s1 * v
    r20 = -s1 * u
    r21 = -s1 * v
    r22 = 1.0 - c2 * (uu + vv)
    # Eq. (2): tip of the bending section on the arc, then T_US along the tip axis
    off = g.us_offset
    px = L * c2 * u + off * r02
    py = L * c2 * v + off * r12
    pz = L * s1 + off * r22
    c = math.cos(float(q[2]))
    s = math.sin(float(q[2]))
    return np.array(
        [
            [c * r00 - s * r10, c * r01 - s * r11, c * r02 - s * r12, c * px - s * py],
            [s * r00 + c * r10, s * r01 + c * r11, s * r02 + c * r12, s * px + c * py],
            [r20, r21, r22, pz + float(q[3])],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


_CHUNK = 8192  # batch FK works in chunks that stay in cache


def _forward_batch(q: Array, g: CatheterGeometry) -> Array:
    flat = q.reshape(-1, 4)
    out = np.empty((flat.shape[0], 4, 4))
    k = g.knob_ratio
    L = g.bending_length
    off = g.us_offset
    for start in range(0, flat.shape[0], _CHUNK):
        qc = flat[start : start + _CHUNK]
        oc = out[start : start + _CHUNK]
        u = k * qc[:, 0]
        v = k * qc[:, 1]
        a2 = u * u + v * v
        a = np.sqrt(a2)
        small = a < 1e-3  # series below: truncation error < 1e-18, no cancellation
        safe = np.where(small, 1.0, a)
        s1 = np.where(small, 1.0 - a2 / 6.0, np.sin(safe) / safe)
        c2 = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
        cu = c2 * u
        cv = c2 * v
        r00 = 1.0 - cu * u
        r01 = -cu * v
        r02 = s1 * u
        r11 = 1.0 - cv * v
        r12 = s1 * v
        r22 = 1.0 - cu * u - cv * v
        px = L * cu + off * r02
        py = L * cv + off * r12
        pz = L * s1 + off * r22
        c = np.cos(qc[:, 2])
        s = np.sin(qc[:, 2])
        oc[:, 0, 0] = c * r00 - s * r01
        oc[:, 0, 1] = c * r01 - s * r11
        oc[:, 0, 2] = c * r02 - s * r12
        oc[:, 0, 3] = c * px - s * py
        oc[:, 1, 0] = s * r00 + c * r01
        oc[:, 1, 1] = s * r01 + c * r11
        oc[:, 1, 2] = s * r02 + c * r12
        oc[:, 1, 3] = s * px + c * py
        oc[:, 2, 0] = -r02
        oc[:, 2, 1] = -r12
        oc[:, 2, 2] = r22
        oc[:, 2, 3] = pz + qc[:, 3]
        oc[:, 3, :3] = 0.0
        oc[:, 3, 3] = 1.0
    return out.reshape(*q.shape[:-1], 4, 4)


def forward(
    q: ArrayLike, geometry: CatheterGeometry = DEFAULT_GEOMETRY, *, check: bool = True
) -> Array:
    """Forward kinematics: joint state to the pose of the image centre frame.

    Parameters
    ----------
    q : array-like, shape (4,) or (..., 4)
        Model joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).
    geometry : CatheterGeometry
        Catheter geometry and joint limits.
    check : bool
        Validate ``q`` (finite, shape, joint limits). ``False`` skips it for hot loops.

    Returns
    -------
    tip2base : ndarray, shape (4, 4) or (..., 4, 4)
        Pose of the image centre frame in the base frame (translation in mm).
    """
    arr = check_joint_state(q, geometry.joint_limits) if check else np.asarray(q, np.float64)
    if arr.shape == (4,):
        return _forward_scalar(arr, geometry)
    return _forward_batch(arr, geometry)


# --- inverse kinematics ------------------------------------------------------------------


@dataclass(frozen=True)
class InverseSolution:
    """Result of :func:`inverse_with_residual`."""

    q: Array
    """Joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm), shape (4,) or (..., 4)."""
    position_residual_mm: Array
    """Distance between the requested and the reached image centre (mm), shape () or (...)."""
    rotation_residual_rad: Array
    """Angle of the rotation between the requested and the reached orientation (rad)."""
    reachable: Array
    """True where both residuals are within tolerance (bool)."""


def _wrap_near(angle: Array, near: Array) -> Array:
    """angle + 2 pi n closest to ``near``."""
    return near + np.remainder(angle - near + np.pi, 2.0 * np.pi) - np.pi


def _inverse_closed_form(t: Array, g: CatheterGeometry) -> Array:
    """Closed-form IK (paper Eqs. (3)-(8)), exact for reachable poses; shape (..., 4)."""
    rot = t[..., :3, :3]
    z = rot[..., :, 2]
    # remove T_US: end of the bending section
    p_end = t[..., :3, 3] - g.us_offset * z
    # Eq. (3): bending angle from the tip axis (atan2 form, accurate near 0)
    alpha = np.arctan2(np.hypot(z[..., 0], z[..., 1]), z[..., 2])
    # Eq. (4): theta' = theta + phi3, the bending-plane angle seen in the base frame
    theta_p = np.arctan2(z[..., 1], z[..., 0])
    # R = Rz(theta') Ry(alpha) Rz(-theta)  =>  Ry(-alpha) Rz(-theta') R = Rz(-theta)
    ct, st = np.cos(theta_p), np.sin(theta_p)
    ca, sa = np.cos(alpha), np.sin(alpha)
    # first column of Rz(-theta') R, then Ry(-alpha) applied to it (rows 0 and 1 only)
    m0 = ct * rot[..., 0, 0] + st * rot[..., 1, 0]
    m1 = -st * rot[..., 0, 0] + ct * rot[..., 1, 0]
    m2 = rot[..., 2, 0]
    n00 = ca * m0 - sa * m2
    n10 = m1
    theta = -np.arctan2(n10, n00)
    # Eq. (5): roll
    phi3 = np.remainder(theta_p - theta + np.pi, 2.0 * np.pi) - np.pi
    # Eqs. (6)-(7): knob angles
    k = g.knob_ratio
    phi1 = alpha * np.cos(theta) / k
    phi2 = alpha * np.sin(theta) / k
    # Eq. (8): translation, d4 = z_end - L sin(alpha)/alpha
    d4 = p_end[..., 2] - g.bending_length * _s1(alpha)
    return np.stack([phi1, phi2, phi3, d4], axis=-1)


def _vee_antisymmetric(m: Array) -> Array:
    """vee(m - m^T) for (..., 3, 3) -> (..., 3): 2 sin(angle) * axis for a rotation."""
    return np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


def _rotation_angle(r_a: Array, r_b: Array) -> Array:
    """Angle (rad) of r_a^T r_b, shape (...)."""
    rel = np.swapaxes(r_a, -1, -2) @ r_b
    tr = np.trace(rel, axis1=-2, axis2=-1)
    # atan2 form, accurate for small angles
    vee = _vee_antisymmetric(rel)
    return np.arctan2(0.5 * np.linalg.norm(vee, axis=-1), 0.5 * (tr - 1.0))


def _pose_error_body(target: Array, reached: Array) -> Array:
    """Body-frame pose error (dx, dy, dz mm, rx, ry, rz rad) of target relative to reached."""
    rel = _rigid_inverse(reached) @ target
    rot = rel[..., :3, :3]
    angle = _rotation_angle(np.broadcast_to(np.eye(3), rot.shape), rot)
    vee = _vee_antisymmetric(rot)
    s = np.sin(angle)
    scale = np.where(s > 1e-9, angle / np.where(s > 1e-9, 2.0 * s, 1.0), 0.5)
    return np.concatenate([rel[..., :3, 3], vee * scale[..., None]], axis=-1)


def _rigid_inverse(t: Array) -> Array:
    out = np.zeros_like(t)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -(rt @ t[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def inverse_with_residual(
    tip2base: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    *,
    check: bool = True,
    tol_mm: float = 1e-3,
    tol_rad: float = 1e-5,
    phi3_near: ArrayLike | None = None,
    max_iterations: int = 30,
) -> InverseSolution:
    """Inverse kinematics with the residual, for reachable and unreachable poses.

    The closed form (paper Eqs. (3)-(8)) is exact for reachable poses. Where its result
    misses the pose by more than the tolerance (the pose is off the 4-D reachable set, or a
    knob would pass its limit), it is refined by projected damped Gauss-Newton to the
    nearest reachable joint state within the limits, in the metric
    ``|dp|^2 + (L * |dr|)^2`` (position error in mm, rotation error in rad scaled by the
    bending length L, so 1 rad counts as much as L mm).

    Parameters
    ----------
    tip2base : array-like, shape (4, 4) or (..., 4, 4)
        Requested pose of the image centre frame in the base frame (mm).
    tol_mm, tol_rad : float
        Residuals up to which a pose counts as reachable.
    phi3_near : array-like, optional, shape () or (...)
        Roll (rad) the answer's phi3 should be nearest to (it is unique modulo 2 pi);
        default: phi3 in (-pi, pi].

    Returns
    -------
    InverseSolution
        At alpha = 0 the bending plane is undefined; the convention is phi1 = phi2 = 0
        and phi3 = the roll of the tip x axis about the base z axis.
    """
    g = geometry
    t = check_transform(tip2base, "tip2base") if check else np.asarray(tip2base, np.float64)
    q = _inverse_closed_form(t, g)
    limits = g.joint_limits
    q[..., :2] = np.clip(q[..., :2], limits[0, 0], limits[0, 1])
    q[..., 3] = np.clip(q[..., 3], limits[3, 0], limits[3, 1])
    weight = np.array([1.0, 1.0, 1.0, g.bending_length, g.bending_length, g.bending_length])
    for _ in range(max_iterations):
        reached = forward(q, g, check=False)
        err = _pose_error_body(t, reached)
        pos_res = np.linalg.norm(err[..., :3], axis=-1)
        rot_res = np.linalg.norm(err[..., 3:], axis=-1)
        bad = (pos_res > tol_mm) | (rot_res > tol_rad)
        if not np.any(bad):
            break
        jac = jacobian(q, g, check=False) * weight[:, None]
        e = err * weight
        jt = np.swapaxes(jac, -1, -2)
        lhs = jt @ jac + 1e-6 * np.eye(4)
        dq = np.linalg.solve(lhs, (jt @ e[..., None]))[..., 0]
        q_new = q + np.where(bad[..., None], dq, 0.0)
        q_new[..., :2] = np.clip(q_new[..., :2], limits[0, 0], limits[0, 1])
        q_new[..., 3] = np.clip(q_new[..., 3], limits[3, 0], limits[3, 1])
        if np.allclose(q_new, q, rtol=0.0, atol=1e-12):
            break
        q = q_new
    reached = forward(q, g, check=False)
    pos_res = np.linalg.norm(t[..., :3, 3] - reached[..., :3, 3], axis=-1)
    rot_res = _rotation_angle(reached[..., :3, :3], t[..., :3, :3])
    if phi3_near is not None:
        q[..., 2] = _wrap_near(q[..., 2], np.asarray(phi3_near, dtype=np.float64))
    else:
        q[..., 2] = np.remainder(q[..., 2] + np.pi, 2.0 * np.pi) - np.pi
    return InverseSolution(
        q=q,
        position_residual_mm=pos_res,
        rotation_residual_rad=rot_res,
        reachable=(pos_res <= tol_mm) & (rot_res <= tol_rad),
    )


def _inverse_scalar(t: Array, g: CatheterGeometry) -> Array:
    """Closed-form IK of one pose with math (fast path); same equations as the batch."""
    r00, r10, r20 = float(t[0, 0]), float(t[1, 0]), float(t[2, 0])
    zx, zy, zz = float(t[0, 2]), float(t[1, 2]), float(t[2, 2])
    alpha = math.atan2(math.hypot(zx, zy), zz)  # Eq. (3)
    theta_p = math.atan2(zy, zx)  # Eq. (4)
    ct, st = math.cos(theta_p), math.sin(theta_p)
    m0 = ct * r00 + st * r10
    m1 = -st * r00 + ct * r10
    n00 = math.cos(alpha) * m0 - math.sin(alpha) * r20
    theta = -math.atan2(m1, n00)
    phi3 = math.remainder(theta_p - theta, 2.0 * math.pi)  # Eq. (5)
    k = g.knob_ratio
    d4 = float(t[2, 3]) - g.us_offset * zz - g.bending_length * _s1_scalar(alpha)  # Eq. (8)
    return np.array([alpha * math.cos(theta) / k, alpha * math.sin(theta) / k, phi3, d4])


def inverse(
    tip2base: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    *,
    check: bool = True,
    unreachable: Literal["raise", "nearest"] = "raise",
    tol_mm: float = 1e-3,
    tol_rad: float = 1e-5,
    phi3_near: ArrayLike | None = None,
) -> Array:
    """Inverse kinematics: pose of the image centre frame to the joint state.

    Parameters
    ----------
    tip2base : array-like, shape (4, 4) or (..., 4, 4)
        Pose of the image centre frame in the base frame (mm).
    unreachable : {"raise", "nearest"}
        What to do when no joint state within the limits reaches the pose within
        ``tol_mm`` / ``tol_rad``: raise :class:`UnreachablePoseError`, or return the nearest
        reachable joint state (see :func:`inverse_with_residual` for the metric).
    check : bool
        ``False`` skips validation *and* the reachability check: the closed form only,
        for hot loops whose poses are known to be reachable.

    Returns
    -------
    q : ndarray, shape (4,) or (..., 4)
        Joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm), unique for alpha > 0; at
        alpha = 0: phi1 = phi2 = 0 and phi3 = roll of the tip x axis.
    """
    if not check:
        t = np.asarray(tip2base, dtype=np.float64)
        if t.shape == (4, 4):
            q = _inverse_scalar(t, geometry)
            if phi3_near is not None:
                near = float(np.asarray(phi3_near, dtype=np.float64))
                q[2] = near + math.remainder(q[2] - near, 2.0 * math.pi)
            return q
        q = _inverse_closed_form(t, geometry)
        if phi3_near is not None:
            q[..., 2] = _wrap_near(q[..., 2], np.asarray(phi3_near, dtype=np.float64))
        return q
    if unreachable not in ("raise", "nearest"):
        raise ConfigurationError(f"unreachable must be 'raise' or 'nearest', got {unreachable!r}")
    sol = inverse_with_residual(
        tip2base, geometry, tol_mm=tol_mm, tol_rad=tol_rad, phi3_near=phi3_near
    )
    if unreachable == "raise" and not np.all(sol.reachable):
        idx = int(np.argmin(np.ravel(sol.reachable)))
        pr = float(np.ravel(sol.position_residual_mm)[idx])
        rr = float(np.ravel(sol.rotation_residual_rad)[idx])
        raise UnreachablePoseError(
            f"tip2base is not reachable within the joint limits: nearest pose is {pr:.4g} mm "
            f"and {math.degrees(rr):.4g} deg away (tolerance {tol_mm} mm, "
            f"{math.degrees(tol_rad):.2g} deg); knobs are limited to "
            f"+-{math.degrees(geometry.knob_limit):.1f} deg, translation to "
            f"{geometry.translation_limits} mm. Pass unreachable='nearest' to get the "
            "nearest joint state",
            position_residual_mm=pr,
            rotation_residual_rad=rr,
        )
    return sol.q


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
            from icenav.errors import ShapeError

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


# --- backbone, for drawing ---------------------------------------------------------------


@dataclass(frozen=True)
class Backbone:
    """Shape of the bending section, for drawing."""

    points_in_base: Array
    """(n, 3) points along the bending section from its base to its end (mm, base frame)."""
    tip2base: Array
    """(4, 4) pose of the image centre frame in the base frame (mm)."""


def backbone(q: ArrayLike, geometry: CatheterGeometry = DEFAULT_GEOMETRY, n: int = 50) -> Backbone:
    """Points along the bending section and the tip frame, for drawing.

    Parameters
    ----------
    q : array-like, shape (4,)
        Model joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).
    n : int
        Number of points (>= 2) from the base of the bending section to its end.
    """
    g = geometry
    qa = check_joint_state(q, g.joint_limits)
    if qa.shape != (4,):
        from icenav.errors import ShapeError

        raise ShapeError(f"backbone takes one joint state of shape (4,), got {qa.shape}")
    if int(n) < 2:
        raise ConfigurationError(f"n must be an integer >= 2 points, got {n}")
    frac = np.linspace(0.0, 1.0, int(n))
    k = g.knob_ratio
    u = k * qa[0] * frac
    v = k * qa[1] * frac
    _, pos, _, _ = _tilt(u, v, g.bending_length)
    pos = pos * frac[:, None]  # arc of length s = frac * L bends by frac * alpha
    c, s = math.cos(qa[2]), math.sin(qa[2])
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    pts = pos @ rz.T
    pts[:, 2] += qa[3]
    return Backbone(points_in_base=pts, tip2base=forward(qa, g, check=False))

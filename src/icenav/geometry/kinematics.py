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
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_joint_state, check_positive, check_transform
from icenav.errors import ConfigurationError, ShapeError, UnreachablePoseError
from icenav.geometry.se3 import body_pose_error, rotation_angle

__all__ = [
    "Backbone",
    "CatheterGeometry",
    "InverseSolution",
    "backbone",
    "bend_to_knobs",
    "forward",
    "inverse",
    "inverse_with_residual",
    "knobs_to_bend",
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


def _s1_c2(a: Array) -> tuple[Array, Array]:
    """sin(a) / a and (1 - cos a) / a^2 for a >= 0 (n,), with the series near 0 (the drawing
    of the backbone: one sine each, no sinc)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s1 = np.sin(a) / a
        h = np.sin(0.5 * a) / a
    c2 = 2.0 * h * h
    small = a < _SERIES_BELOW
    if small.any():
        a2 = a[small] * a[small]
        s1[small] = 1.0 - a2 / 6.0 + a2 * a2 / 120.0
        c2[small] = 0.5 - a2 / 24.0 + a2 * a2 / 720.0
    return s1, c2


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
    from icenav.geometry.jacobian import jacobian  # it builds on this module's helpers

    weight = np.array([1.0, 1.0, 1.0, g.bending_length, g.bending_length, g.bending_length])
    for _ in range(max_iterations):
        reached = forward(q, g, check=False)
        err = body_pose_error(t, reached)
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
    rot_res = rotation_angle(reached[..., :3, :3], t[..., :3, :3], check=False)
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
        raise ShapeError(f"backbone takes one joint state of shape (4,), got {qa.shape}")
    if int(n) < 2:
        raise ConfigurationError(f"n must be an integer >= 2 points, got {n}")
    frac = np.arange(int(n), dtype=np.float64) / (int(n) - 1)
    k = g.knob_ratio
    u0, v0 = k * qa[0], k * qa[1]
    # the arc of length s = frac * L bends by frac * alpha (constant curvature): its end is
    # s * (c2(a) u, c2(a) v, s1(a)) with (u, v) = frac * (u0, v0), a = frac * alpha (the
    # position part of R_tilt / P_tilt, paper Sec. III-B; no rotation is needed to draw it)
    a = frac * math.hypot(u0, v0)
    s1, c2 = _s1_c2(a)
    arc = g.bending_length * frac
    c, s = math.cos(qa[2]), math.sin(qa[2])
    bx = arc * c2 * frac * u0  # bend-plane coordinates before the roll
    by = arc * c2 * frac * v0
    pts = np.empty((frac.size, 3))
    pts[:, 0] = c * bx - s * by  # roll about the base z axis
    pts[:, 1] = s * bx + c * by
    pts[:, 2] = arc * s1 + qa[3]
    return Backbone(points_in_base=pts, tip2base=forward(qa, g, check=False))


def __getattr__(name: str) -> Any:
    """``jacobian`` and ``tip_jog`` live in :mod:`icenav.geometry.jacobian`; the old import
    path ``icenav.geometry.kinematics.jacobian`` still resolves (resolved on use, because
    that module imports this one)."""
    if name in ("jacobian", "tip_jog"):
        from icenav.geometry import jacobian as module

        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

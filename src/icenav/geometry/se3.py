"""Rigid-motion primitives, one copy each: inverse, rotation angle, rotation vector, body pose
error, pose mean.

Transforms are (..., 4, 4) homogeneous matrices named ``a2b`` (maps points in frame a into
frame b); rotations (..., 3, 3); translations in mm, angles in rad. Every function takes a
single transform or a stack (leading axes broadcast), and a (4, 4) or (3,) input takes a
plain-float fast path where the control loop calls it once per cycle.

Formulas (``docs/kinematics.md``, section "SE(3) helpers")::

    inv([R | p]) = [R^T | -R^T p]                                         # rigid inverse
    angle(R_a, R_b) = atan2(|vee(R)| / 2, (tr R - 1) / 2),  R = R_a^T R_b   # accurate near 0
    Exp(w) = I + sin|w| [k]x + (1 - cos|w|) [k]x^2,  k = w / |w|           # Rodrigues
    Log(R) = angle * vee(R - R^T) / (2 sin angle)                          # its inverse
    e(target, reached) = [R_r^T (p_t - p_r) ; w Log(R_r^T R_t)]            # body pose error
    mean(T_i) = [polar(sum R_i) | mean p_i]                                # chordal mean
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.errors import ShapeError

__all__ = [
    "body_pose_error",
    "pose_mean",
    "rigid_inverse",
    "rotation_angle",
    "rotation_log",
    "rotvec_to_matrix",
    "vee",
]


def rigid_inverse(t: ArrayLike) -> Array:
    """Inverse of rigid transforms (..., 4, 4): ``[R^T | -R^T p]`` (no general matrix
    inverse; exact for a rotation R)."""
    a = np.asarray(t, dtype=np.float64)
    out = np.zeros_like(a)
    rt = np.swapaxes(a[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -(rt @ a[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def vee(m: ArrayLike) -> Array:
    """``vee(m - m^T)`` of (..., 3, 3) -> (..., 3): ``2 sin(angle) * axis`` for a rotation."""
    a = np.asarray(m, dtype=np.float64)
    return np.stack(
        [a[..., 2, 1] - a[..., 1, 2], a[..., 0, 2] - a[..., 2, 0], a[..., 1, 0] - a[..., 0, 1]],
        axis=-1,
    )


def rotation_angle(r_a: ArrayLike, r_b: ArrayLike, *, check: bool = True) -> Array:
    """Angle (rad, in [0, pi]) of the rotation ``r_a^T r_b`` between two orientations.

    Parameters
    ----------
    r_a, r_b : array-like, shape (..., 3, 3)
        Rotation matrices (broadcast against each other).
    check : bool
        Validate shapes and finiteness (``False`` for hot loops).

    Returns
    -------
    angle : ndarray, shape (...)
        From both the trace (cos) and the skew part (sin): accurate near 0 and near pi,
        where ``arccos`` of the trace alone loses half the digits.
    """
    if check:
        a = check_finite(r_a, "r_a")
        b = check_finite(r_b, "r_b")
        if a.shape[-2:] != (3, 3) or b.shape[-2:] != (3, 3):
            raise ShapeError(f"rotations must have shape (..., 3, 3), got {a.shape} and {b.shape}")
    else:
        a = np.asarray(r_a, dtype=np.float64)
        b = np.asarray(r_b, dtype=np.float64)
    rel = np.swapaxes(a, -1, -2) @ b
    cos = 0.5 * (np.trace(rel, axis1=-2, axis2=-1) - 1.0)
    sin = 0.5 * np.linalg.norm(vee(rel), axis=-1)
    out: Array = np.arctan2(sin, cos)
    return out


def rotvec_to_matrix(w: ArrayLike) -> Array:
    """Rotation matrix (3, 3) of a rotation vector ``w`` (3,) (rad): Rodrigues' formula."""
    v = np.asarray(w, dtype=np.float64)
    if v.shape != (3,):
        raise ShapeError(f"a rotation vector has shape (3,), got {v.shape}")
    a = math.sqrt(float(v @ v))
    if a < 1e-12:
        return np.eye(3)
    k = v / a
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(a) * kx + (1.0 - math.cos(a)) * (kx @ kx)


def rotation_log(r: ArrayLike) -> Array:
    """Rotation vector (..., 3) (rad) of rotations (..., 3, 3): ``angle * axis`` (the
    inverse of :func:`rotvec_to_matrix` for angles below pi)."""
    m = np.asarray(r, dtype=np.float64)
    v = vee(m)
    s = 0.5 * np.linalg.norm(v, axis=-1)
    c = 0.5 * (np.trace(m, axis1=-2, axis2=-1) - 1.0)
    angle = np.arctan2(s, c)
    # angle / (2 sin angle) -> 1/2 as the angle -> 0
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, 2.0 * s, 1.0), 0.5)
    out: Array = v * scale[..., None]
    return out


def _body_pose_error_one(t: Array, m: Array, w: float) -> Array:
    """:func:`body_pose_error` of one pair in plain floats (the servo's per-cycle path)."""
    rm_t = m[:3, :3].T
    dp = rm_t @ (t[:3, 3] - m[:3, 3])
    r = rm_t @ t[:3, :3]
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    s = 0.5 * math.sqrt(float(v @ v))
    c = 0.5 * (float(r[0, 0] + r[1, 1] + r[2, 2]) - 1.0)
    angle = math.atan2(s, c)
    rot = v * (angle / (2.0 * s) if s > 1e-12 else 0.5)
    return np.concatenate([dp, w * rot])


def body_pose_error(target: ArrayLike, reached: ArrayLike, rotation_weight: float = 1.0) -> Array:
    """Pose error of ``reached`` against ``target`` in the reached tip frame.

    Parameters
    ----------
    target, reached : array-like, shape (4, 4) or (..., 4, 4)
        Poses in one frame (e.g. ``tip2base``, mm).
    rotation_weight : float
        w (mm per rad): how much one radian of orientation error counts against one mm
        (the servo's 30 mm/rad; the inverse kinematics' bending length L; 1 gives rad).

    Returns
    -------
    error : ndarray, shape (6,) or (..., 6)
        ``[R_r^T (p_t - p_r) (mm) ; w Log(R_r^T R_t)]``: the body twist that moves the
        reached pose onto the target (position first).
    """
    t = np.asarray(target, dtype=np.float64)
    m = np.asarray(reached, dtype=np.float64)
    w = float(rotation_weight)
    if t.shape == (4, 4) and m.shape == (4, 4):
        return _body_pose_error_one(t, m, w)
    rel = rigid_inverse(m) @ t
    return np.concatenate([rel[..., :3, 3], w * rotation_log(rel[..., :3, :3])], axis=-1)


def pose_mean(poses: ArrayLike) -> Array:
    """Mean of poses (n, 4, 4): mean position and the chordal mean rotation (the rotation
    nearest the mean of the matrices, by SVD, reflection excluded); one pose: itself.

    Used to average tracker samples (their rotations differ by the jitter, < 1 deg), where
    the chordal mean equals the geodesic mean to second order.
    """
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4) or p.shape[0] < 1:
        raise ShapeError(f"poses must have shape (n >= 1, 4, 4), got {p.shape}")
    if p.shape[0] == 1:
        return np.array(p[0])
    out = np.eye(4)
    out[:3, 3] = p[:, :3, 3].mean(axis=0)
    u, _, vt = np.linalg.svd(p[:, :3, :3].mean(axis=0))
    d = 1.0 if np.linalg.det(u @ vt) >= 0 else -1.0
    out[:3, :3] = u @ np.diag([1.0, 1.0, d]) @ vt
    return out

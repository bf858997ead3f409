"""Image spinning, Savitzky-Golay smoothing and time parameterisation of joint paths.

Image spinning (paper Sec. III-C, last paragraph): turn the ultrasound image plane 360 deg
about the catheter axis at the tip while the tip stays put. The intended pose is the start
pose turned about its own z axis::

    tip2base(t) = tip2base(0) @ Rot_z(direction * t),   t in [0, 2 pi * turns]

and the model joint path follows by inverse kinematics (Eqs. (3)-(8)). From
(phi1, phi2) = (a, 0) this is the paper's example phi1 = a cos t, phi2 = a sin t,
phi3 = -t (``direction = -1``).

Commanded paths are smoothed with a quadratic Savitzky-Golay filter, as the paper does,
and time-parameterised to per-joint velocity and acceleration limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import savgol_filter

from icenav._validation import check_finite, check_joint_state
from icenav.errors import ConfigurationError, UnreachablePoseError
from icenav.geometry.kinematics import (
    DEFAULT_GEOMETRY,
    CatheterGeometry,
    forward,
    inverse_with_residual,
)

__all__ = [
    "SpinTrajectory",
    "TimedPath",
    "savgol_smooth",
    "spin_trajectory",
    "time_parameterize",
]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SpinTrajectory:
    """An image-spinning path in model joint space."""

    spin_angle: Array
    """(n,) angle the image plane has turned at each sample (rad), 0 .. 2 pi turns."""
    q_model: Array
    """(n, 4) model joint states (phi1 rad, phi2 rad, phi3 rad, d4 mm)."""
    tip2base: Array
    """(n, 4, 4) intended poses of the image centre frame (base frame, mm)."""


def spin_trajectory(
    q_start: ArrayLike,
    n_samples: int = 360,
    *,
    turns: float = 1.0,
    direction: int = -1,
    include_end: bool = False,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> SpinTrajectory:
    """Model joint path that spins the image plane about the tip axis with the tip fixed.

    Parameters
    ----------
    q_start : array-like, shape (4,)
        Model joint state at the start (rad, rad, rad, mm).
    n_samples : int
        Number of samples (>= 2).
    turns : float
        Number of turns (1.0 = 360 deg).
    direction : {-1, +1}
        Sense of the spin about the tip z axis; -1 gives the paper's phi3 = -t.
    include_end : bool
        Include the final angle (2 pi turns) as the last sample (otherwise the samples are
        ``2 pi turns * k / n_samples``, the paper's 360 samples of one turn).

    Raises
    ------
    UnreachablePoseError
        If the spin needs knob angles beyond the limits: the bend angle stays constant
        while the bending plane turns through every direction, so the start's
        ``k * hypot(phi1, phi2)`` must not exceed ``k * knob_limit`` (a start in a corner of
        the square knob workspace cannot spin).
    """
    g = geometry
    q0 = check_joint_state(q_start, g.joint_limits, name="q_start")
    if q0.shape != (4,):
        raise ConfigurationError(f"q_start must have shape (4,), got {q0.shape}")
    if int(n_samples) < 2:
        raise ConfigurationError(f"n_samples must be >= 2, got {n_samples}")
    if direction not in (-1, 1):
        raise ConfigurationError(f"direction must be -1 or +1, got {direction!r}")
    tr = float(turns)
    if not math.isfinite(tr) or tr <= 0:
        raise ConfigurationError(f"turns must be finite and > 0, got {turns!r}")
    total = 2.0 * math.pi * tr
    t = np.linspace(0.0, total, int(n_samples), endpoint=include_end)
    t0 = forward(q0, g)
    c, s = np.cos(direction * t), np.sin(direction * t)
    rz = np.zeros((t.size, 4, 4))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1] = c, -s, s, c
    rz[:, 2, 2] = rz[:, 3, 3] = 1.0
    poses = t0 @ rz
    # phi3 follows the spin continuously: phi3(t) ~ phi3(0) + direction * t
    sol = inverse_with_residual(poses, g, phi3_near=q0[2] + direction * t)
    if not np.all(sol.reachable):
        k = int(np.argmin(sol.reachable))
        raise UnreachablePoseError(
            f"spin sample {k} ({math.degrees(t[k]):.1f} deg) is not reachable",
            position_residual_mm=float(sol.position_residual_mm[k]),
            rotation_residual_rad=float(sol.rotation_residual_rad[k]),
        )
    return SpinTrajectory(spin_angle=t, q_model=sol.q, tip2base=poses)


def savgol_smooth(
    q_path: ArrayLike, window: int = 15, polyorder: int = 2, mode: str = "interp"
) -> Array:
    """Savitzky-Golay smoothing of each joint of a path (quadratic by default, as the paper).

    Parameters
    ----------
    q_path : array-like, shape (n, k)
        Joint path (one column per joint).
    window : int
        Odd window length in samples (> polyorder); shortened to fit short paths.
    mode : str
        ``scipy.signal.savgol_filter`` edge mode (``interp`` keeps the ends unbiased;
        ``wrap`` for closed loops).
    """
    q = check_finite(q_path, "q_path")
    if q.ndim != 2:
        raise ConfigurationError(f"q_path must have shape (n, k), got {q.shape}")
    w = int(window)
    if w % 2 == 0 or w <= polyorder:
        raise ConfigurationError(f"window must be odd and > polyorder ({polyorder}), got {window}")
    n = q.shape[0]
    if n <= polyorder + 1:
        return q.copy()
    if w > n:
        w = n if n % 2 == 1 else n - 1
        if w <= polyorder:
            return q.copy()
    return np.asarray(savgol_filter(q, w, polyorder, axis=0, mode=mode))


@dataclass(frozen=True)
class TimedPath:
    """A joint path with a time for each sample."""

    t: Array
    """(n,) times (s), starting at 0, strictly increasing."""
    q: Array
    """(n, k) joint states (rad or mm per joint)."""

    @property
    def duration(self) -> float:
        """Total time (s)."""
        return float(self.t[-1])

    def sample(self, rate_hz: float) -> Array:
        """Joint states (m, k) at a fixed rate by linear interpolation (the path's own
        samples are close, so this stays within the limits up to rounding)."""
        hz = float(rate_hz)
        if not math.isfinite(hz) or hz <= 0:
            raise ConfigurationError(f"rate_hz must be finite and > 0 Hz, got {rate_hz!r}")
        ts = np.arange(0.0, self.duration, 1.0 / hz)
        ts = np.append(ts, self.duration) if ts[-1] < self.duration else ts
        return np.stack([np.interp(ts, self.t, self.q[:, j]) for j in range(self.q.shape[1])], -1)


def _accel_bounds(dq: Array, ddq: Array, x: Array, a: Array) -> tuple[Array, Array]:
    """Bounds on s'' at each node for s'^2 = x: -a <= q' s'' + q'' x <= a, per joint."""
    big = 1e300
    rhs_hi = a[None, :] - ddq * x[:, None]
    rhs_lo = -a[None, :] - ddq * x[:, None]
    pos = dq > 1e-15
    neg = dq < -1e-15
    safe = np.where(pos | neg, dq, 1.0)
    hi = np.where(pos, rhs_hi / safe, np.where(neg, rhs_lo / safe, big))
    lo = np.where(pos, rhs_lo / safe, np.where(neg, rhs_hi / safe, -big))
    # joints that do not move along the path: feasible only if |q'' x| <= a
    still = ~(pos | neg)
    bad = still & (np.abs(ddq * x[:, None]) > a[None, :])
    hi = np.where(bad, -big, hi)
    return np.max(lo, axis=1), np.min(hi, axis=1)


def _discrete_limits(t: Array, q: Array) -> tuple[Array, Array]:
    """Max |velocity| and |acceleration| per joint of a timed path, in the discrete sense
    (segment velocities; node accelerations, at rest before and after)."""
    dt = np.diff(t)
    v = np.diff(q, axis=0) / dt[:, None]
    vv = np.vstack([np.zeros(q.shape[1]), v, np.zeros(q.shape[1])])
    dd = np.concatenate([[dt[0]], dt, [dt[-1]]])
    acc = np.diff(vv, axis=0) / (0.5 * (dd[:-1] + dd[1:]))[:, None]
    return np.max(np.abs(v), axis=0), np.max(np.abs(acc), axis=0)


def time_parameterize(q_path: ArrayLike, v_max: ArrayLike, a_max: ArrayLike) -> TimedPath:
    """Time-optimal-style timing of a sampled path within per-joint velocity / acceleration.

    The path parameter s is the sample index. With q'(s), q''(s) from finite differences,
    ``x = s'^2`` obeys ``|q' s'' + q'' x| <= a_max`` and ``|q'| sqrt(x) <= v_max``; a maximum
    velocity curve, a forward (accelerate) and a backward (decelerate) integration of x
    give the profile (the classic phase-plane method of Bobrow / Shin & McKay), starting
    and ending at rest. A final uniform time scaling makes the *discrete* segment
    velocities and node accelerations (zero velocity before the first and after the last
    sample) meet the limits exactly.

    Parameters
    ----------
    q_path : array-like, shape (n, k)
        Joint path, n >= 2; repeated samples are dropped.
    v_max, a_max : array-like, shape (k,) or scalar
        Velocity (unit/s) and acceleration (unit/s^2) limits per joint, > 0.
    """
    q = check_finite(q_path, "q_path")
    if q.ndim != 2 or q.shape[0] < 2:
        raise ConfigurationError(f"q_path must have shape (n >= 2, k), got {q.shape}")
    k = q.shape[1]
    v = np.broadcast_to(check_finite(v_max, "v_max"), (k,)).astype(np.float64)
    a = np.broadcast_to(check_finite(a_max, "a_max"), (k,)).astype(np.float64)
    if np.any(v <= 0) or np.any(a <= 0):
        raise ConfigurationError(f"v_max and a_max must be > 0, got {v.tolist()}, {a.tolist()}")
    moving = np.concatenate([[True], np.any(np.diff(q, axis=0) != 0.0, axis=1)])
    q = q[moving]
    n = q.shape[0]
    if n < 2:
        return TimedPath(t=np.zeros(1), q=q[:1].copy())
    dq = np.gradient(q, axis=0)
    ddq = np.zeros_like(q)
    if n >= 3:
        ddq[1:-1] = q[2:] - 2.0 * q[1:-1] + q[:-2]
    # maximum velocity curve: velocity limits, then acceleration feasibility (bisection)
    speed = np.abs(dq) / v  # time per unit s at unit rate, per joint
    x_hi = 1.0 / np.maximum(np.max(speed, axis=1), 1e-6) ** 2
    lo_b, hi_b = _accel_bounds(dq, ddq, x_hi, a)
    ok = lo_b <= hi_b
    x_lo = np.zeros(n)
    x_top = x_hi.copy()
    for _ in range(80):
        if np.all(ok):
            break
        mid = 0.5 * (x_lo + x_top)
        lo_m, hi_m = _accel_bounds(dq, ddq, mid, a)
        good = lo_m <= hi_m
        x_lo = np.where(~ok & good, mid, x_lo)
        x_top = np.where(~ok & ~good, mid, x_top)
    mvc = np.where(ok, x_hi, x_lo)
    x = mvc.copy()
    x[0] = 0.0
    x[-1] = 0.0
    for i in range(n - 1):  # forward: accelerate as much as allowed
        _, hi_i = _accel_bounds(dq[i : i + 1], ddq[i : i + 1], x[i : i + 1], a)
        x[i + 1] = min(x[i + 1], max(x[i] + 2.0 * float(hi_i[0]), 0.0))
    for i in range(n - 1, 0, -1):  # backward: decelerate
        lo_i, _ = _accel_bounds(dq[i : i + 1], ddq[i : i + 1], x[i : i + 1], a)
        x[i - 1] = min(x[i - 1], max(x[i] - 2.0 * float(lo_i[0]), 0.0))
    sd = np.sqrt(np.maximum(x, 0.0))
    denom = sd[:-1] + sd[1:]
    floor = 1e-9 * max(float(np.max(denom)), 1e-9)
    dt = 2.0 / np.maximum(denom, floor)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    vmax, amax = _discrete_limits(t, q)
    scale = max(1.0, float(np.max(vmax / v)), float(np.sqrt(np.max(amax / a))))
    return TimedPath(t=t * scale * (1.0 + 1e-9), q=q)

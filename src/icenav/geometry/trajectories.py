"""Image spinning and Savitzky-Golay smoothing of joint paths.

Image spinning (paper Sec. III-C, last paragraph): turn the ultrasound image plane 360 deg
about the catheter axis at the tip while the tip stays put. The intended pose is the start
pose turned about its own z axis::

    tip2base(t) = tip2base(0) @ Rot_z(direction * t),   t in [0, 2 pi * turns]

and the model joint path follows by inverse kinematics (Eqs. (3)-(8)). From
(phi1, phi2) = (a, 0) this is the paper's example phi1 = a cos t, phi2 = a sin t,
phi3 = -t (``direction = -1``).

Commanded paths are smoothed with a quadratic Savitzky-Golay filter, as the paper does
(the controller's path task times them at its speed limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import savgol_filter

from icenav._typing import Array
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
    "savgol_smooth",
    "spin_trajectory",
]


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

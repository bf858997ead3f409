"""Boundary checks shared by every module (pytransform3d's ``check_*`` habit).

Each helper converts its input to a float64 array and raises an
:class:`~icenav.errors.InvalidValueError` subclass that says what was expected (the shape,
the unit, the range) and what arrived. Hot loops call the public functions with
``check=False`` and skip these.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav.errors import (
    ConfigurationError,
    FileFormatError,
    JointLimitError,
    NonFiniteError,
    ShapeError,
    TransformError,
)

__all__ = [
    "JOINT_NAMES",
    "JOINT_UNITS",
    "check_finite",
    "check_joint_state",
    "check_positive",
    "check_transform",
    "read_toml",
]

JOINT_NAMES = ("phi1", "phi2", "phi3", "d4")
"""Names of the four joints, in the order of the joint vector q."""

JOINT_UNITS = ("rad", "rad", "rad", "mm")
"""Units of the four joints."""


def check_finite(value: ArrayLike, name: str, unit: str = "") -> NDArray[np.float64]:
    """Return ``value`` as a float64 array, raising NonFiniteError on NaN or inf."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be numeric, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)].ravel()[0]
        unit_text = f" ({unit})" if unit else ""
        raise NonFiniteError(f"{name}{unit_text} must be finite, got {bad}")
    return arr


def check_positive(value: float, name: str, unit: str) -> float:
    """Return ``value`` as float, raising ConfigurationError unless finite and > 0."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f"{name} must be a number in {unit}, got {value!r}") from exc
    if not np.isfinite(v) or v <= 0.0:
        raise ConfigurationError(f"{name} must be finite and > 0 {unit}, got {v} {unit}")
    return v


def check_joint_state(
    q: ArrayLike,
    limits: NDArray[np.float64] | None = None,
    name: str = "q",
) -> NDArray[np.float64]:
    """Validate a joint state (or a batch of them).

    Parameters
    ----------
    q : array-like, shape (..., 4)
        Joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).
    limits : ndarray, shape (4, 2), optional
        Lower and upper limit of each joint (rad, rad, rad, mm); ``inf`` for none.
    name : str
        Name of the argument, used in messages.

    Returns
    -------
    q : ndarray, shape (..., 4), float64

    Raises
    ------
    ShapeError, NonFiniteError, JointLimitError
    """
    arr = check_finite(q, name)
    if arr.ndim == 0 or arr.shape[-1] != 4:
        raise ShapeError(
            f"{name} must have shape (4,) or (..., 4): (phi1 rad, phi2 rad, phi3 rad, d4 mm); "
            f"got shape {arr.shape}"
        )
    if limits is not None:
        flat = arr.reshape(-1, 4)
        outside = (flat < limits[:, 0] - 1e-12) | (flat > limits[:, 1] + 1e-12)
        if not outside.any():
            return arr
        for j in range(4):
            low, high = float(limits[j, 0]), float(limits[j, 1])
            col = flat[:, j]
            bad = (col < low - 1e-12) | (col > high + 1e-12)
            if np.any(bad):
                v = float(col[bad][0])
                unit = JOINT_UNITS[j]
                if unit == "rad":
                    msg = (
                        f"{name}: {JOINT_NAMES[j]} = {v:.6g} rad ({np.degrees(v):.2f} deg) is "
                        f"outside the allowed range [{low:.6g}, {high:.6g}] rad "
                        f"([{np.degrees(low):.1f}, {np.degrees(high):.1f}] deg)"
                    )
                else:
                    msg = (
                        f"{name}: {JOINT_NAMES[j]} = {v:.6g} mm is outside the allowed range "
                        f"[{low:.6g}, {high:.6g}] mm"
                    )
                raise JointLimitError(msg, joint=JOINT_NAMES[j], value=v, low=low, high=high)
    return arr


def check_transform(
    a2b: ArrayLike, name: str = "transform", tol: float = 1e-6
) -> NDArray[np.float64]:
    """Validate a rigid homogeneous transform (or a batch of them).

    Parameters
    ----------
    a2b : array-like, shape (..., 4, 4)
        Homogeneous transform; translation in mm.
    tol : float
        Allowed deviation of R^T R from identity, of det R from 1 and of the last row
        from (0, 0, 0, 1).

    Raises
    ------
    ShapeError, NonFiniteError, TransformError
    """
    arr = check_finite(a2b, name)
    if arr.ndim < 2 or arr.shape[-2:] != (4, 4):
        raise ShapeError(f"{name} must have shape (4, 4) or (..., 4, 4), got {arr.shape}")
    rot = arr[..., :3, :3]
    ortho_err = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-1, -2))
    det = np.linalg.det(rot)
    last_err = np.abs(arr[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    if np.any(ortho_err > tol) or np.any(np.abs(det - 1.0) > tol) or np.any(last_err > tol):
        raise TransformError(
            f"{name} is not a rigid transform: max |R^T R - I| = {np.max(ortho_err):.3g}, "
            f"det R = {np.ravel(det)[0]:.6g}, max |last row - (0,0,0,1)| = "
            f"{np.max(last_err):.3g} (allowed deviation {tol:g})"
        )
    return arr


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The tables of the TOML file ``path``; FileFormatError naming the file for one that
    cannot be read or is not TOML (``what`` says what the file is, for the message)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{p}: not a valid TOML file (UTF-8): {exc}") from exc
    except OSError as exc:
        raise FileFormatError(f"cannot read {what} {p}: {exc}") from exc

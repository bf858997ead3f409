"""Registration of the EM tracker to the robot base: recover ``tracker2base``.

What a lab does before calibrating (docs/digital-twin.md, "Registration"):

1. Mount the sensor at the tip and measure (or take from the mount's drawing) ``sensor2tip``.
2. Drive the robot through :func:`registration_joint_states`: the catheter straight (knobs
   at zero, where the constant-curvature model is exact), several translations along the
   axis and rolls stepped up and back down (so the torsional play averages out); at each,
   wait for the catheter to settle and average a few tracker samples.
3. Predict each sensor pose in the base frame with the kinematics,
   ``forward(q) @ sensor2tip``, and pair it with the tracked pose in the tracker frame.
4. Solve the paired-point problem (Kabsch-Umeyama, no scale) for ``tracker2base``, each pose
   contributing its position and three points along its axes (the axis line alone cannot fix
   the roll about it); check the RMS residual (0.3-0.8 mm with the twin's defaults: the
   jitter and the roll play; the smooth field distortion shifts all points alike). A
   residual far above that means a wrong ``sensor2tip`` or a moved field generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state, check_transform
from icenav.errors import (
    FileFormatError,
    IcenavError,
    InvalidValueError,
    ShapeError,
    UnsupportedVersionError,
)
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.geometry.se3 import rigid_inverse

__all__ = [
    "REGISTRATION_FORMAT",
    "Registration",
    "kabsch_umeyama",
    "register_tracker",
    "registration_joint_states",
]

REGISTRATION_FORMAT = 1
"""Version of :meth:`Registration.to_dict`'s layout (``format`` key); version 1 is the first."""


@dataclass(frozen=True, eq=False)
class Registration:
    """Where the tracker sits in the robot base frame and where the sensor sits in the tip
    frame: what turns a tracked sensor pose into ``tip2base`` (Eq. R1 of
    :mod:`icenav.devices.tracker`). Made by :func:`register_tracker` (with its residuals) or
    :meth:`given` (known transforms); stored in the session and in calibration files
    (:meth:`to_dict` / :meth:`from_dict`)."""

    tracker2base: Array
    """(4, 4) estimated pose of the tracker frame in the base frame (mm)."""
    rms_residual_mm: float
    """RMS distance between the predicted and the registered tracked points (mm)."""
    max_residual_mm: float
    """Largest such distance (mm)."""
    n_points: int
    """Number of point pairs used."""
    sensor2tip: Array = field(default_factory=lambda: np.eye(4))
    """(4, 4) pose of the sensor in the tip frame (mm): the mount, measured or from its
    drawing (an input of the registration, kept with it)."""

    def __post_init__(self) -> None:
        for name in ("tracker2base", "sensor2tip"):
            t = check_transform(getattr(self, name), name)
            if t.shape != (4, 4):
                raise ShapeError(f"{name} must be one (4, 4) transform, got {t.shape}")
            t = t.copy()
            t.setflags(write=False)
            object.__setattr__(self, name, t)
        for name in ("rms_residual_mm", "max_residual_mm"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0.0:
                raise InvalidValueError(f"{name} must be finite and >= 0 mm, got {v} mm")
            object.__setattr__(self, name, v)
        if int(self.n_points) != self.n_points or int(self.n_points) < 0:
            raise InvalidValueError(f"n_points must be an integer >= 0, got {self.n_points!r}")
        object.__setattr__(self, "n_points", int(self.n_points))

    @classmethod
    def given(cls, tracker2base: ArrayLike, sensor2tip: ArrayLike) -> Registration:
        """A registration of known transforms (from a fixture's drawing, or the twin's
        truth): no residuals, no points."""
        return cls(
            tracker2base=np.asarray(tracker2base, dtype=np.float64),
            rms_residual_mm=0.0,
            max_residual_mm=0.0,
            n_points=0,
            sensor2tip=np.asarray(sensor2tip, dtype=np.float64),
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Registration):
            return NotImplemented
        return (
            np.array_equal(self.tracker2base, other.tracker2base)
            and np.array_equal(self.sensor2tip, other.sensor2tip)
            and (self.rms_residual_mm, self.max_residual_mm, self.n_points)
            == (other.rms_residual_mm, other.max_residual_mm, other.n_points)
        )

    __hash__ = None  # type: ignore[assignment]  # holds arrays

    def to_dict(self) -> dict[str, object]:
        """A JSON-ready dict (``format`` = :data:`REGISTRATION_FORMAT`; mm)."""
        return {
            "format": REGISTRATION_FORMAT,
            "tracker2base": self.tracker2base.tolist(),
            "sensor2tip": self.sensor2tip.tolist(),
            "rms_residual_mm": self.rms_residual_mm,
            "max_residual_mm": self.max_residual_mm,
            "n_points": self.n_points,
        }

    @classmethod
    def from_dict(cls, data: object, source: str = "registration") -> Registration:
        """Inverse of :meth:`to_dict`; FileFormatError naming ``source`` and the bad key."""
        if not isinstance(data, dict):
            raise FileFormatError(f"{source}: a registration must be an object, got {data!r}")
        version = data.get("format")
        if version != REGISTRATION_FORMAT:
            raise UnsupportedVersionError(
                f"{source}: registration format {version!r} is not known "
                f"(this version reads format {REGISTRATION_FORMAT})"
            )
        try:
            return cls(
                tracker2base=np.asarray(data["tracker2base"], dtype=np.float64),
                rms_residual_mm=float(data.get("rms_residual_mm", 0.0)),
                max_residual_mm=float(data.get("max_residual_mm", 0.0)),
                n_points=int(data.get("n_points", 0)),
                sensor2tip=np.asarray(data["sensor2tip"], dtype=np.float64),
            )
        except KeyError as exc:
            raise FileFormatError(f"{source}: registration lacks {exc.args[0]!r}") from exc
        except (TypeError, ValueError, IcenavError) as exc:
            raise FileFormatError(f"{source}: bad registration: {exc}") from exc

    def sensor2base(self, sensor2tracker: Array) -> Array:
        """The tracked sensor pose (4, 4) in the base frame (mm)."""
        return self.tracker2base @ np.asarray(sensor2tracker, dtype=np.float64)

    def tip2base(self, sensor2tracker: Array) -> Array:
        """The tip pose (4, 4) in the base frame implied by a tracked sensor pose (mm):
        ``tracker2base @ sensor2tracker @ inv(sensor2tip)``."""
        return self.sensor2base(sensor2tracker) @ rigid_inverse(self.sensor2tip)


def kabsch_umeyama(points_a: ArrayLike, points_b: ArrayLike) -> Array:
    """Rigid transform ``a2b`` (4, 4) minimising sum |a2b(a_i) - b_i|^2 (Umeyama 1991, no scale).

    Parameters
    ----------
    points_a, points_b : array-like, shape (n, 3), n >= 3, not collinear
        Paired points in frames a and b (mm).
    """
    a = check_finite(points_a, "points_a", "mm")
    b = check_finite(points_b, "points_b", "mm")
    if a.ndim != 2 or a.shape[1] != 3 or a.shape != b.shape:
        raise ShapeError(
            f"points_a and points_b must both have shape (n, 3), got {a.shape} and {b.shape}"
        )
    if a.shape[0] < 3:
        raise InvalidValueError(f"need at least 3 point pairs, got {a.shape[0]}")
    ca = a.mean(axis=0)
    cb = b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    u, s, vt = np.linalg.svd(h)
    if s[1] < 1e-9 * max(s[0], 1e-300):
        raise InvalidValueError(
            "the points are collinear (or coincident): the rotation is not determined; "
            "use joint states that span a plane or a volume"
        )
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = cb - rot @ ca
    return out


def registration_joint_states(
    bend_rad: float = 0.0,
    n_roll: int = 6,
    translations_mm: tuple[float, ...] = (-30.0, 0.0, 30.0),
) -> Array:
    """Joint states for registration, shape (n, 4) (rad, rad, rad, mm).

    At each translation the roll steps up through ``n_roll`` angles and back down, so the
    torsional play is taken up in both directions and averages out. With ``bend_rad = 0``
    (the default) the catheter is straight, where the constant-curvature model is exact
    (the knobs sit in their dead-zone); with ``bend_rad > 0`` each roll is visited with an AP
    bend of that size too (more spread, but the model error of the bend enters).
    """
    rows = []
    rolls = [2.0 * math.pi * k / int(n_roll) for k in range(int(n_roll))]
    for d4 in translations_mm:
        for roll in rolls + rolls[::-1]:
            rows.append([0.0, 0.0, roll, d4])
            if bend_rad > 0.0:
                rows.append([bend_rad, 0.0, roll, d4])
    return np.array(rows)


def register_tracker(
    q_model: ArrayLike,
    sensor2tracker: ArrayLike,
    sensor2tip: ArrayLike,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    orientation_lever_mm: float = 50.0,
) -> Registration:
    """Estimate ``tracker2base`` from tracked sensor poses at known joint states.

    Parameters
    ----------
    q_model : array-like, shape (n, 4)
        Joint states at which the sensor was tracked (rad, rad, rad, mm).
    sensor2tracker : array-like, shape (n, 4, 4)
        Tracked sensor poses (mm); rows with NaN (missing samples) are skipped.
    sensor2tip : array-like, shape (4, 4)
        Fixed pose of the sensor in the tip frame (mm).
    orientation_lever_mm : float
        Use the tracked orientations too: each pose adds the three points at this distance
        along its axes (in both frames), so a straight catheter moved along its axis and
        rolled determines all six degrees of freedom. 0 uses positions only.
    """
    q = check_joint_state(q_model, geometry.joint_limits, name="q_model")
    s2t = np.asarray(sensor2tracker, dtype=np.float64)
    if q.ndim != 2 or s2t.shape != (q.shape[0], 4, 4):
        raise ShapeError(
            f"q_model must be (n, 4) and sensor2tracker (n, 4, 4), got {q.shape} and {s2t.shape}"
        )
    mount = check_transform(sensor2tip, "sensor2tip")
    ok = np.all(np.isfinite(s2t.reshape(len(q), -1)), axis=1)
    pred_poses = forward(q[ok], geometry) @ mount
    predicted = pred_poses[:, :3, 3]
    tracked = s2t[ok, :3, 3]
    lever = float(orientation_lever_mm)
    if lever > 0.0:
        # pose -> points: p + lever * (x, y, z axis); rows of the rotation's columns
        ext_pred = predicted[:, None, :] + lever * np.swapaxes(pred_poses[:, :3, :3], 1, 2)
        ext_trk = tracked[:, None, :] + lever * np.swapaxes(s2t[ok, :3, :3], 1, 2)
        t2b = kabsch_umeyama(
            np.concatenate([tracked, ext_trk.reshape(-1, 3)]),
            np.concatenate([predicted, ext_pred.reshape(-1, 3)]),
        )
    else:
        t2b = kabsch_umeyama(tracked, predicted)
    resid = np.linalg.norm(tracked @ t2b[:3, :3].T + t2b[:3, 3] - predicted, axis=1)
    return Registration(
        tracker2base=t2b,
        rms_residual_mm=float(np.sqrt(np.mean(resid**2))),
        max_residual_mm=float(resid.max()),
        n_points=int(ok.sum()),
        sensor2tip=mount,
    )

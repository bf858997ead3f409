"""Calibration sets: the motor joint states with the tracked tip poses they gave (what the
elasticity map F is built from), their subsets, and their versioned JSON file format.

File (:meth:`CalibrationSet.save`): ``format`` :data:`CALIBRATION_FORMAT`, ``version``
:data:`CALIBRATION_VERSION`, provenance strings, ``units``, ``q_motor`` (n, 4) and
``tip2base`` (n, 4, 4). :class:`icenav.calibration.files.CalibrationFile` adds the tracker's
registration to the same document.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_joint_state, check_transform
from icenav.errors import ConfigurationError, FileFormatError, UnsupportedVersionError

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "CalibrationSet",
    "grid_subset_indices",
]


CALIBRATION_FORMAT = "icenav.calibration.plans"
"""Value of the ``format`` field of a calibration file."""


CALIBRATION_VERSION = 2
"""Format version this icenav writes (and the newest it reads). Version 2 may carry the
tracker's registration (``registration``, read by :mod:`icenav.calibration.files`); version 1
files load unchanged."""


_POSE_TOL = 1e-4  # allowed deviation of a tracked rotation from orthonormal


def _readonly(a: Array) -> Array:
    out = np.array(a, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class CalibrationSet:
    """Motor joint states with the tracked tip poses they gave, and where they came from."""

    q_motor: Array
    """(n, 4) motor joint states (phi1 rad, phi2 rad, phi3 rad, d4 mm) that were commanded."""
    tip2base: Array
    """(n, 4, 4) tracked pose of the image centre frame in the base frame (mm)."""
    catheter_id: str = ""
    """Which catheter (serial number, or ``sim-seed-N`` on the twin)."""
    vessel: str = "straight"
    """Vessel / phantom condition during calibration (straight, moderate, steep, ...)."""
    created: str = ""
    """When the data was taken (ISO 8601, UTC); filled with the current time if empty."""
    method: str = ""
    """How the samples were chosen (``dense-raster``, ``five-point``, ``subset-9``, ...)."""
    notes: str = ""
    """Free text (tracker, operator, ...)."""

    def __post_init__(self) -> None:
        q = check_joint_state(self.q_motor, name="q_motor")
        if q.ndim != 2:
            raise FileFormatError(f"q_motor must have shape (n, 4), got {q.shape}")
        t = check_transform(self.tip2base, "tip2base", tol=_POSE_TOL)
        if t.ndim != 3:
            raise FileFormatError(f"tip2base must have shape (n, 4, 4), got {t.shape}")
        if t.shape[0] != q.shape[0]:
            raise FileFormatError(
                f"inconsistent calibration set: {q.shape[0]} joint states but "
                f"{t.shape[0]} tracked poses"
            )
        if q.shape[0] < 3:
            raise FileFormatError(f"a calibration set needs at least 3 samples, got {q.shape[0]}")
        for name in ("catheter_id", "vessel", "created", "method", "notes"):
            if not isinstance(getattr(self, name), str):
                raise FileFormatError(f"{name} must be a string, got {getattr(self, name)!r}")
        object.__setattr__(self, "q_motor", _readonly(q))
        object.__setattr__(self, "tip2base", _readonly(t))
        if not self.created:
            now = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
            object.__setattr__(self, "created", now)

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.q_motor.shape[0])

    def positions_in_knob_frame(self) -> Array:
        """(n, 3) tracked tip positions with each sample's roll and translation removed (mm).

        ``p = Rz(-phi3) (p_in_base - d4 e_z)``: the position the bend alone produces, which
        is what F depends on (roll and translation pass through F unchanged).
        """
        p = self.tip2base[:, :3, 3].copy()
        p[:, 2] -= self.q_motor[:, 3]
        c = np.cos(self.q_motor[:, 2])
        s = np.sin(self.q_motor[:, 2])
        x = c * p[:, 0] + s * p[:, 1]
        y = -s * p[:, 0] + c * p[:, 1]
        return np.stack([x, y, p[:, 2]], axis=-1)

    def subset(self, indices: Sequence[int] | NDArray[np.int_], method: str = "") -> CalibrationSet:
        """A calibration set of the chosen samples (same provenance)."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1 or idx.size == 0:
            raise ConfigurationError(f"indices must be a non-empty 1-D list, got {indices!r}")
        if np.any(idx < 0) or np.any(idx >= self.n_samples):
            raise ConfigurationError(
                f"indices must be in [0, {self.n_samples - 1}], got {idx.min()}..{idx.max()}"
            )
        return CalibrationSet(
            q_motor=self.q_motor[idx],
            tip2base=self.tip2base[idx],
            catheter_id=self.catheter_id,
            vessel=self.vessel,
            created=self.created,
            method=method or f"subset-{idx.size}",
            notes=self.notes,
        )

    def with_motor_knobs(self, knobs: ArrayLike, method: str = "") -> CalibrationSet:
        """The same poses attributed to other knob angles (n, 2) rad, e.g. effective angles
        after a hysteresis model (see :mod:`icenav.compensation.hysteresis`)."""
        k = check_finite(knobs, "knobs", "rad")
        if k.shape != (self.n_samples, 2):
            raise ConfigurationError(f"knobs must have shape ({self.n_samples}, 2), got {k.shape}")
        q = self.q_motor.copy()
        q[:, :2] = k
        return CalibrationSet(
            q_motor=q,
            tip2base=self.tip2base,
            catheter_id=self.catheter_id,
            vessel=self.vessel,
            created=self.created,
            method=method or self.method,
            notes=self.notes,
        )

    # --- files ---------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of this set (floats written exactly, as repr)."""
        return {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "catheter_id": self.catheter_id,
            "vessel": self.vessel,
            "created": self.created,
            "method": self.method,
            "notes": self.notes,
            "units": {"q_motor": ["rad", "rad", "rad", "mm"], "tip2base": "mm"},
            "q_motor": self.q_motor.tolist(),
            "tip2base": self.tip2base.tolist(),
        }

    def save(self, path: str | Path) -> None:
        """Write the set as a versioned JSON file."""
        text = json.dumps(self.to_dict(), indent=1)
        Path(path).write_text(text + "\n", encoding="utf-8")

    @classmethod
    def from_dict(cls, doc: object, source: str = "calibration document") -> CalibrationSet:
        """Parse a calibration document; raise FileFormatError / UnsupportedVersionError."""
        if not isinstance(doc, dict):
            raise FileFormatError(f"{source}: expected a JSON object, got {type(doc).__name__}")
        fmt = doc.get("format")
        if fmt != CALIBRATION_FORMAT:
            raise FileFormatError(
                f"{source}: not an icenav calibration file (format {fmt!r}, "
                f"expected {CALIBRATION_FORMAT!r})"
            )
        version = doc.get("version")
        if not isinstance(version, int) or isinstance(version, bool):
            raise FileFormatError(f"{source}: version must be an integer, got {version!r}")
        if version > CALIBRATION_VERSION or version < 1:
            raise UnsupportedVersionError(
                f"{source}: calibration file version {version} is not supported; this icenav "
                f"reads versions 1..{CALIBRATION_VERSION} (upgrade icenav to read newer files)"
            )
        missing = [k for k in ("q_motor", "tip2base") if k not in doc]
        if missing:
            raise FileFormatError(f"{source}: missing field(s) {', '.join(missing)}")
        try:
            q = np.asarray(doc["q_motor"], dtype=np.float64)
            t = np.asarray(doc["tip2base"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise FileFormatError(f"{source}: q_motor / tip2base are not numeric arrays") from exc
        if q.ndim != 2 or q.shape[1] != 4:
            raise FileFormatError(f"{source}: q_motor must have shape (n, 4), got {q.shape}")
        if t.ndim != 3 or t.shape[1:] != (4, 4):
            raise FileFormatError(f"{source}: tip2base must have shape (n, 4, 4), got {t.shape}")
        text = {}
        for key in ("catheter_id", "vessel", "created", "method", "notes"):
            value = doc.get(key, "")
            if not isinstance(value, str):
                raise FileFormatError(f"{source}: {key} must be a string, got {value!r}")
            text[key] = value
        try:
            return cls(q_motor=q, tip2base=t, **text)
        except FileFormatError as exc:
            raise FileFormatError(f"{source}: {exc}") from exc
        except ValueError as exc:  # InvalidValueError from the checks: bad numbers
            raise FileFormatError(f"{source}: invalid data: {exc}") from exc

    @classmethod
    def load(cls, path: str | Path) -> CalibrationSet:
        """Read a file written by :meth:`save`."""
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise FileFormatError(f"{p}: not a text (JSON) file") from exc
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FileFormatError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from exc
        return cls.from_dict(doc, source=str(p))


def grid_subset_indices(q_motor: ArrayLike, n_points: int) -> NDArray[np.int_]:
    """Indices of an ``n_points`` subset of a dense knob grid, for sparse calibrations.

    The subsets grow from the paper's five points (centre, +-limit on each knob) outwards:
    5 = centre + 4 axis ends; 9 = the 3 x 3 grid {-lim, 0, lim}^2; 13 = 9 + the four
    half-way points on the axes; 25 = the 5 x 5 grid; larger values take every k-th grid
    line. The nearest grid sample to each wanted knob pair is used.

    Parameters
    ----------
    q_motor : array-like, shape (n, 4)
        The dense set's motor joint states (rad, rad, rad, mm).
    n_points : int
        5, 9, 13, 25, 49, 81, ... or the full set size.
    """
    q = np.asarray(q_motor, dtype=np.float64)
    lim = float(np.max(np.abs(q[:, :2])))
    h = lim / 2.0
    wanted: list[tuple[float, float]]
    if n_points == 5:
        wanted = [(0, 0), (lim, 0), (-lim, 0), (0, lim), (0, -lim)]
    elif n_points == 9:
        wanted = [(a, b) for a in (-lim, 0, lim) for b in (-lim, 0, lim)]
    elif n_points == 13:
        wanted = [(a, b) for a in (-lim, 0, lim) for b in (-lim, 0, lim)]
        wanted += [(h, 0), (-h, 0), (0, h), (0, -h)]
    elif n_points == q.shape[0]:
        return np.arange(q.shape[0])
    else:
        side = int(round(math.sqrt(n_points)))
        if side * side != n_points or side < 2:
            raise ConfigurationError(
                f"n_points must be 5, 9, 13, a square (25, 49, ...) or the set size "
                f"{q.shape[0]}, got {n_points}"
            )
        ax = np.linspace(-lim, lim, side)
        wanted = [(a, b) for a in ax for b in ax]
    w = np.asarray(wanted, dtype=np.float64)
    d = np.linalg.norm(q[None, :, :2] - w[:, None, :], axis=-1)
    idx = np.argmin(d, axis=1)
    if len(set(idx.tolist())) != len(idx):
        raise ConfigurationError(f"the set is too coarse for a {n_points}-point subset")
    return idx

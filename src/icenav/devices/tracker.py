"""The tracker protocol: one interface for the twin's EM tracker and a real NDI Aurora.

:class:`TrackerBackend` is what calibration, the closed-loop spin, the pose stage and the
controller use; the simulated tracker (:class:`icenav.sim.tracker.EMTracker`) and the NDI
backend (:class:`icenav.devices.ndi.NDIAuroraTracker`) both satisfy it:

- ``get_frame() -> TrackerFrame``: the newest sample (timestamp, ``sensor2tracker`` or None,
  :class:`ToolStatus`, quality), non-blocking; a tool that is not seen is MISSING with no
  pose, never with its last pose;
- ``measure_sensor2tracker(n_average=1)``: the sensor pose in the tracker frame averaged over
  the next ``n_average`` samples (blocking for them), None when none was VALID;
- ``measure_tip2base(n_average=1)``: the same reading as the tip pose in the robot base
  frame through the tracker's :attr:`registration` (Eq. R1 below), None when MISSING or when
  the tracker is not registered;
- ``registration``: a :class:`icenav.devices.registration.Registration` value
  (``tracker2base``, ``sensor2tip``, residuals) or None; settable (a lab estimates it with the
  ``registration`` calibration procedure, or loads it from the session).

::

    tip2base = tracker2base @ sensor2tracker @ inv(sensor2tip)                    # (R1)
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from icenav._typing import Array
from icenav.devices.registration import Registration
from icenav.errors import ConfigurationError
from icenav.geometry.se3 import pose_mean

__all__ = [
    "ToolStatus",
    "TrackerBackend",
    "TrackerFrame",
    "check_n_average",
    "mean_sensor_pose",
]


class ToolStatus(enum.Enum):
    """Status of one tracked sample."""

    VALID = "valid"
    """A fresh pose within the measurement volume."""
    MISSING = "missing"
    """No pose: the sensor was not seen (dropout) or no sample exists yet."""
    OUT_OF_VOLUME = "out_of_volume"
    """The sensor is outside the measurement volume; no pose is reported."""


@dataclass(frozen=True)
class TrackerFrame:
    """One report of the tracker."""

    timestamp: float
    """Acquisition time of the sample on the tracker's clock (s)."""
    sensor2tracker: Array | None
    """(4, 4) pose of the sensor in the tracker frame (mm), None unless status is VALID."""
    status: ToolStatus
    """VALID, MISSING or OUT_OF_VOLUME."""
    quality: float
    """Confidence in [0, 1]: 1 undistorted, lower where the field distortion is large; 0 when
    no pose is reported."""


@runtime_checkable
class TrackerBackend(Protocol):
    """What icenav needs from a tracker (simulated or real); see the module docstring."""

    registration: Registration | None
    """Tracker to robot base and sensor mount; None: not registered (no ``tip2base``)."""

    def start(self) -> None:
        """Start tracking (open the device if needed)."""
        ...

    def stop(self) -> None:
        """Stop tracking and release the device."""
        ...

    def get_frame(self) -> TrackerFrame:
        """The newest sample of the tracked sensor (MISSING / OUT_OF_VOLUME without pose)."""
        ...

    def measure_sensor2tracker(self, n_average: int = 1) -> Array | None:
        """(4, 4) sensor pose in the tracker frame (mm) averaged over the next
        ``n_average`` samples (VALID ones only); None when none was VALID."""
        ...

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """(4, 4) tip pose in the base frame (mm) from :meth:`measure_sensor2tracker`
        through :attr:`registration` (Eq. R1); None when MISSING or unregistered."""
        ...


def check_n_average(n_average: object) -> int:
    """``n_average`` as an int >= 1 samples, or ConfigurationError naming it."""
    if (
        isinstance(n_average, bool)
        or not isinstance(n_average, int | np.integer | float)
        or not math.isfinite(float(n_average))
        or int(n_average) != n_average
        or int(n_average) < 1
    ):
        raise ConfigurationError(f"n_average must be an integer >= 1 (samples), got {n_average!r}")
    return int(n_average)


def mean_sensor_pose(frames: Sequence[TrackerFrame]) -> Array | None:
    """Mean (4, 4) of the VALID frames' ``sensor2tracker`` (mean position, chordal mean
    rotation; :func:`icenav.geometry.se3.pose_mean`); None when no frame is VALID."""
    poses = [f.sensor2tracker for f in frames if f.sensor2tracker is not None]
    if not poses:
        return None
    return pose_mean(np.stack(poses))

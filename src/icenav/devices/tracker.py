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
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from icenav._typing import Array
from icenav.devices.registration import Registration
from icenav.errors import ConfigurationError
from icenav.geometry.se3 import pose_mean

__all__ = [
    "PoseSampleBuffer",
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


class PoseSampleBuffer:
    """The tracker's recent tip poses with their times: what the cycle-averaged estimator
    (:class:`icenav.refinement.cycle_pose.CycleAveragedPose`, Eq. R1) cuts at complete
    breaths or beats. The control loop :meth:`push` es the newest VALID sample each cycle
    (never waiting for one); :meth:`sample_window` gives the last seconds of them.

    Parameters
    ----------
    capacity_s : float
        Seconds kept (older samples are dropped; at least the estimator's window).
    max_rate_hz : float
        Samples kept per second at most (a faster push keeps one per ``1 / max_rate_hz``).
    """

    def __init__(self, capacity_s: float = 20.0, max_rate_hz: float = 50.0) -> None:
        if not (math.isfinite(capacity_s) and capacity_s > 0):
            raise ConfigurationError(f"capacity_s must be > 0 s, got {capacity_s}")
        if not (math.isfinite(max_rate_hz) and max_rate_hz > 0):
            raise ConfigurationError(f"max_rate_hz must be > 0 Hz, got {max_rate_hz}")
        self.capacity_s = float(capacity_s)
        self.min_dt = 1.0 / float(max_rate_hz)
        n = int(math.ceil(capacity_s * max_rate_hz)) + 2
        self._t = np.full(n, -math.inf)
        self._p = np.zeros((n, 4, 4))
        self._next = 0
        self._count = 0
        self._lock = threading.Lock()  # the loop pushes; a worker may read

    def __len__(self) -> int:
        return self._count

    def span_s(self) -> float:
        """Time from the oldest kept sample to the newest (s; 0 with fewer than two)."""
        with self._lock:
            if self._count < 2:
                return 0.0
            kept = self._t[np.isfinite(self._t)]
            return float(kept.max() - kept.min())

    def push(self, t: float, tip2base: Array | None) -> None:
        """Keep the pose (4, 4) (mm, base frame) sampled at time ``t`` (s); None (no VALID
        sample) and samples closer than ``1 / max_rate_hz`` to the last kept are skipped."""
        if tip2base is None:
            return
        with self._lock:
            last = self._t[(self._next - 1) % len(self._t)]
            if t - last < self.min_dt - 1e-9:  # the clock's rounding
                return
            self._t[self._next] = float(t)
            self._p[self._next] = tip2base
            self._next = (self._next + 1) % len(self._t)
            self._count = min(self._count + 1, len(self._t))

    def sample_window(self, duration_s: float, rate_hz: float) -> tuple[Array, Array]:
        """The kept samples of the last ``duration_s`` (s) before the newest, thinned to at
        most ``rate_hz`` (Hz): (n,) times (s), (n, 4, 4) poses (mm); empty when none."""
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ConfigurationError(f"duration_s must be > 0 s, got {duration_s}")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigurationError(f"rate_hz must be > 0 Hz, got {rate_hz}")
        with self._lock:
            order = np.argsort(self._t, kind="stable")[len(self._t) - self._count :]
            t, p = self._t[order].copy(), self._p[order].copy()
        if not len(t):
            return np.zeros(0), np.zeros((0, 4, 4))
        keep = t > t[-1] - duration_s
        t, p = t[keep], p[keep]
        # the newest sample of each 1 / rate_hz slot, the slots counted back from the newest
        slot = np.floor((t[-1] - t) * rate_hz + 1e-9)
        newest = np.concatenate([slot[:-1] != slot[1:], [True]])
        return t[newest], p[newest]

"""The NDI Aurora as a :class:`icenav.devices.tracker.TrackerBackend`.

:class:`NDIAuroraTracker` talks to the Aurora through scikit-surgerynditracker's ``NDITracker``
(which drives NDI's serial command set through ``ndicapy``). It always asks for unsmoothed
quaternion frames: ``NDITracker``'s smoothing buffer averages with ``nanmean``, which would
keep reporting the last pose of a tool that went missing. ``measure_tip2base`` maps the
averaged sensor pose into the robot base frame through the tracker's :attr:`registration`
(estimated by the ``registration`` calibration procedure, or loaded from the session); an
unregistered tracker reports frames but no ``tip2base``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.devices.registration import Registration
from icenav.devices.tracker import (
    ToolStatus,
    TrackerFrame,
    check_n_average,
    mean_sensor_pose,
)
from icenav.errors import ConfigurationError, TrackerError

__all__ = ["NDIAuroraConfig", "NDIAuroraTracker", "quaternion_to_transform"]


@dataclass(frozen=True)
class NDIAuroraConfig:
    """How to reach the Aurora and which tool is the catheter's sensor."""

    serial_port: str | None = None
    """Serial device ("/dev/ttyUSB0", "COM3"); None = probe the ports for an NDI device."""
    ports_to_probe: int = 20
    """How many serial ports to probe when ``serial_port`` is None."""
    tool_index: int = 0
    """Which of the wired tools (in port-handle order) is the catheter sensor."""
    quality_scale_mm: float = 1.0
    """The NDI error indicator (RMS, mm) that maps to quality 0.5 (quality = s / (s + e))."""
    reads_per_sample: int = 200
    """How many frame reads (BX round trips, a few ms each) ``measure_*`` makes per sample it
    waits for before it reports a frozen tracker (TrackerError)."""

    def __post_init__(self) -> None:
        if self.tool_index < 0:
            raise ConfigurationError(f"tool_index must be >= 0, got {self.tool_index}")
        if self.ports_to_probe < 1:
            raise ConfigurationError(f"ports_to_probe must be >= 1, got {self.ports_to_probe}")
        if self.reads_per_sample < 1:
            raise ConfigurationError(
                f"reads_per_sample must be >= 1 reads, got {self.reads_per_sample}"
            )
        if not self.quality_scale_mm > 0:
            raise ConfigurationError(
                f"quality_scale_mm must be > 0 mm, got {self.quality_scale_mm} mm"
            )

    def as_nditracker_settings(self) -> dict[str, Any]:
        """The configuration dictionary scikit-surgerynditracker expects."""
        settings: dict[str, Any] = {
            "tracker type": "aurora",
            "ports to probe": self.ports_to_probe,
            "use quaternions": True,
            "smoothing buffer": 1,
        }
        if self.serial_port is not None:
            settings["serial port"] = self.serial_port
        return settings


def _default_factory(settings: Mapping[str, Any]) -> Any:
    from sksurgerynditracker.nditracker import NDITracker

    return NDITracker(dict(settings))


def quaternion_to_transform(
    quat_wxyz: NDArray[np.float64], translation_mm: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(4, 4) transform from a unit quaternion (w, x, y, z) and a translation (mm).

    The quaternion is normalised first (the tracker sends 4 significant digits).
    """
    q = np.asarray(quat_wxyz, dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not math.isfinite(n) or n < 1e-9:
        raise TrackerError(f"tracker sent an invalid quaternion {q.tolist()}")
    w, x, y, z = q / n
    t = np.eye(4)
    t[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    t[:3, 3] = translation_mm
    return t


class NDIAuroraTracker:
    """An NDI Aurora through scikit-surgerynditracker, as a
    :class:`~icenav.devices.tracker.TrackerBackend`.

    Parameters
    ----------
    config : NDIAuroraConfig
        Port and tool selection.
    clock : callable
        Clock for the frames' timestamps (s); the host time of the reply, as NDI's
        ``NDITracker`` stamps it. Default ``time.monotonic``.
    tracker_factory : callable, optional
        Builds the ``NDITracker`` from its settings dictionary (for tests or other NDI
        models); default scikit-surgerynditracker's ``NDITracker``.
    registration : Registration, optional
        Tracker to robot base and sensor mount (settable later, e.g. after the
        ``registration`` procedure); None: frames only, no ``tip2base``.
    """

    def __init__(
        self,
        config: NDIAuroraConfig | None = None,
        clock: Callable[[], float] = time.monotonic,
        tracker_factory: Callable[[Mapping[str, Any]], Any] | None = None,
        registration: Registration | None = None,
    ):
        self.config = config or NDIAuroraConfig()
        self.registration: Registration | None = registration
        """Tracker to robot base and sensor mount; None: not registered."""
        self._clock = clock
        self._factory = tracker_factory or _default_factory
        self._tracker: Any = None
        self._last_frame_number: float | None = None
        self._last: TrackerFrame | None = None

    @property
    def running(self) -> bool:
        """Whether tracking is started."""
        return self._tracker is not None

    def start(self) -> None:
        """Open the Aurora, enable its wired tools and start tracking.

        Raises TrackerError when the device cannot be reached or the tool does not exist.
        """
        if self._tracker is not None:
            return
        try:
            tracker = self._factory(self.config.as_nditracker_settings())
        except (OSError, ValueError, KeyError) as exc:
            raise TrackerError(f"cannot open the NDI Aurora: {exc}") from exc
        handles, _ = tracker.get_tool_descriptions()
        if self.config.tool_index >= len(handles):
            tracker.close()
            raise TrackerError(
                f"tool_index {self.config.tool_index} does not exist: the Aurora reports "
                f"{len(handles)} wired tool(s) (port handles {list(handles)})"
            )
        try:
            tracker.start_tracking()
        except (OSError, ValueError) as exc:
            raise TrackerError(f"the NDI Aurora refused to start tracking: {exc}") from exc
        self._tracker = tracker
        self._last_frame_number = None
        self._last = None

    def stop(self) -> None:
        """Stop tracking and close the serial connection."""
        tracker, self._tracker = self._tracker, None
        if tracker is not None:
            try:
                tracker.close()  # stops tracking first
            except (OSError, ValueError) as exc:
                raise TrackerError(f"closing the NDI Aurora failed: {exc}") from exc

    def get_frame(self) -> TrackerFrame:
        """Read one frame (a BX / TX command round trip).

        A tool the Aurora reports MISSING or DISABLED (NaN pose) is MISSING with no pose.
        When the tracker's frame number has not advanced, the previous report is repeated
        unchanged (same timestamp), so a consumer sees that no new sample exists.
        """
        if self._tracker is None:
            raise TrackerError("the NDI Aurora is not started; call start() first")
        try:
            _, _, frame_numbers, tracking, qualities = self._tracker.get_frame()
        except (OSError, ValueError) as exc:
            raise TrackerError(f"reading a frame from the NDI Aurora failed: {exc}") from exc
        i = self.config.tool_index
        now = self._clock()
        row = np.asarray(tracking[i], dtype=np.float64).reshape(-1)
        frame_number = float(frame_numbers[i])
        if row.shape != (7,) or not np.all(np.isfinite(row)):
            frame = TrackerFrame(now, None, ToolStatus.MISSING, 0.0)
            self._last, self._last_frame_number = frame, None
            return frame
        if (
            self._last is not None
            and self._last.status is ToolStatus.VALID
            and frame_number == self._last_frame_number
        ):
            return self._last
        error_mm = float(qualities[i])
        scale = self.config.quality_scale_mm
        quality = scale / (scale + error_mm) if math.isfinite(error_mm) and error_mm >= 0 else 0.0
        sensor2tracker = quaternion_to_transform(row[:4], row[4:7])
        frame = TrackerFrame(now, sensor2tracker, ToolStatus.VALID, quality)
        self._last, self._last_frame_number = frame, frame_number
        return frame

    def measure_sensor2tracker(self, n_average: int = 1) -> Array | None:
        """Sensor pose (4, 4) in the tracker frame (mm), averaged over the next ``n_average``
        new samples (frames whose frame number advanced; MISSING ones count as samples and
        are left out of the mean). Blocks for them (``n_average / 40 Hz`` on an Aurora).
        None when none was VALID; TrackerError when the frame number stops advancing for
        ``reads_per_sample`` reads."""
        n = check_n_average(n_average)
        frames: list[TrackerFrame] = []
        previous = self._last
        reads = 0
        while len(frames) < n:
            frame = self.get_frame()
            reads += 1
            if frame is not previous:  # a new sample (the same one is returned unchanged)
                frames.append(frame)
                previous = frame
                reads = 0
            elif reads >= self.config.reads_per_sample:
                raise TrackerError(
                    f"the NDI Aurora sent no new sample in {reads} frame reads "
                    f"({len(frames)} of {n} samples received): is it still tracking?"
                )
        return mean_sensor_pose(frames)

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """Tip pose (4, 4) in the robot base frame (mm):
        ``tracker2base @ sensor2tracker @ inv(sensor2tip)`` (the registration's) of
        :meth:`measure_sensor2tracker`; None when MISSING or not registered (no read then)."""
        n = check_n_average(n_average)
        if self.registration is None:
            return None
        sensor = self.measure_sensor2tracker(n)
        return None if sensor is None else self.registration.tip2base(sensor)

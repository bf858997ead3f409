"""A tracker read on its own thread, so the control loop never waits for a tracker.

The control loop reads the tracker every cycle (the refinement's sample buffer, the force
check's tip pose, the published sensor pose). A real tracker's ``get_frame`` is a serial
round trip (the NDI Aurora's BX command: milliseconds, more when the line is disturbed); made
from the control thread at 100 Hz, it would take a large part of every cycle and stall the
loop whenever the device does. :class:`PolledTracker` reads the wrapped tracker at its own
rate on a thread and answers ``get_frame`` from the newest frame at once. A frame older than
``max_age_s`` is reported MISSING, never as a stale VALID pose; a failed read is raised to
the caller (as the wrapped tracker would have raised it) until a read succeeds again.
``measure_*`` (registration, calibration: off the control loop, they may wait) go to the
wrapped tracker under the same lock as the thread's reads, so the two never interleave on
the serial line.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

from icenav._typing import Array
from icenav.devices.tracker import ToolStatus, TrackerFrame
from icenav.errors import ConfigurationError, TrackerError

__all__ = ["PolledTracker"]


class PolledTracker:
    """``tracker`` (a :class:`~icenav.devices.tracker.TrackerBackend`) read on a thread.

    Parameters
    ----------
    tracker : TrackerBackend
        The tracker whose reads block (e.g. :class:`icenav.devices.ndi.NDIAuroraTracker`).
    rate_hz : float
        Reads per second (the Aurora reports at 40 Hz).
    max_age_s : float
        A frame read longer ago than this is MISSING (s).
    clock : callable
        Host clock (s).
    """

    def __init__(
        self,
        tracker: Any,
        rate_hz: float = 40.0,
        max_age_s: float = 0.25,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        for name, value in (("rate_hz", rate_hz), ("max_age_s", max_age_s)):
            if not (math.isfinite(value) and value > 0):
                raise ConfigurationError(f"{name} must be > 0, got {value}")
        self.inner = tracker
        self.rate_hz = float(rate_hz)
        self.max_age_s = float(max_age_s)
        self._clock = clock
        self._io = threading.Lock()  # one conversation with the device at a time
        self._slot: tuple[float, TrackerFrame | None, BaseException | None] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.reads = 0
        """Reads made by the thread (for tests and diagnostics)."""

    @property
    def registration(self) -> Any:
        """The wrapped tracker's registration (settable)."""
        return self.inner.registration

    @registration.setter
    def registration(self, value: Any) -> None:
        self.inner.registration = value

    def start(self) -> None:
        """Start the wrapped tracker (if it is not) and the reading thread."""
        if not getattr(self.inner, "running", False):
            with self._io:
                self.inner.start()
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="icenav-tracker", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the thread, then the wrapped tracker."""
        thread, self._thread = self._thread, None
        self._stop.set()
        if thread is not None:
            thread.join(timeout=5.0)
        with self._io:
            self.inner.stop()
        self._slot = None

    def get_frame(self) -> TrackerFrame:
        """The newest frame read (never waits): MISSING before the first read and when the
        newest is older than ``max_age_s``; the read's TrackerError when the last read
        failed; TrackerError when the thread is not running."""
        if self._thread is None:
            raise TrackerError("the tracker is not started: call start() first")
        slot = self._slot
        now = self._clock()
        if slot is None:
            return TrackerFrame(now, None, ToolStatus.MISSING, 0.0)
        read_at, frame, error = slot
        if error is not None:
            raise TrackerError(f"the tracker's last read failed: {error}")
        assert frame is not None
        if now - read_at > self.max_age_s:
            return TrackerFrame(frame.timestamp, None, ToolStatus.MISSING, 0.0)
        return frame

    def measure_sensor2tracker(self, n_average: int = 1) -> Array | None:
        """The wrapped tracker's (it may wait for new samples; never on the control loop)."""
        with self._io:
            out: Array | None = self.inner.measure_sensor2tracker(n_average)
        return out

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """The wrapped tracker's (it may wait for new samples; never on the control loop)."""
        with self._io:
            out: Array | None = self.inner.measure_tip2base(n_average)
        return out

    def __getattr__(self, name: str) -> Any:
        # config, running, ... of the wrapped tracker
        return getattr(self.inner, name)

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        while not self._stop.is_set():
            t0 = self._clock()
            try:
                with self._io:
                    frame = self.inner.get_frame()
                self._slot = (self._clock(), frame, None)
            except Exception as exc:  # noqa: BLE001 - handed to the reader, who decides
                self._slot = (self._clock(), None, exc)
            self.reads += 1
            self._stop.wait(max(0.0, period - (self._clock() - t0)))

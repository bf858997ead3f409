"""A tracker read on its own thread: the caller never makes the device's round trip, a frame
older than its age limit is MISSING, a failed read reaches the caller, and a measurement never
interleaves with the thread's reads."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest

from icenav.devices.tracker import ToolStatus, TrackerFrame
from icenav.devices.tracker_feed import PolledTracker
from icenav.errors import ConfigurationError, TrackerError
from tests.support.clock import Clock


class BlockingTracker:
    """A tracker whose reads block until released (a serial round trip), recording who
    called and whether a measurement was in progress."""

    def __init__(self) -> None:
        self.registration = None
        self.running = False
        self.callers: list[str] = []
        self.release = threading.Semaphore(0)
        self.read_done = threading.Condition()
        self.n_done = 0
        self.fail: Exception | None = None
        self.measuring = False
        self.overlaps = 0

    def start(self) -> None:
        self.running = True

    def stop(self) -> None:
        self.running = False

    def get_frame(self) -> TrackerFrame:
        self.callers.append(threading.current_thread().name)
        self.overlaps += self.measuring
        self.release.acquire()  # the device answers when the test says so
        with self.read_done:
            self.n_done += 1
            self.read_done.notify_all()
        if self.fail is not None:
            raise self.fail
        pose = np.eye(4)
        pose[0, 3] = self.n_done
        return TrackerFrame(float(self.n_done), pose, ToolStatus.VALID, 1.0)

    def measure_tip2base(self, n_average: int = 1) -> Any:
        self.measuring = True
        self.callers.append(threading.current_thread().name)
        self.measuring = False
        return np.eye(4)


def _feed() -> tuple[PolledTracker, BlockingTracker, Clock]:
    inner, clock = BlockingTracker(), Clock()
    feed = PolledTracker(inner, rate_hz=1000.0, max_age_s=0.25, clock=clock)
    return feed, inner, clock


def test_the_caller_never_makes_the_round_trip_and_a_stale_frame_is_missing() -> None:
    feed, inner, clock = _feed()
    with pytest.raises(TrackerError, match="not started"):
        feed.get_frame()
    feed.start()
    try:
        assert inner.running
        assert feed.get_frame().status is ToolStatus.MISSING  # no read answered yet
        inner.release.release()
        while feed.reads < 1:
            threading.Event().wait(0.001)  # the feed thread stores the frame
        # the device is now blocked in the thread's next read: the caller still gets the
        # newest frame at once, many times
        frames = [feed.get_frame() for _ in range(100)]
        assert all(f.status is ToolStatus.VALID and f.sensor2tracker[0, 3] == 1 for f in frames)
        clock.t = 0.3  # older than max_age_s: never a stale pose as VALID
        assert feed.get_frame().status is ToolStatus.MISSING
        assert set(inner.callers) == {"icenav-tracker"}  # only the feed's thread read
    finally:
        inner.release.release(10)
        feed.stop()
    assert not inner.running


def test_a_failed_read_reaches_the_caller_until_a_read_succeeds() -> None:
    feed, inner, clock = _feed()
    inner.fail = OSError("serial timeout")
    feed.start()
    try:
        inner.release.release()
        while feed.reads < 1:
            threading.Event().wait(0.001)
        with pytest.raises(TrackerError, match="serial timeout"):
            feed.get_frame()
        inner.fail = None
        inner.release.release()
        while feed.reads < 2:
            threading.Event().wait(0.001)
        assert feed.get_frame().status is ToolStatus.VALID
    finally:
        inner.release.release(10)
        feed.stop()


def test_a_measurement_waits_for_the_threads_read_and_never_interleaves() -> None:
    feed, inner, _ = _feed()
    feed.start()
    try:
        done = threading.Event()
        result: list[Any] = []

        def measure() -> None:
            result.append(feed.measure_tip2base(4))
            done.set()

        while not inner.callers:  # the thread is inside a read (blocked on the device)
            threading.Event().wait(0.001)
        worker = threading.Thread(target=measure, name="registration")
        worker.start()
        assert not done.wait(0.05)  # it waits for the read in progress ...
        inner.release.release()
        assert done.wait(10.0)  # ... then runs
        worker.join()
        np.testing.assert_array_equal(result[0], np.eye(4))
        assert "registration" in inner.callers and inner.overlaps == 0
    finally:
        inner.release.release(10)
        feed.stop()


@pytest.mark.parametrize("kw", [{"rate_hz": 0.0}, {"max_age_s": float("nan")}])
def test_bad_settings_are_refused(kw: dict[str, float]) -> None:
    with pytest.raises(ConfigurationError):
        PolledTracker(BlockingTracker(), **kw)

"""Running the controller in real time: the loop thread, its supervisor, the worker jobs,
the imaging thread and the process-wide garbage-collection policy.

- :class:`LoopThread` calls ``step()`` at the control rate; a cycle that raises is the
  controller's business (it ends in FAULT), so the thread never dies; between cycles, in the
  idle time of a cycle, it runs the GC policy's full collection when due.
- :class:`Supervisor` watches the loop's heartbeat (the count of finished cycles): if it does
  not advance for ``stall_s`` (a cycle stuck in a driver call, a deadlock), it e-stops the
  robot from its own thread and reports it (the log, and the message the next state shows).
- :class:`Jobs` runs slow work off the control thread (planning on a large roadmap, a
  calibration's fit, a tracker reading that blocks) and hands each result back to the loop,
  which applies it at the start of a cycle; when the controller is stepped by hand (tests,
  simulation, the soak) the work runs at once, so a stepped run is reproducible.
- :class:`ImagingThread` renders the live image at its own rate, so a slow renderer never
  delays a cycle; an imager error is reported, and imaging goes on.
- GC policy (the soak, ``docs/safety.md``): a full (generation 2) collection traverses every
  container of the process and stalled one cycle for up to seconds on a long procedure. After
  start-up: collect once and freeze what exists, switch the automatic full collection off,
  and run a full collection only between cycles, at most every ``gc_full_every_s`` of
  controller time. Young generations stay automatic.
"""

from __future__ import annotations

import gc
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Generic, TypeVar

__all__ = ["GcPolicy", "ImagingThread", "Jobs", "LoopThread", "Supervisor"]

logger = logging.getLogger("icenav.control")

T = TypeVar("T")

_GC_NO_AUTOMATIC_FULL = 1_000_000_000
"""Generation-2 threshold of the GC policy: so large that no full collection is automatic."""
_GC_LOCK = threading.Lock()
_GC_USERS: set[int] = set()  # policies in force (GcPolicy.settle)
_GC_SAVED: list[int] = []  # the generation-2 threshold before the policy


class GcPolicy:
    """The garbage-collection policy of one controller (see the module docstring); the
    process-wide setting holds while any controller's policy is settled."""

    def __init__(self, every_s: float) -> None:
        self.every_s = float(every_s)
        self._next: float | None = None

    @property
    def settled(self) -> bool:
        """Whether this policy is in force."""
        return self._next is not None

    def settle(self, now: float) -> None:
        """Collect, ``gc.freeze()``, no automatic full collection (until :meth:`release` of
        the last policy in force)."""
        if self._next is not None:
            return
        with _GC_LOCK:
            if not _GC_USERS:
                gc.collect()
                gc.freeze()
                t0, t1, t2 = gc.get_threshold()
                _GC_SAVED[:] = [t2]
                gc.set_threshold(t0, t1, _GC_NO_AUTOMATIC_FULL)
            _GC_USERS.add(id(self))
        self._next = now + self.every_s

    def release(self) -> None:
        """Undo :meth:`settle` (the default policy is back once no policy is in force)."""
        if self._next is None:
            return
        self._next = None
        with _GC_LOCK:
            _GC_USERS.discard(id(self))
            if not _GC_USERS and _GC_SAVED:
                t0, t1, _ = gc.get_threshold()
                gc.set_threshold(t0, t1, _GC_SAVED.pop())
                gc.unfreeze()

    def collect_if_due(self, now: float) -> bool:
        """Run a full collection if ``every_s`` passed since the last one (controller time
        ``now``); return whether it ran."""
        if self._next is None or now < self._next:
            return False
        self._next = now + self.every_s
        gc.collect()
        return True

    @staticmethod
    def in_force_elsewhere() -> bool:
        """Whether any policy is in force in this process."""
        return bool(_GC_USERS)


class _Job(Generic[T]):
    __slots__ = ("apply", "future", "name")

    def __init__(self, future: Future[T], apply: Callable[[Future[T]], None], name: str):
        self.future = future
        self.apply = apply
        self.name = name


class Jobs:
    """Work off the control thread, results applied on it (see the module docstring).

    :meth:`submit` returns a :class:`concurrent.futures.Future`; :meth:`apply_finished`
    (called by the loop at the start of a cycle) calls each finished job's ``apply(future)``
    on the loop thread.
    """

    def __init__(self) -> None:
        self.threaded = False
        """Run jobs on threads (the real-time loop); False: at once, on the caller's thread."""
        self._pending: deque[_Job[Any]] = deque()
        self._lock = threading.Lock()

    def submit(
        self,
        fn: Callable[[], T],
        apply: Callable[[Future[T]], None] | None = None,
        name: str = "icenav-job",
        *,
        threaded: bool | None = None,
    ) -> Future[T]:
        """Run ``fn`` (on a daemon thread, or now); ``apply(future)`` runs on the loop once
        it finished. ``threaded``: always on a thread (True), never (False), or as
        :attr:`threaded` says (None): planning always runs on a thread, so that even a loop
        stepped by hand (the soak) never waits for a search."""
        future: Future[T] = Future()

        def run() -> None:
            if not future.set_running_or_notify_cancel():
                return
            try:
                future.set_result(fn())
            except BaseException as exc:  # noqa: BLE001 - handed to the loop, which reports it
                future.set_exception(exc)

        if apply is not None:
            with self._lock:
                self._pending.append(_Job(future, apply, name))
        if self.threaded if threaded is None else threaded:
            threading.Thread(target=run, name=name, daemon=True).start()
        else:
            run()
        return future

    def call_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the loop at the start of the next cycle (any thread may ask)."""
        future: Future[None] = Future()
        future.set_result(None)
        with self._lock:
            self._pending.append(_Job(future, lambda _f: fn(), "call-soon"))

    def apply_finished(self) -> None:
        """Apply the finished jobs (on the loop thread), in submission order."""
        if not self._pending:
            return
        with self._lock:
            done = [j for j in self._pending if j.future.done()]
            for job in done:
                self._pending.remove(job)
        for job in done:
            job.apply(job.future)

    def __len__(self) -> int:
        return len(self._pending)


class _Worker:
    """A daemon thread running ``_run`` between :meth:`start` and :meth:`stop` (the one
    lifecycle of the loop, the supervisor and the imager); ``_stop`` is set to end it."""

    _thread_name = "icenav-worker"

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        """True while the thread runs."""
        return self._thread is not None

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self._thread_name, daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
        self._thread = None

    def _run(self) -> None:
        raise NotImplementedError


class LoopThread(_Worker):
    """Calls ``step()`` every ``period_s`` in a thread until :meth:`stop`.

    Parameters
    ----------
    step : callable
        One control cycle; it handles its own exceptions (an exception escaping it is
        logged and the loop goes on).
    period_s : float
        The control period (s).
    idle : callable
        Called between cycles when more than half a period is left (the GC policy); returns
        whether it did anything.
    """

    def __init__(self, step: Callable[[], object], period_s: float, idle: Callable[[], bool]):
        super().__init__()
        self._step = step
        self.period_s = float(period_s)
        self._idle = idle
        self.cycle_starts: deque[float] = deque(maxlen=100_000)
        """perf_counter() at the start of the latest cycles (s), for jitter."""
        self.heartbeat = 0
        """Cycles finished (the supervisor watches it)."""
        self.escaped = 0
        """Exceptions that escaped ``step()`` (should stay 0: the cycle catches its own)."""

    _thread_name = "icenav-control"

    def _run(self) -> None:
        period = self.period_s
        next_t = time.perf_counter()
        while not self._stop.is_set():
            self.cycle_starts.append(time.perf_counter())
            try:
                self._step()
            except Exception:  # the loop never dies
                self.escaped += 1
                logger.exception("a control cycle raised past its own handler")
            self.heartbeat += 1
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0.5 * period and self._idle():
                delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.perf_counter()


class Supervisor(_Worker):
    """E-stops the robot when the loop's heartbeat stops for ``stall_s`` (see the module
    docstring). ``on_stall(seconds)`` is called from the supervisor's thread, once per
    stall (again only after the loop advanced)."""

    def __init__(
        self,
        heartbeat: Callable[[], int],
        on_stall: Callable[[float], None],
        stall_s: float,
    ) -> None:
        super().__init__()
        self._heartbeat = heartbeat
        self._on_stall = on_stall
        self.stall_s = float(stall_s)
        self.stalls = 0
        """Stalls detected."""

    _thread_name = "icenav-supervisor"

    def _run(self) -> None:
        last = self._heartbeat()
        since = time.perf_counter()
        reported = False
        while not self._stop.wait(self.stall_s / 4.0):
            beat = self._heartbeat()
            now = time.perf_counter()
            if beat != last:
                last, since, reported = beat, now, False
                continue
            if not reported and now - since > self.stall_s:
                reported = True
                self.stalls += 1
                try:
                    self._on_stall(now - since)
                except Exception:  # keep supervising
                    logger.exception("the supervisor's e-stop raised")


class ImagingThread(_Worker):
    """Calls ``render()`` at ``rate_hz`` until :meth:`stop`; an exception is handed to
    ``on_error`` (and rendering goes on at the same rate)."""

    def __init__(
        self, render: Callable[[], object], rate_hz: float, on_error: Callable[[Exception], None]
    ) -> None:
        super().__init__()
        self._render = render
        self._period = 1.0 / float(rate_hz)
        self._on_error = on_error
        self.errors = 0
        """Renders that raised."""

    _thread_name = "icenav-imager"

    def _run(self) -> None:
        while True:
            t0 = time.perf_counter()
            try:
                self._render()
            except Exception as exc:  # the imager is not in the control path
                self.errors += 1
                self._on_error(exc)
            if self._stop.wait(max(0.0, self._period - (time.perf_counter() - t0))):
                return

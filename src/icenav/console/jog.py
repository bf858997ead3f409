"""The on-screen jog, kept alive on the server between a browser's hold messages.

A held jog button makes the browser send a hold message every 1/jog_hz s from a JavaScript
timer. When the page's main thread is busy (measured: Chromium's software WebGL on a loaded
2-core machine fired a 50 ms timer 19 times in 3 s, and the messages arrived in bursts up to
0.74 s apart), the gaps exceed the controller's 0.25 s jog watchdog: the jog lapses and
restarts, the motion moves in stairs at a third of its speed (docs/console.md). So the
console repeats the jog itself at ``hz`` while the last hold message is younger than
``grace_s``; the release (the button's click on pointer-up) stops it at once with a zero
jog, a browser that goes away is disconnected (its motion stops), and the controller's
watchdog still ends a jog the console stops repeating. A release that never arrives stops
the motion within ``grace_s`` plus the watchdog.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Hashable

from icenav.errors import ConfigurationError

__all__ = ["JOG_GRACE_S", "JogRepeater"]

JOG_GRACE_S = 0.5
"""How long a held jog is repeated after the browser's latest hold message (s)."""


class JogRepeater:
    """Repeats each held jog at ``hz`` until released or ``grace_s`` after its last hold.

    Parameters
    ----------
    hz : float
        Repeat rate (Hz), > 0.
    grace_s : float
        A jog is repeated until this long after its latest :meth:`hold` (s), > 0.
    clock : callable
        Time source (s).
    """

    def __init__(
        self,
        hz: float,
        grace_s: float = JOG_GRACE_S,
        clock: Callable[[], float] = time.monotonic,
    ):
        if not hz > 0:
            raise ConfigurationError(f"jog repeat rate must be > 0 Hz, got {hz}")
        if not grace_s > 0:
            raise ConfigurationError(f"jog grace must be > 0 s, got {grace_s}")
        self.hz = hz
        self.grace_s = grace_s
        self._clock = clock
        self._lock = threading.Lock()
        self._held: dict[Hashable, tuple[Callable[[], None], float]] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def hold(self, key: Hashable, send: Callable[[], None]) -> None:
        """A hold message for ``key`` (one browser): send its jog now and keep repeating it."""
        with self._lock:
            self._held[key] = (send, self._clock() + self.grace_s)
        send()

    def release(self, key: Hashable) -> bool:
        """Stop repeating ``key``'s jog; True if one was held."""
        with self._lock:
            return self._held.pop(key, None) is not None

    def held(self) -> set[Hashable]:
        """Keys whose jog is being repeated."""
        with self._lock:
            return set(self._held)

    def tick(self) -> int:
        """Re-send every jog still within its grace, drop the others; how many were sent."""
        now = self._clock()
        with self._lock:
            for key in [k for k, (_, until) in self._held.items() if until < now]:
                del self._held[key]
            sends = [send for send, _ in self._held.values()]
        for send in sends:
            send()
        return len(sends)

    def start(self) -> None:
        """Repeat on a thread of its own (returns at once)."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="icenav-console-jog", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop repeating; forget every held jog."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            self._held.clear()

    def _run(self) -> None:
        while not self._stop.wait(1.0 / self.hz):
            self.tick()

"""The on-screen jog: a hold-to-run control with a dead-man, kept alive on the server
between a browser's "still held" messages.

A held jog button makes the browser send a hold message every 1/jog_hz s from a JavaScript
timer. When the page's main thread is busy (measured: Chromium's software WebGL on a loaded
2-core machine fired a 50 ms timer 19 times in 3 s), the gaps exceed the controller's 0.25 s
jog watchdog and the motion moves in stairs (docs/console.md). So the console repeats the
jog itself at ``hz`` while the browser's latest hold message is younger than the dead-man
time ``deadman_s`` (``ConsoleConfig.jog_deadman_s``).

The jog stops, with a zero jog sent at once (not left to the controller's watchdog):

- when the button is released (its click, on pointer-up: :meth:`JogRepeater.release`);
- when the page says the pointer left the button, the window lost the focus or the page
  was hidden (the page's guard, :data:`icenav.console.layout.JOG_GUARD_JS`, ends the press
  and clicks the button: a release);
- when no hold message came for ``deadman_s`` (a lost release, a frozen page): the
  dead-man **pauses** the jog; it moves again only if the page's holds resume (the page
  still says the button is held: a page starved by a loaded machine, measured in
  docs/console.md; a hidden page's holds end with the guard's release);
- when one browser holds two jog buttons at once: the conflicting holds **trip** the jog,
  which stays stopped whatever holds still arrive until a release;
- when the browser disconnects, loses control or the robot halts (the console releases).

Every send happens under one lock, so a repeat can never follow the release's zero jog:
once :meth:`JogRepeater.release` returns, that browser's jog is stopped for good.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass

from icenav.errors import ConfigurationError

__all__ = [
    "JOG_DEADMAN_RANGE_S",
    "JOG_DEADMAN_S",
    "JogEvent",
    "JogRepeater",
    "check_deadman",
]

JOG_DEADMAN_S = 0.5
"""Default dead-man time of the on-screen jog (s): a held jog stops this long after the
browser's latest hold message (10 messages at the page's 20 Hz)."""
JOG_DEADMAN_RANGE_S = (0.1, 1.0)
"""Allowed dead-man times (s): at least two hold periods at the page's fastest rate, at
most 1 s (30 deg of a knob at the jog's 30 deg/s past a lost release)."""


@dataclass(frozen=True)
class JogEvent:
    """One thing the jog saw (kept for diagnostics: :attr:`JogRepeater.events`)."""

    t: float
    """When (s, the repeater's clock)."""
    key: Hashable
    """The browser."""
    what: str
    """"press" (first hold of a press), "resume" (a hold after a pause), "pause" (the
    dead-man), "release", "trip" (conflicting holds: latched until a release), "ignored" (a
    hold while tripped, first of a run)."""
    button: Hashable = None
    """The button (axis, sign) of the press, if known."""
    detail: str = ""


@dataclass
class _Held:
    button: Hashable
    send: Callable[[], None]
    stop: Callable[[], None]
    last: float
    holds: int = 1
    longest_gap: float = 0.0

    def summary(self) -> str:
        return f"{self.holds} holds, longest gap {self.longest_gap:.2f} s"


class JogRepeater:
    """Repeats each held jog at ``hz`` while its holds keep coming; a dead-man stops it.

    Parameters
    ----------
    hz : float
        Repeat rate (Hz), > 0.
    deadman_s : float
        A jog pauses (a zero jog at once) when no hold came for this long (s), within
        :data:`JOG_DEADMAN_RANGE_S` and above two repeat periods.
    clock : callable
        Time source (s).
    on_trip : callable, optional
        Called with (key, reason, latched) when a browser's jog is paused by the dead-man
        (latched False) or tripped by conflicting holds (True); under the lock: keep it
        short and do not call back into the repeater.
    """

    def __init__(
        self,
        hz: float,
        deadman_s: float = JOG_DEADMAN_S,
        clock: Callable[[], float] = time.monotonic,
        on_trip: Callable[[Hashable, str, bool], None] | None = None,
    ):
        if not (math.isfinite(hz) and hz > 0):
            raise ConfigurationError(f"jog repeat rate must be > 0 Hz, got {hz}")
        check_deadman(deadman_s, hz)
        self.hz = hz
        self.deadman_s = float(deadman_s)
        self._clock = clock
        self._on_trip = on_trip
        self._lock = threading.RLock()
        self._held: dict[Hashable, _Held] = {}
        self._tripped: dict[Hashable, str] = {}
        self._paused: dict[Hashable, Hashable] = {}
        """The button of each browser's jog the dead-man paused."""
        self.events: deque[JogEvent] = deque(maxlen=200)
        """The latest presses, releases, trips and ignored holds (diagnostics)."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def hold(
        self,
        key: Hashable,
        button: Hashable,
        send: Callable[[], None],
        stop: Callable[[], None],
    ) -> bool:
        """A "still held" message of ``button`` from ``key`` (one browser): the first of a
        press (or the first after a pause) sends ``send`` at once, later ones renew the
        dead-man. ``stop`` sends the zero jog. False when ignored: tripped by conflicting
        holds (until :meth:`release`)."""
        with self._lock:
            now = self._clock()
            if key in self._tripped:
                if self._tripped[key] != "ignored":
                    self.events.append(JogEvent(now, key, "ignored", button))
                    self._tripped[key] = "ignored"
                return False
            held = self._held.get(key)
            if held is not None and held.button != button:
                self._trip(key, held, now, f"two jog buttons held at once ({button})")
                return False
            if held is not None and now - held.last > self.deadman_s:  # tick not yet run
                self._stop_jog(key, held, now, f"no hold for {now - held.last:.2f} s", False)
                held = None
            if held is None:
                resumed = self._paused.pop(key, None) == button
                self._held[key] = _Held(button, send, stop, now)
                self.events.append(JogEvent(now, key, "resume" if resumed else "press", button))
                send()
            else:
                held.holds += 1
                held.longest_gap = max(held.longest_gap, now - held.last)
                held.last = now
            return True

    def release(self, key: Hashable) -> bool:
        """The button let go (or the browser gone): stop ``key``'s jog with its zero jog,
        clear a tripped dead-man; True if a jog was running."""
        with self._lock:
            tripped = self._tripped.pop(key, None)
            paused = self._paused.pop(key, None)
            held = self._held.pop(key, None)
            if held is not None:
                button, detail = held.button, held.summary()
            else:  # every release is logged: a paused or tripped jog's too
                button, detail = None, "tripped" if tripped else "paused" if paused else "idle"
            self.events.append(JogEvent(self._clock(), key, "release", button, detail))
            if held is not None:
                held.stop()
            return held is not None

    def held(self) -> set[Hashable]:
        """Keys whose jog is running."""
        with self._lock:
            return set(self._held)

    def tripped(self) -> set[Hashable]:
        """Keys tripped by conflicting holds (jog stopped until released)."""
        with self._lock:
            return set(self._tripped)

    def tick(self) -> int:
        """Re-send every jog whose latest hold is within the dead-man time; pause the
        others (their zero jog sent); how many were re-sent."""
        sent = 0
        with self._lock:
            now = self._clock()
            for key, held in list(self._held.items()):
                if now - held.last > self.deadman_s:
                    self._stop_jog(key, held, now, f"no hold for {now - held.last:.2f} s", False)
                else:
                    held.send()
                    sent += 1
        return sent

    def _trip(self, key: Hashable, held: _Held, now: float, reason: str) -> None:
        self._stop_jog(key, held, now, reason, True)

    def _stop_jog(self, key: Hashable, held: _Held, now: float, reason: str, latch: bool) -> None:
        """The dead-man's pause (``latch`` False) or a conflict's trip: the zero jog now."""
        del self._held[key]
        if latch:
            self._tripped[key] = reason
        else:
            self._paused[key] = held.button
        what = "trip" if latch else "pause"
        self.events.append(JogEvent(now, key, what, held.button, f"{reason}; {held.summary()}"))
        held.stop()
        if self._on_trip is not None:
            self._on_trip(key, reason, latch)

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
            self._tripped.clear()
            self._paused.clear()

    def _run(self) -> None:
        while not self._stop.wait(1.0 / self.hz):
            self.tick()


def check_deadman(deadman_s: float, hz: float) -> None:
    """Refuse a dead-man time outside :data:`JOG_DEADMAN_RANGE_S` or within two periods of
    the hold messages at ``hz`` (the page's timer would trip it while held)."""
    lo, hi = JOG_DEADMAN_RANGE_S
    number = isinstance(deadman_s, int | float) and not isinstance(deadman_s, bool)
    if not (number and math.isfinite(deadman_s) and lo <= deadman_s <= hi):
        raise ConfigurationError(
            f"the jog dead-man time (ConsoleConfig.jog_deadman_s) must be in [{lo}, {hi}] s, "
            f"got {deadman_s!r} s"
        )
    if deadman_s <= 2.0 / hz:
        raise ConfigurationError(
            f"the jog dead-man time ({deadman_s} s) must exceed two hold periods "
            f"(2 / {hz} Hz = {2.0 / hz} s)"
        )

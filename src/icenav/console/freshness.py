"""Whether the state the console shows is current: the stale-state indicator.

The controller publishes a state at the end of every cycle, in every mode, idle and halted
alike (``ControllerConfig.publish_every`` = 1 cycle by default: 100 states a second at
100 Hz; ``Controller.step``). ``state.time`` is the controller's time (cycles x period), which
does not advance while the loop hangs, so it cannot tell the console how old a state is.
The console's own clock does: :class:`StateFreshness` notes when the refresh thread last
saw a new state (from the listener's mailbox, or a new ``controller.snapshot()``), and the
age of the shown state is the time since then. Past ``ConsoleConfig.stale_after_s`` the
safety bar says the robot's state is unknown (:func:`stale_banner_html`) until a new state
arrives. The age is measured to within one refresh period (the refresh looks 25 times a
second); a refresh thread that runs late sees the states waiting for it, so lateness alone
never shows the banner.

The indicator only informs: commands (Stop, E-STOP, every other) still go to the
controller, which decides them (an E-STOP is decided at once on the caller's thread, not
by the control loop).
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from dataclasses import dataclass

from icenav.console.jog import JOG_DEADMAN_RANGE_S, JOG_DEADMAN_S
from icenav.control.state import ControllerState
from icenav.errors import ConfigurationError

__all__ = ["ConsoleConfig", "StateFreshness", "check_publish_period", "stale_banner_html"]

STALE_AFTER_RANGE_S = (0.1, 10.0)
"""Allowed range of ``ConsoleConfig.stale_after_s`` (s): above the console's refresh period
(0.04 s at 25 Hz) and the controller's publish period (0.01 s), below anything an operator
would wait through."""


@dataclass(frozen=True)
class ConsoleConfig:
    """Settings of the console's safety bar and its on-screen jog."""

    stale_after_s: float = 0.5
    """The safety bar says "no state from the controller" once the newest state the console
    has seen is older than this (s, console clock). Default: 50 cycles of the controller at
    100 Hz (it publishes every cycle) and 12 refreshes at 25 Hz, half the supervisor's
    default stall limit (``ControllerConfig.stall_estop_s`` = 1 s), so the page says the
    state is unknown before the supervisor's E-STOP, which the page cannot show until the
    loop runs again."""

    jog_deadman_s: float = JOG_DEADMAN_S
    """A held on-screen jog stops when no "still held" message came from the browser for
    this long (s, console clock), and stays stopped until the button is released and
    pressed again (:mod:`icenav.console.jog`). Allowed 0.1-1 s, and above two hold periods
    of the page (``Console(jog_hz=...)``, 20 Hz: 0.1 s)."""

    def __post_init__(self) -> None:
        for name, (lo, hi) in (
            ("stale_after_s", STALE_AFTER_RANGE_S),
            ("jog_deadman_s", JOG_DEADMAN_RANGE_S),
        ):
            value = getattr(self, name)
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if not (number and math.isfinite(value) and lo <= value <= hi):
                raise ConfigurationError(
                    f"ConsoleConfig.{name} must be in [{lo}, {hi}] s, got {value!r} s"
                )


def check_publish_period(controller: object, stale_after_s: float) -> None:
    """Refuse a threshold a controller's regular publishing would cross: its publish period
    (``config.publish_every / config.rate_hz``, s) must be under ``stale_after_s``. A
    controller without such a ``config`` (a test double, a remote proxy) is not checked."""
    config = getattr(controller, "config", None)
    every, rate = getattr(config, "publish_every", None), getattr(config, "rate_hz", None)
    if isinstance(every, int) and isinstance(rate, int | float) and rate > 0:
        period = every / rate
        if period >= stale_after_s:
            raise ConfigurationError(
                f"ConsoleConfig.stale_after_s ({stale_after_s} s) must exceed the "
                f"controller's publish period ({every} cycles at {rate} Hz = {period} s)"
            )


class StateFreshness:
    """When the console last saw a new controller state, on the console's clock.

    Parameters
    ----------
    stale_after_s : float
        Age (s) beyond which the shown state counts as stale.
    clock : callable
        The console's clock (s, monotonic).
    """

    def __init__(self, stale_after_s: float, clock: Callable[[], float]) -> None:
        self.stale_after_s = float(stale_after_s)
        self._clock = clock
        self._seen: ControllerState | None = None
        self._seen_at: float | None = None

    def saw(self, state: ControllerState | None) -> None:
        """A state taken from the mailbox or the controller's snapshot: new if it is not
        the one seen last (the controller makes a new object each publish)."""
        if state is not None and state is not self._seen:
            self._seen = state
            self._seen_at = self._clock()

    def age_s(self) -> float | None:
        """Seconds since the newest state was seen (None before any)."""
        return None if self._seen_at is None else self._clock() - self._seen_at

    def stale_age_s(self) -> float | None:
        """The age (s) when it exceeds ``stale_after_s``; None while the state is current
        (or before the first state: the page then says it waits for the controller)."""
        age = self.age_s()
        return age if age is not None and age > self.stale_after_s else None


def stale_banner_html(age_s: float) -> str:
    """The stale-state banner (HTML, red like the halt banner)."""
    title = f"No state from the controller for {age_s:.1f} s: the robot's state is unknown"
    body = "The page shows the last state it had. E-STOP and Stop still go to the controller."
    return (
        f"<div class=\"icenav-banner icenav-stale\"><div style='font-size:1.15em;font-weight:700'>"
        f"{html.escape(title)}</div><div>{html.escape(body)}</div></div>"
    )

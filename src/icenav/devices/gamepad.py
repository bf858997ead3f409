"""Gamepad hardware: readings from a real pad (SDL2) or a scripted one.

Both sources yield :class:`JoystickSample` values (raw axes in -1..1, buttons as booleans, a
timestamp, ``connected``); what the axes and buttons *mean* (the mapping, the dead-man
button, the commands they send) is :mod:`icenav.control.teleop`'s business.

- :class:`Sdl2Gamepad`: a real gamepad on the host through SDL2 (pygame-ce), with background
  events allowed so the console need not have focus. No gamepad connected is normal: the
  sample says ``connected=False`` and carries no motion.
- :class:`ScriptedInput`: keyframes played back on an injectable clock, for tests and the
  headless demo.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from icenav.errors import ConfigurationError

__all__ = ["JoystickSample", "Keyframe", "ScriptedInput", "Sdl2Gamepad"]


@dataclass(frozen=True)
class JoystickSample:
    """One reading of a gamepad."""

    axes: tuple[float, ...]
    """Raw axis values in [-1, 1] (unitless; the deadzone is applied by the mapping)."""
    buttons: tuple[bool, ...]
    """Button states, True while pressed."""
    timestamp: float
    """Time of the reading (s, the source's clock)."""
    connected: bool = True
    """False when no gamepad is connected (then axes and buttons are empty)."""

    def axis(self, index: int) -> float:
        """Axis ``index``, or 0.0 when the pad has fewer axes (or the index is -1)."""
        if index < 0 or index >= len(self.axes):
            return 0.0
        value = self.axes[index]
        return value if math.isfinite(value) else 0.0

    def button(self, index: int) -> bool:
        """Button ``index``, or False when the pad has fewer buttons (or the index is -1)."""
        return 0 <= index < len(self.buttons) and self.buttons[index]


class Sdl2Gamepad:
    """The first gamepad SDL2 sees, through pygame-ce.

    Background joystick events are allowed (the console runs in a browser, not in an SDL
    window). With no gamepad plugged in, :meth:`poll` returns ``connected=False``; plugging
    one in later is picked up.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, index: int = 0):
        os.environ.setdefault("SDL_JOYSTICK_ALLOW_BACKGROUND_EVENTS", "1")
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
        # SDL would take over SIGINT/SIGTERM (turning them into quit events nobody reads),
        # so Ctrl-C and a service manager's stop would no longer end the console
        os.environ.setdefault("SDL_NO_SIGNAL_HANDLERS", "1")
        import pygame  # imported here: only a host with a gamepad needs SDL loaded

        self._pygame = pygame
        self._clock = clock
        self._index = index
        pygame.init()
        pygame.joystick.init()
        self._pad: Any = None

    def _open(self) -> None:
        js = self._pygame.joystick
        if js.get_count() > self._index:
            self._pad = js.Joystick(self._index)
            self._pad.init()

    def poll(self) -> JoystickSample:
        self._pygame.event.pump()
        for event in self._pygame.event.get():
            if event.type == self._pygame.JOYDEVICEREMOVED:
                self._pad = None
        if self._pad is None:
            self._open()
        now = self._clock()
        if self._pad is None:
            return JoystickSample(axes=(), buttons=(), timestamp=now, connected=False)
        axes = tuple(float(self._pad.get_axis(i)) for i in range(self._pad.get_numaxes()))
        buttons = tuple(bool(self._pad.get_button(i)) for i in range(self._pad.get_numbuttons()))
        return JoystickSample(axes=axes, buttons=buttons, timestamp=now)

    def close(self) -> None:
        self._pad = None
        self._pygame.joystick.quit()


@dataclass(frozen=True)
class Keyframe:
    """A scripted gamepad state that holds from ``t`` until the next keyframe."""

    t: float
    """Start time of this state (s, relative to the script's start)."""
    axes: tuple[float, ...] = ()
    """Raw axis values in [-1, 1]."""
    buttons: tuple[int, ...] = ()
    """Indices of the buttons held."""


@dataclass
class ScriptedInput:
    """Keyframes played back on a clock (tests, headless demo).

    ``clock`` returns seconds; the script starts at the first :meth:`poll`. After the last
    keyframe the pad reads neutral (no buttons), or disconnected if ``disconnect_at_end``.
    """

    keyframes: Sequence[Keyframe]
    clock: Callable[[], float] = time.monotonic
    n_axes: int = 6
    n_buttons: int = 12
    disconnect_at_end: bool = False
    duration: float | None = None
    _start: float | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        times = [k.t for k in self.keyframes]
        if times != sorted(times):
            raise ConfigurationError(f"keyframe times must be increasing (s), got {times}")

    def poll(self) -> JoystickSample:
        now = self.clock()
        if self._start is None:
            self._start = now
        t = now - self._start
        end = self.duration if self.duration is not None else math.inf
        current: Keyframe | None = None
        for k in self.keyframes:
            if k.t <= t:
                current = k
        if t >= end:
            current = None
            if self.disconnect_at_end:
                return JoystickSample(axes=(), buttons=(), timestamp=now, connected=False)
        axes = [0.0] * self.n_axes
        buttons = [False] * self.n_buttons
        if current is not None:
            for i, v in enumerate(current.axes[: self.n_axes]):
                axes[i] = float(v)
            for b in current.buttons:
                if 0 <= b < self.n_buttons:
                    buttons[b] = True
        return JoystickSample(axes=tuple(axes), buttons=tuple(buttons), timestamp=now)

    def close(self) -> None:
        pass

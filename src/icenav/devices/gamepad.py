"""Gamepad input for teleoperation, mapped like ROS's ``joy`` / ``teleop_twist_joy``.

An :class:`InputSource` yields :class:`JoystickSample` values (axes in -1..1 after the
deadzone, buttons as booleans, a timestamp). Two sources:

- :class:`Sdl2Gamepad`: a real gamepad on the host through SDL2 (pygame-ce), with background
  events allowed so the console need not have focus. No gamepad connected is normal: the
  sample says ``connected=False`` and carries no motion.
- :class:`ScriptedInput`: keyframes played back on an injectable clock, for tests and the
  headless demo.

:class:`JoystickMapping` (loadable from a TOML file) says which axis drives what and how
fast; :func:`knob_velocity` and :func:`tip_twist` turn a sample into a joint velocity
(knob mode) or a tip-frame twist (tip mode). Motion needs the enable (dead-man) button held;
releasing it gives a zero command.
"""

from __future__ import annotations

import math
import os
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from icenav.errors import ConfigurationError, FileFormatError

__all__ = [
    "InputSource",
    "JoystickMapping",
    "JoystickSample",
    "Keyframe",
    "ScriptedInput",
    "Sdl2Gamepad",
    "apply_deadzone",
    "knob_velocity",
    "load_mapping",
    "tip_twist",
]


@dataclass(frozen=True)
class JoystickSample:
    """One reading of a gamepad."""

    axes: tuple[float, ...]
    """Axis values in [-1, 1] after the deadzone (unitless)."""
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


class InputSource(Protocol):
    """Anything that yields gamepad samples."""

    def poll(self) -> JoystickSample:
        """The latest sample (never blocks)."""
        ...

    def close(self) -> None:
        """Release the device."""
        ...


@dataclass(frozen=True)
class JoystickMapping:
    """Which axis and button does what (indices as SDL2 reports them; -1 = unused).

    The defaults suit an Xbox-style pad: left stick = AP / RL knobs (or tip x / y), right
    stick horizontal = roll, right stick vertical = translation (or tip z).
    """

    axis_phi1: int = 1
    """Axis driving the AP knob (knob mode) or tip x velocity (tip mode)."""
    axis_phi2: int = 0
    """Axis driving the RL knob (knob mode) or tip y velocity (tip mode)."""
    axis_phi3: int = 3
    """Axis driving the bulk rotation (both modes: roll about the tip z axis in tip mode)."""
    axis_d4: int = 4
    """Axis driving the translation (knob mode) or tip z velocity (tip mode)."""
    invert: tuple[bool, bool, bool, bool] = (True, False, False, True)
    """Invert each of the four axes above (SDL's stick up is negative)."""
    deadzone: float = 0.08
    """Axis values with magnitude below this are 0; the rest is rescaled to reach 1."""
    knob_rate: float = math.radians(30.0)
    """Knob velocity at full stick (rad/s)."""
    roll_rate: float = math.radians(45.0)
    """Bulk rotation velocity at full stick (rad/s)."""
    translation_rate: float = 5.0
    """Translation velocity at full stick (mm/s)."""
    tip_speed: float = 10.0
    """Tip velocity at full stick in tip mode (mm/s)."""
    enable_button: int = 4
    """Dead-man button: motion only while held (left shoulder)."""
    save_view_button: int = 0
    """Save the current view (A)."""
    goto_view_button: int = 1
    """Go to the selected view (B)."""
    stop_button: int = 2
    """Stop the current automatic motion (X)."""
    mode_button: int = 3
    """Toggle knob / tip mode (Y)."""
    estop_button: int = 7
    """Emergency stop (Start)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.deadzone < 1.0:
            raise ConfigurationError(f"deadzone must be in [0, 1) (unitless), got {self.deadzone}")
        for name in ("knob_rate", "roll_rate", "translation_rate", "tip_speed"):
            value = getattr(self, name)
            unit = "mm/s" if name in ("translation_rate", "tip_speed") else "rad/s"
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigurationError(f"{name} must be finite and > 0 {unit}, got {value}")
        if len(self.invert) != 4:
            raise ConfigurationError(f"invert needs 4 booleans, got {self.invert!r}")
        for f in fields(self):
            if f.type == "int" and getattr(self, f.name) < -1:
                raise ConfigurationError(
                    f"{f.name} must be an axis/button index >= 0, or -1 for unused; "
                    f"got {getattr(self, f.name)}"
                )


def load_mapping(path: str | Path) -> JoystickMapping:
    """Read a :class:`JoystickMapping` from a TOML file (a ``[joystick]`` table).

    Rates may be given in degrees per second with a ``_deg`` suffix (``knob_rate_deg = 30``).
    Unknown keys are an error (a typo should not silently fall back to a default).
    """
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FileFormatError(f"cannot read joystick mapping {p}: {exc}") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"joystick mapping {p} is not valid TOML (UTF-8): {exc}") from exc
    table = data.get("joystick", data)
    if not isinstance(table, dict):
        raise FileFormatError(f"joystick mapping {p}: [joystick] must be a table, got {table!r}")
    types = {f.name: f.type for f in fields(JoystickMapping)}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        name = key
        if key.endswith("_deg") and key[:-4] in ("knob_rate", "roll_rate"):
            name = key[:-4]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise FileFormatError(f"joystick mapping {p}: {key} must be a number (deg/s)")
            value = math.radians(float(value))
        if name not in types:
            raise FileFormatError(
                f"joystick mapping {p}: unknown key {key!r}; known keys: {sorted(types)}"
            )
        expected = types[name]
        if name == "invert":
            if not (isinstance(value, list) and all(isinstance(v, bool) for v in value)):
                raise FileFormatError(f"joystick mapping {p}: invert must be 4 booleans")
            value = tuple(value)
        elif expected == "int" and (isinstance(value, bool) or not isinstance(value, int)):
            raise FileFormatError(f"joystick mapping {p}: {key} must be an integer index")
        elif expected == "float" and (
            isinstance(value, bool) or not isinstance(value, int | float)
        ):
            raise FileFormatError(f"joystick mapping {p}: {key} must be a number")
        kwargs[name] = value
    return JoystickMapping(**kwargs)


def apply_deadzone(value: float, deadzone: float) -> float:
    """Scaled deadzone: |value| < deadzone -> 0, else rescaled so that +-1 stays +-1."""
    if not math.isfinite(value):
        return 0.0
    v = max(-1.0, min(1.0, value))
    mag = abs(v)
    if mag < deadzone:
        return 0.0
    return math.copysign((mag - deadzone) / (1.0 - deadzone), v)


def _mapped_axes(sample: JoystickSample, m: JoystickMapping) -> NDArray[np.float64]:
    idx = (m.axis_phi1, m.axis_phi2, m.axis_phi3, m.axis_d4)
    out = np.array([apply_deadzone(sample.axis(i), m.deadzone) for i in idx])
    return np.where(np.array(m.invert), -out, out)


def knob_velocity(sample: JoystickSample, mapping: JoystickMapping) -> NDArray[np.float64]:
    """Knob-mode command: joint velocity (rad/s, rad/s, rad/s, mm/s), shape (4,).

    Zero unless the pad is connected and the enable button is held.
    """
    if not sample.connected or not sample.button(mapping.enable_button):
        return np.zeros(4)
    a = _mapped_axes(sample, mapping)
    m = mapping
    return a * np.array([m.knob_rate, m.knob_rate, m.roll_rate, m.translation_rate])


def tip_twist(sample: JoystickSample, mapping: JoystickMapping) -> NDArray[np.float64]:
    """Tip-mode command: twist in the tip frame (vx, vy, vz mm/s, wx, wy, wz rad/s).

    The left stick moves the image centre along tip x (image facing direction) and y, the
    right stick's vertical axis along the catheter axis z, its horizontal axis rolls about
    z. Zero unless the pad is connected and the enable button is held.
    """
    if not sample.connected or not sample.button(mapping.enable_button):
        return np.zeros(6)
    a = _mapped_axes(sample, mapping)
    s = mapping.tip_speed
    return np.array([a[0] * s, a[1] * s, a[3] * s, 0.0, 0.0, a[2] * mapping.roll_rate])


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

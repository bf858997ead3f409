"""Teleoperation: what a gamepad's sticks and buttons mean, and the operator's jog.

The gamepad hardware (SDL2) and the scripted pad live in :mod:`icenav.devices.gamepad`; they
yield readings with axes, buttons, a timestamp and ``connected`` (:class:`PadSample`). Here
is what a reading means, mapped like ROS's ``joy`` / ``teleop_twist_joy``:

- :class:`JoystickMapping` (loadable from a TOML file) says which axis drives what and how
  fast; :func:`knob_velocity` and :func:`tip_twist` turn a reading into a joint velocity (knob
  mode) or a tip-frame twist (tip mode). Motion needs the enable (dead-man) button held.
- :class:`GamepadReader` reads the pad once per cycle: a reading older than the watchdog, or
  with a non-finite axis, counts as released; button *edges* become commands (E-STOP, Stop,
  mode toggle, save view, go to view, refine view), the dead-man button takes and releases
  control, and the sticks become :class:`~icenav.control.commands.Jog` commands. The gamepad
  defines no command of its own: it sends the ones every adapter sends.
- :class:`JogHold` is the jog being applied (from the gamepad or the console): it lasts one
  watchdog period unless repeated; :func:`jog_setpoint` turns it into the next set-point.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.control.commands import (
    GAMEPAD,
    Command,
    Disconnect,
    EStop,
    GoToView,
    Jog,
    RefineView,
    ReleaseControl,
    SaveView,
    SetMode,
    Stop,
    TakeControl,
)
from icenav.control.modes import TELEOP, Mode
from icenav.errors import ConfigurationError, FileFormatError
from icenav.geometry.kinematics import CatheterGeometry, tip_jog

__all__ = [
    "GamepadReader",
    "InputSource",
    "JogHold",
    "JoystickMapping",
    "PadReading",
    "PadSample",
    "apply_deadzone",
    "jog_setpoint",
    "knob_velocity",
    "load_mapping",
    "tip_twist",
]


class PadSample(Protocol):
    """One reading of a gamepad (:class:`icenav.devices.gamepad.JoystickSample` is one)."""

    @property
    def axes(self) -> tuple[float, ...]:
        """Axis values in [-1, 1] (unitless)."""
        ...

    @property
    def buttons(self) -> tuple[bool, ...]:
        """Button states, True while pressed."""
        ...

    @property
    def timestamp(self) -> float:
        """Time of the reading (s, the controller's clock)."""
        ...

    @property
    def connected(self) -> bool:
        """False when no gamepad is connected."""
        ...

    def axis(self, index: int) -> float:
        """Axis ``index``; 0.0 when the pad has fewer axes or the value is not finite."""
        ...

    def button(self, index: int) -> bool:
        """Button ``index``; False when the pad has fewer buttons."""
        ...


class InputSource(Protocol):
    """Anything that yields gamepad readings (``icenav.devices.gamepad``)."""

    def poll(self) -> PadSample:
        """The latest reading (never blocks)."""
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
    refine_view_button: int = 5
    """Refine the selected view on the EM sensor (right shoulder); after a Go to view."""
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


def _mapped_axes(sample: PadSample, m: JoystickMapping) -> NDArray[np.float64]:
    idx = (m.axis_phi1, m.axis_phi2, m.axis_phi3, m.axis_d4)
    out = np.array([apply_deadzone(sample.axis(i), m.deadzone) for i in idx])
    return np.where(np.array(m.invert), -out, out)


def knob_velocity(sample: PadSample, mapping: JoystickMapping) -> NDArray[np.float64]:
    """Knob-mode command: joint velocity (rad/s, rad/s, rad/s, mm/s), shape (4,).

    Zero unless the pad is connected and the enable button is held.
    """
    if not sample.connected or not sample.button(mapping.enable_button):
        return np.zeros(4)
    a = _mapped_axes(sample, mapping)
    m = mapping
    return a * np.array([m.knob_rate, m.knob_rate, m.roll_rate, m.translation_rate])


def tip_twist(sample: PadSample, mapping: JoystickMapping) -> NDArray[np.float64]:
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


@dataclass(frozen=True)
class PadReading:
    """What one cycle's gamepad reading asks for."""

    commands: tuple[Command, ...] = ()
    """Commands from button edges, the dead-man button and the sticks, in order."""
    message: str = ""
    """Why the reading was not used ("" when it was, or when the pad is simply idle)."""
    active: bool = False
    """The sticks command motion now (a jog is among the commands)."""


class GamepadReader:
    """Reads an :class:`InputSource` once per cycle and turns it into commands.

    Parameters
    ----------
    source : InputSource
        The gamepad.
    mapping : JoystickMapping
        What each axis and button does.
    watchdog_s : float
        A reading older than this counts as released (s).
    clock : callable
        The controller's clock (s).
    """

    def __init__(
        self,
        source: InputSource,
        mapping: JoystickMapping,
        watchdog_s: float,
        clock: Callable[[], float],
    ) -> None:
        self.source = source
        self.mapping = mapping
        self.watchdog_s = float(watchdog_s)
        self._clock = clock
        self._prev: tuple[bool, ...] = ()
        self._connected = False

    def read(
        self, mode: Mode, holder: str | None, n_views: int, selected_view: str | None
    ) -> PadReading:
        """This cycle's commands, given the mode, who holds control, how many views exist
        (the name of the next one) and the view selected for Go to view."""
        sample = self.source.poll()
        now = self._clock()
        mine = holder == GAMEPAD.client
        if not sample.connected:
            self._prev = ()
            gone = self._connected
            self._connected = False
            return PadReading((Disconnect(source=GAMEPAD),) if gone else ())
        self._connected = True
        if now - sample.timestamp > self.watchdog_s:
            release = (ReleaseControl(source=GAMEPAD),) if mine else ()
            return PadReading(release, "gamepad input stale: motion stopped")
        m = self.mapping
        prev = self._prev
        self._prev = sample.buttons

        def pressed(i: int) -> bool:
            return sample.button(i) and not (0 <= i < len(prev) and prev[i])

        if pressed(m.estop_button):
            return PadReading((EStop(source=GAMEPAD),))
        out: list[Command] = []
        if pressed(m.stop_button):
            out.append(Stop(source=GAMEPAD))
        if pressed(m.mode_button) and mode in TELEOP:
            out.append(SetMode(Mode.TIP if mode is Mode.KNOB else Mode.KNOB, source=GAMEPAD))
        if pressed(m.save_view_button):
            out.append(SaveView(f"view {n_views + 1}", source=GAMEPAD))
        if pressed(m.goto_view_button) and selected_view is not None:
            out.append(GoToView(selected_view, source=GAMEPAD))
        if pressed(m.refine_view_button) and selected_view is not None:
            out.append(RefineView(selected_view, source=GAMEPAD))
        if not all(math.isfinite(a) for a in sample.axes):  # reliability: never half-apply
            if mine:
                out.append(ReleaseControl(source=GAMEPAD))
            return PadReading(
                tuple(out), "gamepad input not finite (NaN / inf axis): treated as released"
            )
        if not sample.button(m.enable_button):
            if mine:  # the gamepad holds control while its dead-man button is held
                out.append(ReleaseControl(source=GAMEPAD))
            return PadReading(tuple(out))
        if not mine:
            out.append(TakeControl(source=GAMEPAD))
        if mode is Mode.TIP:
            twist = tip_twist(sample, m)
            if np.any(twist != 0):
                out.append(Jog(twist, "tip", source=GAMEPAD))
                return PadReading(tuple(out), active=True)
        else:
            v = knob_velocity(sample, m)
            if np.any(v != 0):
                out.append(Jog(v, "knob", source=GAMEPAD))
                return PadReading(tuple(out), active=True)
        return PadReading(tuple(out))


@dataclass(eq=False)
class JogHold:
    """The jog being applied: valid for one watchdog period after ``at`` unless renewed."""

    velocity: Array
    """(4,) joint velocity (rad/s, rad/s, rad/s, mm/s) or (6,) tip twist (mm/s, rad/s)."""
    frame: Literal["knob", "tip"]
    """Which of the two."""
    client: str
    """Who sent it (a disconnect or release of that client drops it)."""
    at: float = field(default=0.0)
    """When it was sent (s, the controller's clock)."""


def jog_setpoint(
    mode: Mode,
    jog: JogHold,
    q_cmd: Array,
    dt: float,
    geometry: CatheterGeometry,
    to_model: Callable[[Array], Array],
    to_motor: Callable[[Array], Array],
) -> Array | None:
    """The next motor set-point of a held jog in knob or tip mode (None: nothing to do in
    this mode, e.g. a tip-frame jog in knob mode; the robot holds).

    Knob mode: ``q_cmd + v dt``. Tip mode: the model joint step of the tip twist
    (:func:`icenav.geometry.kinematics.tip_jog`) from the model state of ``q_cmd``, mapped to
    the motors through the compensation (``to_motor``)."""
    if mode is Mode.KNOB and jog.frame == "knob":
        out: Array = q_cmd + jog.velocity * dt
        return out
    if mode is Mode.TIP and jog.frame == "tip":
        q_model = to_model(q_cmd)
        dq_model = tip_jog(q_model, jog.velocity, geometry, dt=dt, check=False)
        return to_motor(q_model + dq_model * dt)
    return None

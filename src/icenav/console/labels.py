"""Human words for what the console shows: modes, who holds control, the safety line, the
banner of a halted robot, and times in the units people read.

Internal names (``five_point``, ``browser-8``, ``GOTO_VIEW``) never reach the page: this
module turns them into the words on the screen. Pure functions, no viser.
"""

from __future__ import annotations

import datetime as dt
import html
import math
import re
from dataclasses import dataclass
from typing import Literal

from icenav.control.state import ControllerState, Mode, ViewSummary
from icenav.control.teleop import JoystickMapping

__all__ = [
    "ALARM_CLEAR",
    "Banner",
    "GamepadState",
    "MODE_LABELS",
    "SHORTCUTS",
    "ago_text",
    "alarm_html",
    "client_label",
    "duration_text",
    "halt_banner",
    "humanize",
    "jog_rate_words",
    "md",
    "robot_label",
    "safety_markdown",
    "tracker_label",
    "view_caption",
]

MODE_LABELS: dict[Mode, str] = {
    Mode.IDLE: "Holding still",
    Mode.KNOB: "Jogging the knobs",
    Mode.TIP: "Jogging the tip",
    Mode.GOTO_VIEW: "Going to a saved view",
    Mode.SPINNING: "Spinning the image 360°",
    Mode.CALIBRATING: "Calibrating",
    Mode.FAULT: "FAULT: robot stopped",
    Mode.ESTOP: "EMERGENCY STOP",
}
"""What each mode is called on the screen."""

SHORTCUTS: tuple[tuple[str, str], ...] = (
    ("Space", "Stop (end an automatic motion, hold position)"),
    ("Esc", "E-STOP (all axes, any mode)"),
    ("G", "Go to the selected view"),
    ("V", "Save a view under the name typed"),
    ("T", "Take control"),
)
"""The console's keyboard shortcuts (key, what it does); inactive while typing in a field."""

GamepadState = Literal["none", "connected", "disconnected"]
"""The controller's gamepad: none configured, connected, or configured but not connected."""

_CALIBRATION_WORDS = {
    "dense+hysteresis": "dense + hysteresis",
    "five_point": "5-point",
}
_BROWSER = re.compile(r"\bbrowser-(\d+)\b")
_IGTL = re.compile(r"\bigtl-([\w.:\[\]-]+)")


def client_label(client: str | None, me: str | None = None) -> str:
    """Who a client id is, in words: ``browser-8`` -> "browser #8" ("you" when it is ``me``),
    ``gamepad`` -> "the gamepad", ``igtl-host:port`` -> "3D Slicer at host:port",
    ``script`` -> "a script", None -> "nobody"."""
    if client is None:
        return "nobody"
    if me is not None and client == me:
        return f"you ({client_label(client)})"
    if client == "gamepad":
        return "the gamepad"
    if client == "script":
        return "a script"
    m = _BROWSER.fullmatch(client)
    if m:
        return f"browser #{m.group(1)}"
    if client.startswith("igtl-"):
        return f"3D Slicer at {client[5:]}"
    return client


def humanize(text: str) -> str:
    """A controller message with its internal names in words (``browser-1`` -> "browser #1",
    ``five_point`` -> "5-point", ``igtl-host:port`` -> "3D Slicer at host:port")."""
    out = _BROWSER.sub(lambda m: f"browser #{m.group(1)}", text)
    out = _IGTL.sub(lambda m: f"3D Slicer at {m.group(1)}", out)
    for raw, words in _CALIBRATION_WORDS.items():
        out = out.replace(raw, words)
    return out


def md(text: str) -> str:
    """Text from the controller or a client (a view name, a message, a client id), in words
    and safe inside markdown: viser renders raw HTML in markdown unsanitized, and a view
    name is whatever a client with control typed, so ``<`` ``>`` ``&`` become entities."""
    return html.escape(humanize(text), quote=False)


def duration_text(seconds: float) -> str:
    """A duration as people read it: "0.4 s", "42 s", "3 min 05 s", "1 h 02 min"."""
    if not math.isfinite(seconds):
        return "unknown"
    s = max(0.0, seconds)
    if s < 10:
        return f"{s:.1f} s"
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        m, r = divmod(int(round(s)), 60)
        return f"{m} min {r:02d} s"
    h, r = divmod(int(round(s)), 3600)
    return f"{h} h {r // 60:02d} min"


def ago_text(then_s: float, now_s: float) -> str:
    """How long ago wall-clock time ``then_s`` (s since the epoch) was: "just now",
    "5 min ago", "2 h ago", or the date when older than a day."""
    d = now_s - then_s
    if not math.isfinite(d) or d < 0:
        return "just now" if math.isfinite(d) and d > -5 else "at an unknown time"
    if d < 60:
        return "just now"
    if d < 3600:
        return f"{int(d // 60)} min ago"
    if d < 86400:
        return f"{int(d // 3600)} h ago"
    return "on " + dt.datetime.fromtimestamp(then_s).strftime("%Y-%m-%d")


def view_caption(view: ViewSummary, now_s: float) -> str:
    """One line under a view's thumbnail: its name and when it was saved."""
    clock = dt.datetime.fromtimestamp(view.created_s).strftime("%H:%M")
    image = "" if view.has_image else " (no image)"
    return f"{view.name}: saved {clock}, {ago_text(view.created_s, now_s)}{image}"


def robot_label(state: ControllerState) -> str:
    """The robot's status in words."""
    words = {"enabled": "enabled", "disabled": "disabled", "fault": "FAULT", "estop": "E-STOPPED"}
    return words.get(state.robot_status.value, state.robot_status.value)


def tracker_label(status: str) -> str:
    """The tracker's status in words."""
    words = {
        "VALID": "tracking",
        "MISSING": "sensor not seen",
        "ERROR": "error",
        "none": "none",
    }
    return words.get(status, status.lower())


def _gamepad_text(state: ControllerState, gamepad: GamepadState) -> str:
    if gamepad == "none":
        return "none configured"
    if gamepad == "disconnected":
        return "**not connected**"
    held = state.control_owner == "gamepad"  # it holds control while its dead-man is held
    return "connected, dead-man **held**" if held else "connected, dead-man released"


def safety_markdown(state: ControllerState, gamepad: GamepadState = "none") -> str:
    """The safety bar's status line: mode, robot, tracker, who holds control, gamepad."""
    mode = MODE_LABELS.get(state.mode, state.mode.value)
    return (
        f"**{mode}** &nbsp;·&nbsp; Robot: {robot_label(state)} &nbsp;·&nbsp; Tracker: "
        f"{tracker_label(state.tracker_status)}  \nControl: "
        f"**{md(client_label(state.control_owner))}** &nbsp;·&nbsp; Gamepad: "
        f"{_gamepad_text(state, gamepad)}"
    )


@dataclass(frozen=True)
class Banner:
    """The banner of a halted robot."""

    title: str
    cause: str
    action: str

    def markdown(self) -> str:
        return f"### {self.title}\n**Cause:** {self.cause}  \n**To clear:** {self.action}"

    def html(self) -> str:
        """The banner as HTML (the cause is the controller's text: escaped)."""

        def bold(text: str) -> str:
            parts = html.escape(text).split("**")
            return "".join(f"<b>{s}</b>" if i % 2 else s for i, s in enumerate(parts))

        return (
            f'<div class="icenav-banner icenav-halt">'
            f"<div style='font-size:1.05em;font-weight:700'>{html.escape(self.title)}</div>"
            f"<div><b>Cause:</b> {html.escape(self.cause)}</div>"
            f"<div><b>To clear:</b> {bold(self.action)}</div></div>"
        )


def jog_rate_words(mapping: JoystickMapping) -> dict[Mode, tuple[str, ...]]:
    """Each on-screen jog axis's speed in words, per jog mode (for the buttons' hints)."""
    knob = f"{math.degrees(mapping.knob_rate):.0f}°/s"
    roll = f"{math.degrees(mapping.roll_rate):.0f}°/s"
    tip = f"{mapping.tip_speed:.0f} mm/s"
    return {
        Mode.KNOB: (knob, knob, roll, f"{mapping.translation_rate:.0f} mm/s"),
        Mode.TIP: (tip, tip, tip, roll),
    }


def halt_banner(state: ControllerState) -> Banner | None:
    """In ESTOP or FAULT: the cause (the controller's message, in words) and the one action
    that clears it; None otherwise."""
    if state.mode not in (Mode.ESTOP, Mode.FAULT):
        return None
    cause = humanize(state.message) if state.message else "not reported"
    title = (
        "EMERGENCY STOP: motion controls disabled"
        if state.mode is Mode.ESTOP
        else "FAULT: robot stopped, motion controls disabled"
    )
    action = (
        "make the patient and the robot safe, then press **Reset fault** (from the "
        "browser holding control)."
    )
    return Banner(title, cause, action)


ALARM_CLEAR = "No alarm"
"""What the alarm area says while no banner is shown."""


def alarm_html(stale: str | None, halt: str | None) -> str:
    """The safety bar's alarm area (HTML): the stale-state banner above the halt banner, or
    a quiet "No alarm". The area has a fixed height (``layout.PAGE_CSS``, ``.icenav-alarm``;
    it scrolls inside when both banners are shown), so a banner coming or going moves no
    control below it under the operator's pointer."""
    inner = (stale or "") + (halt or "")
    if not inner:
        inner = f'<div class="icenav-clear">{ALARM_CLEAR}</div>'
    return f'<div class="icenav-alarm">{inner}</div>'

"""The jog tab's buttons wired to the hold-to-run jog (:mod:`icenav.console.jog`).

The hold and the click (pointer-up: the release) are viser callbacks declared ``async``:
viser runs those on its event loop in the order the page sent the messages, where plain
callbacks go to a thread pool in no set order (a release could then be handled before the
press's last hold, and that hold would start the jog again). They only take the jog's lock
and submit a command (non-blocking). The page's guard (:data:`icenav.console.layout.
JOG_GUARD_JS`) ends a press when the pointer leaves the button, the window loses the focus
or the page is hidden, and sends the release.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from icenav.console.layout import JOG_GUARD_JS
from icenav.console.panels import jog_command
from icenav.control.commands import Jog
from icenav.control.state import Mode

__all__ = ["JOG_PAUSED_TEXT", "JOG_TRIPPED_TEXT", "JogControls"]

JOG_PAUSED_TEXT = (
    "**Jog paused**: no hold signal from this page for {s:.1f} s ({reason}; the page is "
    "slow). It moves again while the page says the button is held; release to stop."
)
"""Told to the browser whose jog the dead-man paused."""
JOG_TRIPPED_TEXT = "**Jog stopped**: {reason}. Release the buttons, then press one."
"""Told to the browser that held two jog buttons at once."""


class JogControls:
    """Mixin of :class:`icenav.console.app.Console`: the jog buttons' callbacks."""

    # provided by the Console
    jog: Any
    jog_hz: float
    mapping: Any
    _last_state: Any
    _panels: dict[int, Any]
    send: Callable[..., None]

    def _wire_jog(self, panel: Any) -> None:
        """Hold to jog each button's axis; its click (pointer-up) releases."""
        for b, axis, sign in panel.jog_buttons:
            b.on_hold(self._jog_hold(panel, axis, sign), callback_hz=self.jog_hz)
            b.on_click(self._jog_release(panel))
        connection = getattr(panel.client, "_websock_connection", None)
        if connection is not None:  # a browser (not a test's stand-in): the page's guard
            from viser._messages import RunJavascriptMessage  # viser's own use: plotly.js

            ids = json.dumps([b._impl.uuid for b, _, _ in panel.jog_buttons])
            connection.queue_message(RunJavascriptMessage(source=f"{JOG_GUARD_JS}({ids});"))

    def _jog_hold(self, panel: Any, axis: int, sign: int) -> Any:
        def send() -> None:
            state = self._last_state
            if state is None or not panel.can_control:
                return  # not this browser's robot now (the refresh releases it)
            # Outside tip mode a jog drives the knobs: the controller wakes from IDLE into
            # knob mode on it, and it aborts an automatic motion (as gamepad input does).
            mode = Mode.TIP if state.mode == Mode.TIP else Mode.KNOB
            vel, frame = jog_command(mode, axis, sign, self.mapping)
            self.send(panel, Jog(vel, frame, source=panel.source))

        async def on_hold(ev: Any) -> None:
            self.jog.hold(panel.name, (axis, sign), send, lambda: self._jog_zero(panel))

        return on_hold

    def _jog_release(self, panel: Any) -> Any:
        async def on_click(ev: Any) -> None:
            self.jog.release(panel.name)

        return on_click

    def _jog_zero(self, panel: Any) -> None:
        """Stop ``panel``'s jog now: a zero jog, from a browser that may move the robot (a
        halted robot is stopped already, and would refuse it with a message)."""
        if panel.can_control and panel.enabled:
            state = self._last_state
            tip = state is not None and state.mode == Mode.TIP
            zero = np.zeros(6 if tip else 4)
            self.send(panel, Jog(zero, "tip" if tip else "knob", source=panel.source))

    def _jog_tripped(self, key: Hashable, reason: str, latched: bool) -> None:
        """Browser ``key``'s jog was paused by the dead-man or tripped by conflicting holds
        (``latched``): tell it (under the jog's lock)."""
        text = JOG_TRIPPED_TEXT if latched else JOG_PAUSED_TEXT
        for p in list(self._panels.values()):
            if p.name == key:
                p.tell(text.format(s=self.jog.deadman_s, reason=reason), "jog")

    def _jog_follow(self, panel: Any) -> None:
        """Refresh thread: a browser that may no longer move the robot (control lost, the
        robot halted) releases its jog."""
        if not panel.enabled and panel.name in self.jog.held():
            self.jog.release(panel.name)

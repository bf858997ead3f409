"""One browser's own controls in the console (viser handles made on its connection) and how
they follow the controller's state: enabled only while this browser holds control and the
robot is not halted, the view list with thumbnails, the jog labels of the mode.

The callbacks are wired by :class:`icenav.console.app.Console`; this module builds and
updates. Runs on viser's connection thread (build) and the console's refresh thread
(update).
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np

from icenav.console.commands import NO_VIEWS, Confirmation
from icenav.console.labels import view_caption
from icenav.console.layout import FEEDBACK_SLOT
from icenav.console.panels import (
    JOG_AXES,
    MODE_CHOICES,
    client_name,
    control_view,
    gray_to_rgb,
    mode_options,
)
from icenav.control.commands import Source
from icenav.control.state import ControllerState, ImageFrame, Mode, ViewSummary

__all__ = ["CALIBRATIONS", "ClientPanel", "THUMB_WIDTH_PX"]

CALIBRATIONS: dict[str, str] = {
    "Dense raster": "dense",
    "5-point": "five_point",
    "Dense + hysteresis": "dense+hysteresis",
}
"""Calibration dropdown label -> the controller's calibration kind."""
THUMB_WIDTH_PX = 180
"""Width of a view's thumbnail in the list (pixels)."""
FEEDBACK_S = 10.0
"""A refusal or failure shown to a browser is cleared after this long (s)."""


class ClientPanel:
    """One browser's own controls.

    Parameters
    ----------
    client : viser.ClientHandle
        The browser.
    token_needed : bool
        True when a control token must be entered before taking control.
    export : bool
        True to add the Export DICOM button.
    """

    def __init__(self, client: Any, token_needed: bool, export: bool):
        self.client = client
        self.name = client_name(client.client_id)
        self.source = Source("console", self.name)
        """The source of this browser's commands."""
        self.can_control: bool | None = None
        self.enabled: bool | None = None
        self.note_text = ""
        self.jog_mode: Mode | None = None
        self.mode_shown: tuple[tuple[str, ...], str] | None = None
        self.view_options: tuple[str, ...] = ()
        self.view_rows: dict[str, tuple[Any, Any]] = {}
        """Thumbnail and Go-to button of each view in the list."""
        self.feedback_text = ""
        """What the controller decided about this browser's latest refused or failed
        command (shown by the refresh thread)."""
        self.feedback_kind = ""
        self.feedback_at = 0.0
        self.feedback_shown = ""
        self.confirm: Confirmation | None = None
        """The confirmation dialog open in this browser (Delete view, Calibrate), if any."""
        self.exports: deque[str] = deque(maxlen=8)
        """Views whose export the controller accepted, to write on the refresh thread."""
        self.export_text = ""
        self.export_shown = ""
        self.authorised = not token_needed
        gui = client.gui
        self.note = gui.add_markdown("", order=1.0)
        self.feedback = gui.add_markdown(FEEDBACK_SLOT, order=1.01)
        self.token = None
        if token_needed:  # reliability: part 4 (security)
            self.token = gui.add_text("Control token", initial_value="", order=1.05)
        self.take = gui.add_button("Take control", order=1.1, hint="Shortcut: T")
        self.release = gui.add_button("Release control", order=1.2, visible=False)
        tabs = gui.add_tab_group(order=5.0)
        with tabs.add_tab("Views"):
            self.view_name = gui.add_text("View name", initial_value="view-1")
            self.save = gui.add_button("Save view", hint="Shortcut: V")
            self.views = gui.add_dropdown("Saved views", (NO_VIEWS,), initial_value=NO_VIEWS)
            self.goto = gui.add_button("Go to view", color="green", hint="Shortcut: G")
            self.refine = gui.add_button(
                "Refine view (EM)",
                color="teal",
                hint="After a return: corrects towards the selected view's tracked pose, "
                "averaged over complete breaths / beats (needs the tracker, and the view "
                "saved after the catheter was held still)",
            )
            self.delete = gui.add_button("Delete view", color="gray", hint="Asks first")
            self.export = None
            self.export_note = None
            if export:  # reliability: part 4 (security)
                self.export = gui.add_button("Export DICOM", hint="Into the export directory")
                self.export_note = gui.add_markdown("")
            self.view_list_note = gui.add_markdown("*No saved views yet.*")
            self.view_list = gui.add_folder("View list", expand_by_default=True)
        with tabs.add_tab("Jog"):
            self.jog_note = gui.add_markdown("")
            self.jog_buttons: list[tuple[Any, int, int]] = []
            labels = JOG_AXES[Mode.KNOB]
            for axis in range(4):
                for sign in (-1, 1):
                    b = gui.add_button(f"{labels[axis]} {'-' if sign < 0 else '+'}")
                    self.jog_buttons.append((b, axis, sign))
        with tabs.add_tab("Drive"):
            self.mode = gui.add_dropdown(
                "Mode", tuple(MODE_CHOICES), initial_value=next(iter(MODE_CHOICES))
            )
            self.compensation = gui.add_checkbox("Compensation", initial_value=False)
            self.spin = gui.add_button("Spin 360")
            self.calib_kind = gui.add_dropdown(
                "Calibration", tuple(CALIBRATIONS), initial_value="5-point"
            )
            self.calibrate = gui.add_button("Calibrate", hint="Explains and asks first")
        self.motion_controls = [
            self.mode,
            self.compensation,
            self.spin,
            self.calib_kind,
            self.calibrate,
            self.save,
            self.goto,
            self.refine,
            self.delete,
            *([self.export] if self.export is not None else []),
            *(b for b, _, _ in self.jog_buttons),
        ]
        """Every control that moves the robot or changes the session: enabled only while
        this browser holds control and the robot is not halted (ESTOP / FAULT)."""

    # ------------------------------------------------------------------ feedback
    def tell(self, text: str, kind: str = "") -> None:
        """Show ``text`` (markdown) to this browser for :data:`FEEDBACK_S`; any thread."""
        self.feedback_kind = kind
        self.feedback_at = time.monotonic()
        self.feedback_text = text

    def clear(self, kind: str | None = None) -> None:
        """Clear the feedback (only if it is of ``kind``, when given)."""
        if kind is None or self.feedback_kind == kind:
            self.feedback_text = ""

    def serve_feedback(self) -> None:
        """Refresh thread: show the newest feedback; drop it once stale."""
        if self.feedback_text and time.monotonic() - self.feedback_at > FEEDBACK_S:
            self.feedback_text = ""
        if self.feedback_text != self.feedback_shown:
            self.feedback.content = FEEDBACK_SLOT + self.feedback_text
            self.feedback_shown = self.feedback_text

    # ------------------------------------------------------------------ state
    def update(self, state: ControllerState, jog_rates: dict[Mode, tuple[str, ...]]) -> bool:
        """Follow ``state`` (``jog_rates``: each jog axis's speed in words, per mode); True
        when the view list changed (thumbnails to redraw)."""
        cv = control_view(state.control_owner, self.name)
        if cv.text != self.note_text:
            self.note.content = cv.text
            self.note_text = cv.text
        halted = state.mode in (Mode.ESTOP, Mode.FAULT)
        enabled = cv.can_control and not halted
        if enabled != self.enabled:
            for h in self.all_motion_controls():
                h.disabled = not enabled
            self.enabled = enabled
        self.can_control = cv.can_control
        self.take.visible = not cv.can_control
        self.take.disabled = not cv.can_take
        self.release.visible = cv.can_control
        shown = mode_options(state.mode)
        if shown != self.mode_shown:
            self.mode.options = shown[0]
            self.mode.value = shown[1]
            self.mode_shown = shown
        if self.compensation.value != state.compensation_enabled:
            self.compensation.value = state.compensation_enabled
        jog_mode = state.mode if state.mode == Mode.TIP else Mode.KNOB
        if jog_mode != self.jog_mode:
            labels = JOG_AXES[jog_mode]
            for b, axis, sign in self.jog_buttons:
                b.label = f"{labels[axis]} {'-' if sign < 0 else '+'}"
                b.hint = f"Hold to move at {jog_rates[jog_mode][axis]}; release to stop"
            word = "tip" if jog_mode is Mode.TIP else "knobs"
            self.jog_note.content = (
                f"Hold a button to jog the **{word}**; release to stop. "
                "Jogging during an automatic motion ends it."
            )
            self.jog_mode = jog_mode
        names = tuple(v.name for v in state.views)
        if names == self.view_options:
            return False
        new = [n for n in names if n not in self.view_options]
        self.view_options = names
        self.views.options = names or (NO_VIEWS,)
        if new:  # select the view just saved
            self.views.value = new[-1]
        elif self.views.value not in names:
            self.views.value = names[0] if names else NO_VIEWS
        return True

    def draw_view_list(
        self,
        views: tuple[ViewSummary, ...],
        image_of: Any,
        on_goto: Any,
    ) -> None:
        """The list of saved views, each with its thumbnail (the image saved with it), when
        it was saved, and a Go-to button; ``image_of(name)`` gives a view's ImageFrame or
        None, ``on_goto(name)`` makes the callback of its button."""
        gui = self.client.gui
        names = {v.name for v in views}
        for name in [n for n in self.view_rows if n not in names]:
            for h in self.view_rows.pop(name):
                h.remove()
        now = time.time()
        self.view_list_note.content = (
            "*No saved views yet.*" if not views else f"{len(views)} saved view(s):"
        )
        with self.view_list:
            for v in views:
                if v.name in self.view_rows:
                    self.view_rows[v.name][0].label = view_caption(v, now)
                    continue
                frame: ImageFrame | None = image_of(v.name)
                pixels = np.zeros((8, 8), np.uint8) if frame is None else frame.pixels
                thumb = gui.add_image(
                    gray_to_rgb(pixels, max_width=THUMB_WIDTH_PX, min_width=THUMB_WIDTH_PX),
                    label=view_caption(v, now),
                    format="jpeg",
                )
                go = gui.add_button(f"Go to {v.name}", color="green", disabled=not self.enabled)
                go.on_click(on_goto(v.name))
                self.view_rows[v.name] = (thumb, go)

    def all_motion_controls(self) -> list[Any]:
        """:attr:`motion_controls` and the Go-to button of each view in the list."""
        return [*self.motion_controls, *(go for _, go in self.view_rows.values())]

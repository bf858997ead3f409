"""The console's side of commands: each browser's commands sent to the controller (source
``Source("console", "browser-<id>")``), what the controller decided shown in that browser's
panel, confirmation dialogs (Delete view, Calibrate), and the DICOM export the controller
accepted (written on the refresh thread). Who may do what is decided by the controller
(:mod:`icenav.control.authorization`), never here."""

from __future__ import annotations

import contextlib
import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from icenav.console.labels import md
from icenav.control.commands import (
    Calibrate,
    Command,
    CommandResult,
    DeleteView,
    Export,
    Jog,
    Outcome,
)
from icenav.control.state import CalibrationKind, ControllerCommands, ControllerState
from icenav.errors import ExportError, IcenavError
from icenav.geometry.kinematics import CatheterGeometry, forward
from icenav.persistence.dicom import ExportDirectory, ViewClip

__all__ = ["Confirmation", "ConsoleCommands", "next_name"]

NO_VIEWS = "(no saved views)"
SINGLE_FRAME_TIME_S = 0.05
"""Frame Time written for a one-frame export (s; DICOM requires one for a multi-frame image)."""


@dataclass(eq=False)
class Confirmation:
    """A confirmation dialog of one browser: its modal and its two buttons."""

    modal: Any
    yes: Any
    no: Any


class ConsoleCommands:
    """The console's side of commands (mixed into :class:`~icenav.console.app.Console`):
    sending them for a browser and showing what the controller decided, the confirmation
    dialogs, and the DICOM export the controller accepted."""

    controller: ControllerCommands
    export_dir: ExportDirectory | None
    geometry: CatheterGeometry
    _lock: Any
    _panels: dict[int, Any]

    def send(
        self,
        panel: Any,
        command: Command,
        on_decided: Callable[[CommandResult], None] | None = None,
    ) -> None:
        """Submit ``command`` for ``panel``'s browser; a refusal or failure is shown in its
        panel (with the controller's reason), a success clears the note."""

        def show(result: CommandResult) -> None:
            what = md(command.describe())
            if result.outcome is Outcome.REFUSED:
                panel.tell(f"**Refused** ({what}): {md(result.reason)}", command.name)
            elif result.outcome is Outcome.FAILED:
                panel.tell(f"**Failed** ({what}): {md(result.reason)}", command.name)
            else:  # an accepted jog clears only a jog's refusal, not another command's
                panel.clear(command.name if isinstance(command, Jog) else None)

        ticket = self.controller.submit(command)
        if on_decided is not None:
            ticket.add_callback(on_decided, when="decided")
        ticket.add_callback(show, when="final")

    def _ask(self, panel: Any, title: str, text: str, yes: str, on_yes: Callable[[], None]) -> None:
        """A confirmation dialog in ``panel``'s browser: ``on_yes`` runs only on ``yes``."""
        if panel.confirm is not None:
            with contextlib.suppress(Exception):
                panel.confirm.modal.close()
        gui = panel.client.gui
        with gui.add_modal(title) as modal:
            gui.add_markdown(text)
            yes_button = gui.add_button(yes, color="red")
            no_button = gui.add_button("Cancel")
        confirm = Confirmation(modal, yes_button, no_button)
        panel.confirm = confirm

        def close() -> None:
            if panel.confirm is confirm:
                panel.confirm = None
            modal.close()

        @yes_button.on_click
        def _(ev: Any) -> None:
            close()
            on_yes()

        no_button.on_click(lambda ev: close())

    def _confirm_delete(self, panel: Any, view: str) -> None:
        self._ask(
            panel,
            "Delete view?",
            f"Delete the saved view **{md(view)}** from this session? Its image goes with it; "
            "the recorded roadmap stays.",
            "Delete",
            lambda: self.send(panel, DeleteView(view, source=panel.source)),
        )

    def _confirm_calibration(self, panel: Any, kind: CalibrationKind) -> None:
        try:
            text = md(self.controller.preview_calibration(kind).describe())
        except IcenavError as exc:
            panel.tell(f"**Cannot calibrate**: {md(str(exc))}")
            return
        self._ask(
            panel,
            "Start the calibration?",
            text,
            "Start calibration",
            lambda: self.send(panel, Calibrate(kind, source=panel.source)),
        )

    def _export_clicked(self, panel: Any) -> None:
        """The Export DICOM button: the controller decides (the holder only, the view saved
        with an image); once it accepted, the refresh thread writes the file and the outcome
        is shown under the button."""
        if panel.export_note is None:
            return
        if panel.views.value == NO_VIEWS:
            panel.export_note.content = "**Nothing to export**: save a view first."
            return
        view = str(panel.views.value)

        def decided(result: CommandResult) -> None:
            if result.outcome is Outcome.REFUSED:
                panel.export_text = f"**Export refused**: {md(result.reason)}"
            else:
                panel.exports.append(view)

        self.send(panel, Export(view, source=panel.source), on_decided=decided)

    def export_view(self, name: str, state: ControllerState | None = None) -> str:
        """Write the image saved with view ``name`` into :attr:`export_dir` as a DICOM file
        (one frame, with the view's joint state and pose); returns the operator's message
        (markdown), naming the file written or why nothing was written.

        ``name`` is looked up among the saved views; it never becomes a path (the file name
        is :meth:`ExportDirectory.path_for`'s).
        """
        if self.export_dir is None:
            return "**Export is off**: no export directory is configured."
        try:
            path = self.export_dir.write_clip(self.view_clip(name, state))
        except IcenavError as exc:
            return f"**Export failed**: {md(str(exc))}"
        return f"Exported view **{md(name)}** to `{path}`"

    def view_clip(self, name: str, state: ControllerState | None = None) -> ViewClip:
        """The image saved with view ``name`` as a one-frame clip with its state.

        The pose is the one the controller saved with the view when the controller exposes
        its view library (``controller.views``, as :class:`icenav.control.controller.Controller`
        does); otherwise the model pose of the view's motor state.

        Raises
        ------
        ExportError
            No view of that name, or no image saved with it.
        """
        state = state or self.controller.snapshot()
        summary = next((v for v in state.views if v.name == name), None)
        if summary is None:
            raise ExportError(f"no saved view named {name!r}")
        frame = self.controller.view_image(name)
        if frame is None:
            raise ExportError(f"view {name!r} has no saved image: nothing to export")
        q = np.asarray(summary.q_motor, dtype=np.float64)
        tip2base = None
        get = getattr(getattr(self.controller, "views", None), "get", None)
        if callable(get):
            with contextlib.suppress(KeyError, IcenavError):
                tip2base = get(name).tip2base
        if tip2base is None:
            tip2base = forward(q, self.geometry)
        ijk2tip = np.asarray(frame.ijk2tip, dtype=np.float64)
        pixel_mm = None  # identity: the imager did not say how large its pixels are
        if not np.array_equal(ijk2tip, np.eye(4)):
            pixel_mm = float(np.linalg.norm(ijk2tip[:3, 0]))  # one column step (mm)
        pixels = np.asarray(frame.pixels, dtype=np.uint8)
        if pixels.ndim == 3:  # RGB: grey for MONOCHROME2
            pixels = pixels.mean(axis=2).round().astype(np.uint8)
        return ViewClip(
            frames=pixels[np.newaxis],
            frame_time_s=SINGLE_FRAME_TIME_S,
            acquired_at=dt.datetime.fromtimestamp(summary.created_s, dt.UTC),
            q_motor=q,
            tip2base=np.asarray(tip2base, dtype=np.float64),
            view_name=name,
            pixel_mm=pixel_mm,
        )

    def _serve_panels(self) -> None:
        """Show each browser what the controller decided about its commands, and write the
        exports it accepted (on this, the refresh thread: no file I/O on the control thread
        or in viser's callbacks)."""
        with self._lock:
            panels = list(self._panels.values())
        for p in panels:
            p.serve_feedback()
            while p.exports:
                p.export_text = self.export_view(p.exports.popleft())
            if p.export_note is not None and p.export_text != p.export_shown:
                p.export_note.content = p.export_text
                p.export_shown = p.export_text


def next_name(name: str) -> str:
    """view-1 -> view-2; apex -> apex-2 (a suggestion for the next view's name)."""
    head, sep, tail = name.rpartition("-")
    if sep and tail.isdigit():
        return f"{head}-{int(tail) + 1}"
    return f"{name}-2"

"""The controller's thin calls: one method per command, for scripts and adapters.

Each call builds a command (:mod:`icenav.control.commands`) with the caller as its source and
submits it; the loop decides it (authorization, the mode machine, the handler) and the
returned :class:`~icenav.control.commands.Ticket` carries the outcome. These names are the
contract the console, the OpenIGTLink server, scripts and the external checks use; the
:class:`~icenav.control.controller.Controller` inherits them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Literal

from numpy.typing import ArrayLike

from icenav.control.commands import (
    Calibrate,
    Command,
    DeleteView,
    Disconnect,
    EStop,
    Export,
    GoToView,
    Jog,
    RefineView,
    ReleaseControl,
    RenameView,
    Reset,
    SaveView,
    SetCompensation,
    SetMode,
    Source,
    Spin,
    Stop,
    TakeControl,
    Ticket,
)
from icenav.control.modes import Mode
from icenav.control.state import CalibrationKind

__all__ = ["CommandCalls"]


class CommandCalls(ABC):
    """One call per command; ``client`` is a client name or a :class:`Source`."""

    @abstractmethod
    def submit(self, command: Command) -> Ticket:
        """Queue ``command`` for the loop to decide; E-STOP acts at once."""

    def request_mode(self, mode: Mode, client: str | Source = "script") -> Ticket:
        return self.submit(SetMode(mode, source=Source.of(client)))

    def jog(
        self, velocity: ArrayLike, frame: Literal["knob", "tip"], client: str | Source = "script"
    ) -> Ticket:
        return self.submit(Jog(velocity, frame, source=Source.of(client)))  # type: ignore[arg-type]

    def save_view(self, name: str, client: str | Source = "script") -> Ticket:
        return self.submit(SaveView(name, source=Source.of(client)))

    def goto_view(self, name: str, client: str | Source = "script") -> Ticket:
        return self.submit(GoToView(name, source=Source.of(client)))

    def refine_view(self, name: str, client: str | Source = "script") -> Ticket:
        return self.submit(RefineView(name, source=Source.of(client)))

    def rename_view(self, name: str, new_name: str, client: str | Source = "script") -> Ticket:
        return self.submit(RenameView(name, new_name, source=Source.of(client)))

    def delete_view(self, name: str, client: str | Source = "script") -> Ticket:
        return self.submit(DeleteView(name, source=Source.of(client)))

    def start_spin(self, client: str | Source = "script") -> Ticket:
        return self.submit(Spin(source=Source.of(client)))

    def start_calibration(self, kind: CalibrationKind, client: str | Source = "script") -> Ticket:
        return self.submit(Calibrate(kind, source=Source.of(client)))

    def set_compensation(self, enabled: bool, client: str | Source = "script") -> Ticket:
        return self.submit(SetCompensation(bool(enabled), source=Source.of(client)))

    def export(self, name: str, client: str | Source = "script") -> Ticket:
        return self.submit(Export(name, source=Source.of(client)))

    def stop(self, client: str | Source = "script") -> Ticket:
        return self.submit(Stop(source=Source.of(client)))

    def estop(self, client: str | Source = "script") -> Ticket:
        """Emergency stop: acts at once from the caller's thread, whatever the loop is doing."""
        return self.submit(EStop(source=Source.of(client)))

    def reset_fault(self, client: str | Source = "script") -> Ticket:
        return self.submit(Reset(source=Source.of(client)))

    def acquire_control(self, client: str | Source) -> bool:
        return self.submit(TakeControl(source=Source.of(client))).result().ok

    def release_control(self, client: str | Source) -> None:
        self.submit(ReleaseControl(source=Source.of(client)))

    def disconnect(self, client: str | Source) -> None:
        self.submit(Disconnect(source=Source.of(client)))

"""A mocked NDI Aurora: ndicapy's functions answering the command set the way an Aurora with
two wired tools does (as scikit-surgerynditracker's own tests mock it); scikit-surgerynditracker's
``NDITracker`` runs for real on top of it."""

from __future__ import annotations

import ndicapy
import pytest

Pose = tuple[float, float, float, float, float, float, float, float]


class FakeAurora:
    """ndicapy's functions for an Aurora with wired tools on port handles 0x0A and 0x0B."""

    def __init__(self, handles: tuple[int, ...] = (0x0A, 0x0B), probe_ok: bool = True):
        self.handles = list(handles)
        self.probe_ok = probe_ok
        self.commands: list[str] = []
        self.initialised: set[int] = set()
        self.enabled: set[int] = set()
        self.listing: list[int] = []
        self.frame = 100
        self.poses: dict[int, Pose | str] = {h: "MISSING" for h in handles}
        self.closed = False
        self.frozen = False

    # -- connection
    def ndiProbe(self, name: str) -> int:
        return ndicapy.NDI_OKAY if self.probe_ok else ndicapy.NDI_PROBE_FAIL

    def ndiOpen(self, name: str) -> str:
        self.port = name
        return "aurora-device"

    def ndiClose(self, device: str) -> None:
        self.closed = True

    def ndiGetError(self, device: str) -> int:
        return ndicapy.NDI_OKAY

    def ndiErrorString(self, errnum: int) -> str:
        return f"error {errnum}"

    def ndiVER(self, device: str, n: int) -> str:
        return "NDI AURORA\nFreeze Tag: AURORA Rev 009\n"

    # -- commands
    def ndiCommand(self, device: str, command: str) -> None:
        self.commands.append(command)
        if command == "PHSR:02":  # port handles to initialise
            self.listing = [h for h in self.handles if h not in self.initialised]
        elif command == "PHSR:03":  # initialised, not enabled
            self.listing = [h for h in self.handles if h in self.initialised - self.enabled]
        elif command.startswith("PINIT:"):
            self.initialised.add(int(command[6:8], 16))
        elif command.startswith("PENA:"):
            self.enabled.add(int(command[5:7], 16))
        elif command in ("BX:0801", "TX:0801") and not self.frozen:
            self.frame += 1

    def ndiGetPHSRNumberOfHandles(self, device: str) -> int:
        return len(self.listing)

    def ndiGetPHSRHandle(self, device: str, index: int) -> int:
        return self.listing[index]

    def ndiGetBXFrame(self, device: str, handle: bytes) -> int:
        return self.frame

    def ndiGetBXTransform(self, device: str, handle: bytes) -> Pose | str:
        return self.poses[handle[0]]

    def install(self, monkeypatch: pytest.MonkeyPatch) -> None:
        for name in dir(self):
            if name.startswith("ndi"):
                monkeypatch.setattr(ndicapy, name, getattr(self, name))


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        self.t += 0.025
        return self.t

"""Command-line interface: ``icenav <command> [options]``.

Each command lives in its own module with a ``main(argv) -> int``; this file only
dispatches, importing the module when the command is used (so ``icenav --help`` stays fast
and a command's heavy dependencies load only when needed).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

__all__ = ["COMMANDS", "main"]

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": (
        "icenav.apps.demo",
        "start the console on the simulated robot (headless: a scripted run)",
    ),
    "serve": (
        "icenav.apps.serve",
        "run the controller in real time without a browser, streaming to 3D Slicer",
    ),
    "run": (
        "icenav.apps.run",
        "the console on CiA 402 drives and a tracker, with the guided registration",
    ),
    "calibrate": (
        "icenav.apps.calibrate",
        "a calibration file from a recorded CSV of joint states and tracked poses",
    ),
    "eval": ("icenav.eval", "run an evaluation that reproduces a table of the paper"),
    "export-calibration": (
        "icenav.apps.export_calibration",
        "write a session's calibration in use (fitted model included) as a calibration file",
    ),
    "export-view": (
        "icenav.apps.export_view",
        "export a saved view's image from a session file as ultrasound DICOM",
    ),
}
"""command name -> (module with main(argv), one-line help)."""


def _usage() -> str:
    lines = ["usage: icenav <command> [options]", "", "commands:"]
    width = max(len(c) for c in COMMANDS)
    for name, (_, text) in COMMANDS.items():
        lines.append(f"  {name.ljust(width)}  {text}")
    lines.append("")
    lines.append("Run 'icenav <command> --help' for a command's options.")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``icenav`` console script; returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if args[0] == "--version":
        from icenav import __version__

        print(f"icenav {__version__}")
        return 0
    name = args[0]
    if name not in COMMANDS:
        print(f"icenav: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    code: int = module.main(args[1:])
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

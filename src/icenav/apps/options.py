"""The command-line options that ``icenav demo``, ``serve`` and ``run`` share, in one place.

Each ``add_*`` function adds one group of options to a parser and each ``check_*`` function
refuses a bad value with a message naming the option, the value, its unit and the allowed
range (``parser.error``: exit code 2 and the usage line), so that the three commands accept
the same spelling and reject the same mistakes:

- the twin (``--seed``, ``--vessel``, ``--plant MODULE:FACTORY``, ``--plant-family NAME``,
  ``--robot sim|emulated-canopen``);
- the hardware (``--robot-config FILE``, ``--tracker sim|ndi|none``, ``--tracker-config
  FILE``);
- the session (``--session FILE``, ``--new-session``);
- OpenIGTLink (``--igtl``, ``--igtl-port``, ``--igtl-commands``, ``--igtl-allow-remote``);
- the run time (``--duration``).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from icenav.io.igtl import IgtlBridge, IgtlConfig
    from icenav.io.igtl_stream import CommandForwarder

__all__ = [
    "IGTL_COMMAND_NAMES",
    "TRACKERS",
    "VESSELS",
    "add_calibration_option",
    "add_hardware_options",
    "add_igtl_options",
    "add_session_options",
    "add_twin_options",
    "check_calibration_option",
    "check_duration",
    "check_hardware_options",
    "check_igtl_options",
    "check_port",
    "check_session_options",
    "check_twin_options",
    "default_session_path",
    "igtl_config",
]

VESSELS = ("straight", "moderate", "steep")
"""The twin's vessel curvature conditions."""
TRACKERS = ("sim", "ndi", "none")
"""Trackers of ``--tracker``: the twin's EM tracker (following the drives), an NDI Aurora,
or none."""
IGTL_COMMAND_NAMES = ("stop", "save_view", "go_to_view", "refine_view")
"""Commands ``--igtl-commands`` may enable (``icenav.io.igtl.IgtlCommand`` values)."""


def add_twin_options(p: argparse.ArgumentParser, *, robot: bool = True) -> None:
    """``--seed``, ``--vessel``, ``--plant``, ``--plant-family`` (and ``--robot``)."""
    g = p.add_argument_group("digital twin")
    g.add_argument("--seed", type=int, default=100, help="catheter seed of the twin (>= 0)")
    g.add_argument(
        "--vessel",
        choices=VESSELS,
        default="straight",
        help="vessel curvature condition of the twin (default straight)",
    )
    g.add_argument(
        "--plant",
        default=None,
        metavar="MODULE:FACTORY",
        help="a plant plug-in instead of the default twin: factory(seed, vessel) -> "
        "(plant, tracker); MODULE an importable module or a .py file",
    )
    g.add_argument(
        "--plant-family",
        default=None,
        metavar="NAME",
        help="a plant family of the twin (icenav.sim.families: distributed-friction, "
        "rate-dependent, nonlinear-play, out-of-tolerance, field-distortion, 'a+b')",
    )
    if robot:
        g.add_argument(
            "--robot",
            choices=("sim", "emulated-canopen"),
            default="sim",
            help="robot backend of the twin: the simulated robot, or emulated CiA 402 drives "
            "on a virtual CAN bus (the code path of real drives)",
        )


def check_twin_options(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse a negative seed, or both --plant and --plant-family; import the plug-in now
    (so that a wrong spec ends here, naming it) and check the family name."""
    from icenav.errors import IcenavError

    if args.seed < 0:
        parser.error(f"--seed must be >= 0 (an integer), got {args.seed}")
    if args.plant is not None and args.plant_family is not None:
        parser.error("give --plant MODULE:FACTORY or --plant-family NAME, not both")
    if args.plant is not None or args.plant_family is not None:
        if getattr(args, "robot", "sim") != "sim":
            parser.error("--plant and --plant-family run on --robot sim only")
        from icenav.sim.plugins import resolve_factory

        try:
            resolve_factory(args.plant, args.plant_family)
        except IcenavError as exc:
            parser.error(str(exc))


def add_calibration_option(p: argparse.ArgumentParser) -> None:
    """``--calibration CAL.json``: a calibration file to install at start."""
    p.add_argument(
        "--calibration",
        type=Path,
        default=None,
        metavar="CAL.json",
        help="install the compensation of this calibration file at start (as written by "
        "icenav calibrate)",
    )


def check_calibration_option(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse a calibration file that does not exist."""
    _check_file(parser, "--calibration", args.calibration)


def add_hardware_options(p: argparse.ArgumentParser, *, required: bool) -> None:
    """``--robot-config``, ``--tracker``, ``--tracker-config``."""
    g = p.add_argument_group("hardware")
    g.add_argument(
        "--robot-config",
        type=Path,
        default=None,
        required=required,
        metavar="FILE",
        help="robot configuration TOML of the CiA 402 drives (as examples/robot.toml)"
        + ("" if required else "; without it the twin runs"),
    )
    g.add_argument(
        "--tracker",
        choices=TRACKERS,
        default="sim" if required else None,
        help="the tracker: the twin's EM tracker following the drives (sim), an NDI Aurora "
        "(ndi) or none" + (" (default sim)" if required else "; with --robot-config only"),
    )
    g.add_argument(
        "--tracker-config",
        type=Path,
        default=None,
        metavar="FILE",
        help="tracker configuration TOML (as examples/tracker.toml): the NDI port and tool, "
        "the sensor mount sensor2tip, the registration settings",
    )


def _check_file(parser: argparse.ArgumentParser, option: str, path: Path | None) -> None:
    if path is None:
        return
    if not path.exists():
        parser.error(f"{option} {path}: no such file")
    if not path.is_file():
        parser.error(f"{option} {path}: not a regular file")


def check_hardware_options(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse missing configuration files, and tracker options without ``--robot-config``."""
    _check_file(parser, "--robot-config", args.robot_config)
    _check_file(parser, "--tracker-config", args.tracker_config)
    if args.robot_config is None:
        if args.tracker is not None or args.tracker_config is not None:
            parser.error("--tracker and --tracker-config need --robot-config FILE")
        return
    if getattr(args, "robot", "sim") != "sim":
        parser.error("--robot-config and --robot are exclusive: the drives are in the file")
    if getattr(args, "plant", None) is not None or getattr(args, "plant_family", None):
        parser.error("--plant and --plant-family are options of the twin, not of the drives")
    if args.tracker is None:
        args.tracker = "sim"
    if args.tracker == "none" and args.tracker_config is not None:
        parser.error("--tracker-config with --tracker none: there is no tracker to configure")


def default_session_path() -> Path:
    """Where ``icenav demo`` keeps its session without ``--session``:
    ``$XDG_DATA_HOME/icenav/demo.sqlite`` (``~/.local/share/icenav/demo.sqlite`` when
    ``XDG_DATA_HOME`` is unset or not absolute, as the XDG base directory specification
    says)."""
    xdg = os.environ.get("XDG_DATA_HOME", "")
    root = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".local" / "share"
    return root / "icenav" / "demo.sqlite"


def add_session_options(p: argparse.ArgumentParser, *, default_note: str = "") -> None:
    """``--session FILE`` and ``--new-session``."""
    g = p.add_argument_group("session")
    g.add_argument(
        "--session",
        type=Path,
        default=None,
        metavar="FILE",
        help="SQLite session file (roadmap, views, registration, event log), resumed when it "
        "exists" + (f"; {default_note}" if default_note else ""),
    )
    g.add_argument(
        "--new-session",
        action="store_true",
        help="start a new session in --session, which must not exist or be empty (0 bytes)",
    )


def check_session_options(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse ``--new-session`` without a session, and a session path that is a folder."""
    if args.new_session and args.session is None:
        parser.error("--new-session needs --session FILE")
    if args.session is not None and Path(args.session).is_dir():
        parser.error(f"--session {args.session} is a directory, not a session file")


def add_igtl_options(p: argparse.ArgumentParser, *, always_on: bool = False) -> None:
    """``--igtl`` (unless always on), ``--igtl-port``, ``--igtl-commands``,
    ``--igtl-allow-remote``."""
    g = p.add_argument_group("OpenIGTLink (3D Slicer)")
    if not always_on:
        g.add_argument("--igtl", action="store_true", help="stream to 3D Slicer over OpenIGTLink")
    g.add_argument(
        "--igtl-port",
        type=int,
        default=18944,
        help="OpenIGTLink port (default 18944, Slicer's; 0: a free one, printed)",
    )
    g.add_argument(
        "--igtl-commands",
        default="",
        metavar="LIST",
        help="commands Slicer may send, comma-separated from "
        f"{', '.join(IGTL_COMMAND_NAMES)} (default: none, stream only)",
    )
    g.add_argument(
        "--igtl-allow-remote",
        action="store_true",
        help="accept OpenIGTLink clients from other machines (default: this machine only)",
    )


def check_port(parser: argparse.ArgumentParser, option: str, port: int) -> None:
    """Refuse a TCP port outside [0, 65535]."""
    if not 0 <= port <= 65535:
        parser.error(f"{option} must be in [0, 65535], got {port}")


def check_igtl_options(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse a bad port or an unknown command name."""
    check_port(parser, "--igtl-port", args.igtl_port)
    names = [c.strip() for c in args.igtl_commands.split(",") if c.strip()]
    unknown = [c for c in names if c not in IGTL_COMMAND_NAMES]
    if unknown:
        parser.error(
            f"--igtl-commands: unknown command(s) {', '.join(unknown)}; "
            f"allowed: {', '.join(IGTL_COMMAND_NAMES)}"
        )


def igtl_config(args: argparse.Namespace) -> IgtlConfig:
    """The :class:`icenav.io.igtl.IgtlConfig` of the checked options; commands on a bridge
    open to other machines get a fresh random token (printed by the command)."""
    from icenav.io.igtl import IgtlCommand, IgtlConfig

    names = [c.strip() for c in args.igtl_commands.split(",") if c.strip()]
    token = ""
    if args.igtl_allow_remote and names:
        import secrets

        token = secrets.token_urlsafe(16)
    return IgtlConfig(
        port=args.igtl_port,
        local_only=not args.igtl_allow_remote,
        accepted_commands=frozenset(IgtlCommand(n) for n in names),
        token=token,
    )


def open_igtl_bridge(args: argparse.Namespace) -> tuple[IgtlBridge, CommandForwarder]:
    """The OpenIGTLink server of the checked options and its command forwarder (commands and
    disconnects go to the controller once the forwarder is bound to it,
    :func:`icenav.io.igtl_stream.attach_bridge`)."""
    from icenav.io.igtl import IgtlBridge
    from icenav.io.igtl_stream import CommandForwarder

    forwarder = CommandForwarder()
    bridge = IgtlBridge(
        igtl_config(args), on_command=forwarder, on_disconnect=forwarder.disconnected
    )
    return bridge, forwarder


def check_duration(
    parser: argparse.ArgumentParser, seconds: float | None, *, optional: bool
) -> None:
    """Refuse a duration that is not finite and > 0 s (None allowed when ``optional``)."""
    if seconds is None and optional:
        return
    if seconds is None or not (math.isfinite(seconds) and seconds > 0):
        parser.error(f"--duration must be finite and > 0 s, got {seconds}")

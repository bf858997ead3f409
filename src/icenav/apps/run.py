"""``icenav run``: the console on real CiA 402 drives and a tracker (docs/hardware.md).

::

    icenav run --robot-config FILE [--tracker sim|ndi|none] [--tracker-config FILE]
               [--session FILE [--new-session]] [--registration auto|new|session]
               [--igtl [--igtl-port 18944]] [--host 127.0.0.1] [--port 8080]
    icenav run ... --headless [--duration S] [--calibrate KIND]

1. The drives of the robot TOML (``examples/robot.toml``) are started and homed: their
   current position becomes q = 0 (set the catheter to neutral before).
2. The tracker starts: ``ndi`` (an NDI Aurora, port and tool from the tracker TOML,
   ``examples/tracker.toml``), ``sim`` (the twin's EM tracker on a catheter that follows the
   drives: a dry run of the whole chain) or ``none``.
3. The guided registration: the straight catheter is translated and rolled through 36
   states, the sensor read at each, ``tracker2base`` fitted; the residual is shown and the
   registration stored in the session. ``--registration session`` reuses the session's,
   ``new`` always registers, ``auto`` (default) reuses one when the session has one.
4. The console in the browser (calibration through the control core's calibration runner:
   Calibrate in the console), or with ``--headless`` the controller alone (OpenIGTLink with
   ``--igtl``), optionally running one calibration (``--calibrate``) and stopping after
   ``--duration`` seconds.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from icenav.apps import options
from icenav.errors import IcenavError

__all__ = ["main"]

_REGISTRATION = {"auto": None, "new": True, "session": False}


def _parser() -> argparse.ArgumentParser:
    from icenav.calibration.procedures import CALIBRATION_KINDS

    p = argparse.ArgumentParser(
        prog="icenav run",
        description="Open the icenav console on CiA 402 drives and a tracker, with a guided "
        "registration of the tracker to the robot base (docs/hardware.md).",
    )
    options.add_hardware_options(p, required=True)
    options.add_session_options(p)
    options.add_igtl_options(p)
    options.add_calibration_option(p)
    p.add_argument(
        "--registration",
        choices=tuple(_REGISTRATION),
        default="auto",
        help="auto: reuse the session's registration when it has one, else register; new: "
        "always register; session: the session's (an error when it has none)",
    )
    p.add_argument("--host", default="127.0.0.1", help="console address (default 127.0.0.1)")
    p.add_argument(
        "--port", type=int, default=8080, help="console port (default 8080; 0: a free one)"
    )
    p.add_argument(
        "--headless",
        action="store_true",
        help="no browser: run the controller (and --calibrate, --igtl) until --duration, "
        "Ctrl-C or SIGTERM",
    )
    p.add_argument(
        "--duration", type=float, default=None, help="headless: wall-clock seconds to run (> 0)"
    )
    p.add_argument(
        "--calibrate",
        choices=tuple(k for k in CALIBRATION_KINDS if k != "registration"),
        default=None,
        help="headless: run this calibration on the drives (the control core's runner) "
        "and install its compensation",
    )
    g = p.add_argument_group("twin of --tracker sim")
    g.add_argument("--seed", type=int, default=100, help="catheter seed of the twin (>= 0)")
    g.add_argument("--vessel", choices=options.VESSELS, default="straight", help="vessel")
    return p


def check_args(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse every bad option with a message naming it (exit code 2)."""
    options.check_hardware_options(args, parser)
    options.check_session_options(args, parser)
    options.check_igtl_options(args, parser)
    options.check_port(parser, "--port", args.port)
    options.check_duration(parser, args.duration, optional=True)
    options.check_calibration_option(args, parser)
    if args.seed < 0:
        parser.error(f"--seed must be >= 0 (an integer), got {args.seed}")
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        parser.error(f"--host {args.host}: icenav run serves the console on this machine only")
    if not args.headless and (args.duration is not None or args.calibrate is not None):
        parser.error("--duration and --calibrate go with --headless (the console calibrates)")
    if args.calibrate is not None and args.tracker == "none":
        parser.error("--calibrate needs a tracker: --tracker sim or ndi")
    if args.registration == "session" and args.session is None:
        parser.error("--registration session needs --session FILE")


def _calibrate(ctrl: Any, kind: str, stop: threading.Event) -> bool:
    """Run one calibration through the controller (its runner) and wait for its outcome."""
    ticket = ctrl.start_calibration(kind)
    print(f"calibration {kind}: {ctrl.preview_calibration(kind).describe()}", flush=True)
    while not ticket.finished and not stop.is_set():
        stop.wait(0.5)
    if not ticket.finished:
        return False
    result = ticket.final(0)
    print(f"calibration {kind}: {result.outcome.value}: {result.reason}", flush=True)
    return result.outcome.value == "done"


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    check_args(args, parser)
    from icenav.apps.demo import start_new_session
    from icenav.apps.serve import make_session, run_realtime, stop_on_signals

    stop = threading.Event()
    bridge: Any = None
    forwarder: Any = None
    console: Any = None
    failed: list[str] = []
    try:
        with stop_on_signals(stop):
            start_new_session(args)
            if args.igtl:
                bridge, forwarder = options.open_igtl_bridge(args)
            gamepad = None
            if not args.headless:
                from icenav.devices.gamepad import Sdl2Gamepad

                gamepad = Sdl2Gamepad()
            args.image_rate_hz = 20.0
            session = make_session(
                args, gamepad, register=_REGISTRATION[args.registration], stop=stop
            )
            ctrl = session.controller

            def ready() -> None:
                nonlocal console
                if bridge is not None:
                    print(f"OpenIGTLink: 127.0.0.1:{bridge.port} (TipToBase, Image, ...)")
                if args.headless:
                    print("icenav run: headless", flush=True)
                    if args.calibrate and not _calibrate(ctrl, args.calibrate, stop):
                        failed.append(f"calibration {args.calibrate} did not finish")
                    return
                console = _console(ctrl, args, with_anatomy=args.tracker == "sim")
                print(f"icenav console: {console.url}  (Ctrl-C to stop)", flush=True)

            t0 = time.monotonic()
            try:
                code = run_realtime(
                    session,
                    stop,
                    bridge=bridge,
                    forwarder=forwarder,
                    ready=ready,
                    duration_s=args.duration,
                )
            finally:
                if console is not None:
                    console.stop()
                if gamepad is not None:
                    gamepad.close()
            print(f"icenav run: stopped after {time.monotonic() - t0:.1f} s")
    except IcenavError as exc:
        print(f"icenav run: {exc}", file=sys.stderr)
        return 1
    finally:
        if bridge is not None:
            bridge.close()
    for f in failed:
        print(f"FAILED: {f}", file=sys.stderr)
    return 1 if failed else code


def _console(ctrl: Any, args: argparse.Namespace, *, with_anatomy: bool) -> Any:
    from icenav.apps.demo import export_dir_for
    from icenav.console import Console
    from icenav.persistence.dicom import ExportDirectory

    meshes = labels = None
    if with_anatomy:
        from icenav.apps.wiring import anatomy_labels, anatomy_meshes

        meshes, labels = anatomy_meshes(), anatomy_labels()
    args.export_dir = None
    console = Console(
        ctrl,
        host=args.host,
        port=args.port,
        anatomy_mesh=meshes,
        anatomy_labels=labels,
        export_dir=ExportDirectory(export_dir_for(args)),
    )
    console.start()
    return console

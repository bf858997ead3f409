"""``icenav demo``: the operator console on the simulated robot.

::

    icenav demo [--host 127.0.0.1] [--port 8080] [--session FILE [--new-session] | --no-session]
                [--seed N] [--vessel straight|moderate|steep] [--robot sim|emulated-canopen]
                [--plant MODULE:FACTORY | --plant-family NAME] [--calibration CAL.json]
                [--igtl [--igtl-port 18944]] [--export-dir DIR]
    icenav demo --headless --duration S    # scripted operator, no browser; exit 0 if all well

The console binds to 127.0.0.1 unless ``--host`` says otherwise; ``--port 0`` picks a free
port (printed), a port in use is an error naming it. The roadmap, the views and the event
log are kept in an SQLite session file and resumed from it: ``--session FILE``, or by
default ``$XDG_DATA_HOME/icenav/demo.sqlite`` (``~/.local/share/icenav/demo.sqlite``),
printed at start; ``--no-session`` keeps nothing (the headless run keeps nothing without
``--session``). One process writes a session at a time; an empty (0-byte) file becomes a
new session only with ``--new-session``.
The console's Export DICOM button writes into ``--export-dir`` (default: ``exports/`` beside
the session file, or in the current directory without ``--session``), with file names made
by the program.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icenav.apps import options
from icenav.errors import IcenavError

__all__ = ["export_dir_for", "main", "resolve_session", "run_headless", "start_new_session"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav demo",
        description="Start the icenav console on the simulated ICE catheter robot.",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument(
        "--port", type=int, default=8080, help="console port (default 8080; 0: a free one)"
    )
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="required with a --host other than loopback: expose the console on the network",
    )
    options.add_session_options(
        p, default_note="default (console): $XDG_DATA_HOME/icenav/demo.sqlite, printed"
    )
    p.add_argument(
        "--no-session",
        action="store_true",
        help="console: keep nothing (no session file; views are lost on exit)",
    )
    p.add_argument(
        "--export-dir",
        type=Path,
        default=None,
        help="directory of the console's DICOM exports (default: exports/ beside the "
        "session file, or in the current directory)",
    )
    options.add_twin_options(p)
    options.add_calibration_option(p)
    p.add_argument("--headless", action="store_true", help="scripted operator, no browser")
    p.add_argument(
        "--duration",
        type=float,
        default=20.0,
        help="headless: simulated seconds to run (> 0, default 20)",
    )
    options.add_igtl_options(p)
    return p


_LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _check_args(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    if args.host not in _LOOPBACK and not args.allow_remote:  # reliability: part 4 (security)
        parser.error(
            f"--host {args.host} exposes the console beyond this machine: "
            "add --allow-remote to confirm"
        )
    if args.export_dir is not None and args.export_dir.exists() and not args.export_dir.is_dir():
        parser.error(f"--export-dir {args.export_dir} exists and is not a directory")
    if args.no_session and args.session is not None:
        parser.error("--no-session and --session FILE are exclusive")
    options.check_session_options(args, parser)
    options.check_port(parser, "--port", args.port)
    options.check_igtl_options(args, parser)
    options.check_twin_options(args, parser)
    options.check_calibration_option(args, parser)
    if not (math.isfinite(args.duration) and args.duration > 0):
        parser.error(f"--duration must be > 0 s, got {args.duration}")


def resolve_session(args: argparse.Namespace) -> Path | None:
    """The session file of the console: ``--session``, none with ``--no-session`` (or
    headless without ``--session``: the scripted operator keeps nothing), else the default
    :func:`icenav.apps.options.default_session_path` (its folder made)."""
    if args.session is not None:
        return Path(args.session).expanduser()
    if args.no_session or args.headless:
        return None
    path = options.default_session_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def export_dir_for(args: argparse.Namespace) -> Path:
    """The console's export directory: ``--export-dir``, else ``exports/`` beside the
    session file given with ``--session``, else ``exports/`` in the current directory
    (absolute; also with the default session, whose folder a user does not look into)."""
    if args.export_dir is not None:
        return Path(args.export_dir).expanduser().absolute()
    given = args.session is not None and not getattr(args, "session_is_default", False)
    base = Path(args.session).expanduser().parent if given else Path.cwd()
    return base.absolute() / "exports"


def control_token_for(host: str) -> str | None:
    """A fresh random control token when the console is exposed beyond loopback, else None."""
    if host in _LOOPBACK:
        return None
    import secrets

    return secrets.token_urlsafe(16)


def start_new_session(args: argparse.Namespace) -> None:
    """With ``--new-session``, create the session in ``--session`` (which must not exist or
    be empty) before the controller opens it."""
    if args.new_session:
        from icenav.persistence.store import SessionStore

        SessionStore(args.session, new_session=True).close()


def _install_calibration(session: Any, args: argparse.Namespace) -> None:
    """Say what the reopened session re-installed (its calibration in use), then install
    ``--calibration`` (if given) on the session's controller, store it as the session's
    calibration in use and say so; a file that cannot be installed closes the session and
    raises."""
    if session.resumed_calibration is not None:
        print(session.resumed_calibration)
    if args.calibration is None:
        return
    from icenav.apps.wiring import install_calibration

    try:
        print(install_calibration(session.controller, args.calibration, session.store))
    except BaseException:
        session.close()
        raise


def run_headless(args: argparse.Namespace) -> int:
    """A scripted operator: drive, save two views, wander, return to each, spin; check it."""
    from icenav.apps.wiring import make_sim_controller
    from icenav.control.state import ControllerState, Mode
    from icenav.control.teleop import JoystickMapping
    from icenav.devices.gamepad import Keyframe, ScriptedInput

    sim_t = [0.0]

    def clock() -> float:
        return sim_t[0]

    m = JoystickMapping()
    en = m.enable_button
    script = ScriptedInput(
        [
            Keyframe(0.0, (0.3, -0.6, 0.0, 0.0, 0.2), (en,)),
            Keyframe(1.5, (), ()),
            Keyframe(1.7, (), (m.save_view_button,)),
            Keyframe(1.8, (), ()),
            Keyframe(2.0, (-0.5, 0.2, 0.0, 0.4, -0.3), (en,)),
            Keyframe(3.5, (), ()),
            Keyframe(3.7, (), (m.save_view_button,)),
            Keyframe(3.8, (), ()),
            Keyframe(4.0, (0.6, 0.5, 0.0, -0.5, 0.0), (en,)),
            Keyframe(5.5, (), ()),
        ],
        clock=clock,
    )
    from icenav.control.controller import ControllerConfig

    session = make_sim_controller(
        seed=args.seed,
        vessel=args.vessel,
        session=args.session,
        robot=args.robot,
        plant=args.plant,
        plant_family=args.plant_family,
        input_source=script,
        clock=clock,
        config=ControllerConfig(image_rate_hz=2.0),  # faster than real time: fewer images
    )
    ctrl = session.controller
    _install_calibration(session, args)
    dt = ctrl.config.dt
    failures: list[str] = []
    # the simulated robot runs faster than real time; emulated drives move in real time
    realtime = args.robot != "sim"
    wall0 = time.perf_counter()
    tolerance = 1e-6 if not realtime else 2e-3  # rad/mm: exact, or encoder-limited

    def step() -> ControllerState:
        sim_t[0] += dt
        if realtime:
            ahead = sim_t[0] - (time.perf_counter() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        state = ctrl.step()
        if state.mode in (Mode.FAULT, Mode.ESTOP):
            failures.append(f"t={state.time:.2f} s: {state.mode.value}: {state.message}")
        return state

    def run(seconds: float) -> None:
        for _ in range(int(round(seconds / dt))):
            if step().mode in (Mode.FAULT, Mode.ESTOP):
                return

    def until_idle(max_s: float) -> ControllerState:
        state = step()
        for _ in range(int(max_s / dt)):
            if state.mode is Mode.IDLE and state.progress is None:
                break
            state = step()
        run(0.3)  # let the drives settle on the last set-point
        return ctrl.snapshot()

    try:
        print(f"icenav demo (headless): catheter seed {args.seed}, {args.vessel} vessel")
        run(6.0)
        names = [v.name for v in ctrl.snapshot().views]
        print(f"  operator drove {ctrl.roadmap.n_vertices} roadmap states, saved views {names}")
        if len(names) < 2:
            failures.append(f"expected 2 saved views, got {names}")
        for name in names[:2]:
            ctrl.goto_view(name)
            state = until_idle(60.0)
            err = float(np.max(np.abs(state.q_motor - ctrl.views.get(name).q)))
            print(f"  returned to {name!r}: max joint error {err:.2e} ({state.message})")
            if err > tolerance:
                failures.append(f"return to {name!r} ended {err:.3g} from the view")
        ctrl.start_spin()
        state = until_idle(200.0)
        print(f"  spin: {state.message}")
        remaining = args.duration - sim_t[0]
        if remaining > 0:
            run(remaining)
        image = ctrl.latest_image()
        if image is None:
            failures.append("no ICE image was rendered")
        else:
            print(f"  live image {image.pixels.shape}, mean grey {image.pixels.mean():.0f}")
    finally:
        session.close()
    if failures:
        for f in failures:
            print(f"FAILED: {f}", file=sys.stderr)
        return 1
    print("headless demo: all went well")
    return 0


def run_console(args: argparse.Namespace) -> int:
    """The console in the browser on the real-time controller; Ctrl-C to stop."""
    from icenav.apps.wiring import anatomy_labels, anatomy_meshes, make_sim_controller
    from icenav.console import Console
    from icenav.devices.gamepad import Sdl2Gamepad
    from icenav.persistence.dicom import ExportDirectory

    bridge = streamer = forwarder = None
    if args.igtl:
        bridge, forwarder = options.open_igtl_bridge(args)
    gamepad = Sdl2Gamepad()
    session = make_sim_controller(
        seed=args.seed,
        vessel=args.vessel,
        session=args.session,
        input_source=gamepad,
        robot=args.robot,
        plant=args.plant,
        plant_family=args.plant_family,
    )
    ctrl = session.controller
    if args.session is not None:
        print(f"session: {args.session} (views and roadmap kept; --session FILE for another)")
    _install_calibration(session, args)
    if bridge is not None:
        from icenav.io.igtl_stream import attach_bridge

        streamer = attach_bridge(ctrl, bridge, forwarder)
        print(f"OpenIGTLink: 127.0.0.1:{bridge.port} (TipToBase, SensorToTracker, Image)")
    token = control_token_for(args.host)  # reliability: part 4 (security)
    exports = ExportDirectory(export_dir_for(args))
    console = Console(
        ctrl,
        host=args.host,
        port=args.port,
        anatomy_mesh=anatomy_meshes(),
        anatomy_labels=anatomy_labels(),
        # the twin's heart gives the ECG strip its phase (on hardware: an ECG input)
        cardiac_phase=None if session.renderer is None else session.renderer.phantom.cardiac_phase,
        control_token=token,
        export_dir=exports,
    )
    print(f"DICOM exports (Export DICOM in the views panel) go to {exports.root}")
    if token is not None:
        print(f"control token (enter it in the console to take control): {token}", flush=True)
    stop = threading.Event()
    try:
        console.start()  # first: a console port in use ends here, before the robot runs
        ctrl.start()
        # SIGTERM (a service manager, `kill`) ends the console as cleanly as Ctrl-C;
        # installed before the URL is printed, so whoever reads the URL may stop it at once
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
        print(f"icenav console: {console.url}  (Ctrl-C to stop)", flush=True)
        while not stop.is_set():
            time.sleep(0.2)
    except KeyboardInterrupt:
        print("\nstopping")
    finally:
        console.stop()
        if streamer is not None:
            streamer.stop()
        session.close()
        gamepad.close()
        if bridge is not None:
            bridge.close()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    _check_args(args, parser)
    try:
        args.session_is_default = args.session is None and not args.headless
        args.session = resolve_session(args)
        start_new_session(args)
        return run_headless(args) if args.headless else run_console(args)
    except IcenavError as exc:
        print(f"icenav demo: {exc}", file=sys.stderr)
        return 1

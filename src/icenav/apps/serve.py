"""``icenav serve``: the controller in real time without a browser, streaming to 3D Slicer.

::

    icenav serve [--robot sim|emulated-canopen] [--seed N] [--vessel V]
                 [--plant MODULE:FACTORY | --plant-family NAME]       # the twin (default)
    icenav serve --robot-config FILE [--tracker sim|ndi|none] [--tracker-config FILE]
                                                                      # the drives
                 [--session FILE [--new-session]] [--igtl-port 18944] [--igtl-commands LIST]
                 [--duration S] [--no-gamepad]

It runs the control loop at its rate (100 Hz) and the ICE imager in real time, streams
``TipToBase``, ``SensorToTracker``, ``Image`` and ``IcenavStatus`` over OpenIGTLink to every
connected client (docs/slicer.md), reads the gamepad when one is plugged in (plugging one in
later is picked up), and runs until Ctrl-C, SIGTERM or ``--duration`` seconds of wall-clock
time. It prints where it streams before it starts. Exit code 0 when it ended as asked, 1
when the controller ended in FAULT or an error stopped it, 2 for bad options.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from icenav.apps import options
from icenav.errors import IcenavError

__all__ = ["main", "make_session", "run_realtime", "stop_on_signals"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav serve",
        description="Run the controller in real time without a browser and stream the "
        "catheter pose and the ICE image to 3D Slicer over OpenIGTLink, until Ctrl-C, "
        "SIGTERM or --duration seconds.",
    )
    options.add_twin_options(p)
    options.add_hardware_options(p, required=False)
    options.add_session_options(p)
    options.add_igtl_options(p, always_on=True)
    options.add_calibration_option(p)
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="stop after this many seconds of wall-clock time (> 0; default: run until "
        "Ctrl-C or SIGTERM)",
    )
    p.add_argument(
        "--image-rate-hz",
        type=float,
        default=20.0,
        help="ICE images rendered per second by the twin (default 20; 1 to 60)",
    )
    p.add_argument(
        "--no-gamepad", action="store_true", help="do not look for a gamepad (SDL2) at all"
    )
    return p


def check_args(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """Refuse every bad option with a message naming it (exit code 2)."""
    options.check_hardware_options(args, parser)
    if args.robot_config is None:
        options.check_twin_options(args, parser)
    options.check_session_options(args, parser)
    options.check_igtl_options(args, parser)
    options.check_duration(parser, args.duration, optional=True)
    options.check_calibration_option(args, parser)
    rate = args.image_rate_hz
    if not (1.0 <= rate <= 60.0):
        parser.error(f"--image-rate-hz must be in [1, 60] Hz, got {rate}")


def make_session(
    args: argparse.Namespace,
    input_source: Any,
    *,
    register: bool | None = None,
    report: Callable[[str], None] = print,
    stop: threading.Event | None = None,
) -> Any:
    """The controller the checked options ask for: the drives of ``--robot-config`` with
    their tracker (:func:`icenav.apps.hardware.make_hardware_controller`), else the twin
    (:func:`icenav.apps.wiring.make_sim_controller`); a :class:`~icenav.apps.wiring.SimSession`."""
    from icenav.control.controller import ControllerConfig

    config = ControllerConfig(image_rate_hz=getattr(args, "image_rate_hz", 20.0))
    session = _make_session(args, input_source, config, register, report, stop)
    if session.resumed_calibration is not None:
        report(session.resumed_calibration)
    if getattr(args, "calibration", None) is not None:
        from icenav.apps.wiring import install_calibration

        try:
            report(install_calibration(session.controller, args.calibration, session.store))
        except BaseException:
            session.close()
            raise
    return session


def _make_session(
    args: argparse.Namespace,
    input_source: Any,
    config: Any,
    register: bool | None,
    report: Callable[[str], None],
    stop: threading.Event | None,
) -> Any:
    if args.robot_config is not None:
        from icenav.apps.hardware import load_tracker_config, make_hardware_controller

        return make_hardware_controller(
            args.robot_config,
            tracker=args.tracker,
            tracker_settings=load_tracker_config(args.tracker_config),
            session=args.session,
            input_source=input_source,
            config=config,
            seed=args.seed,
            vessel=args.vessel,
            register=register,
            report=report,
            stop=stop,
        )
    from icenav.apps.wiring import make_sim_controller

    return make_sim_controller(
        seed=args.seed,
        vessel=args.vessel,
        session=args.session,
        config=config,
        input_source=input_source,
        robot=args.robot,
        plant=args.plant,
        plant_family=args.plant_family,
    )


@contextlib.contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """SIGTERM and SIGINT set ``stop`` inside the block (then the previous handlers are back).
    Only the main thread may install handlers; elsewhere (a test's thread) nothing is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    for s in previous:
        signal.signal(s, lambda *_: stop.set())
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def run_realtime(
    session: Any,
    stop: threading.Event,
    *,
    bridge: Any = None,
    forwarder: Any = None,
    duration_s: float | None = None,
    ready: Callable[[], None] | None = None,
) -> int:
    """Run ``session``'s controller in real time (its loop thread, the imager) with the
    OpenIGTLink streamer on ``bridge`` until ``stop`` is set or ``duration_s`` of wall-clock
    time has passed; close everything. 0 when the controller did not end in FAULT."""
    from icenav.control.state import Mode

    ctrl = session.controller
    streamer = None
    code = 0
    try:
        ctrl.start()
        if bridge is not None:
            from icenav.io.igtl_stream import attach_bridge

            streamer = attach_bridge(ctrl, bridge, forwarder)
        if ready is not None:
            ready()
        deadline = None if duration_s is None else time.monotonic() + duration_s
        while not stop.is_set():
            left = 0.5 if deadline is None else min(0.5, deadline - time.monotonic())
            if left <= 0:
                break
            stop.wait(left)
        state = ctrl.snapshot()
        if state.mode is Mode.FAULT:
            print(f"the controller is in FAULT: {state.message}", file=sys.stderr)
            code = 1
    finally:
        if streamer is not None:
            streamer.stop()
            print(f"sent {streamer.sent_poses} poses and {streamer.sent_images} images")
        session.close()
    return code


def _describe(args: argparse.Namespace) -> str:
    """What runs, for the operator."""
    if args.robot_config is not None:
        return f"the drives of {args.robot_config}, tracker {args.tracker}"
    text = f"the twin (catheter seed {args.seed}, {args.vessel} vessel"
    if args.plant is not None or args.plant_family is not None:
        text += f", plant {args.plant or args.plant_family}"
    if args.robot != "sim":
        text += ", emulated CiA 402 drives"
    return text + ")"


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    check_args(args, parser)
    from icenav.apps.demo import start_new_session

    stop = threading.Event()
    gamepad: Any = None
    pad = ""
    bridge: Any = None
    try:
        with stop_on_signals(stop):
            start_new_session(args)
            bridge, forwarder = options.open_igtl_bridge(args)
            config = bridge.config
            if not args.no_gamepad:
                from icenav.devices.gamepad import Sdl2Gamepad

                gamepad = Sdl2Gamepad()
                # polled here, before the control loop reads it from its own thread
                pad = "connected" if gamepad.poll().connected else "none yet"
            session = make_session(args, gamepad, stop=stop)
            what = _describe(args)

            def ready() -> None:
                host = "127.0.0.1" if config.local_only else config.bind_address
                print(
                    f"icenav serve: {what}; OpenIGTLink on {host}:{bridge.port} "
                    "(TipToBase, SensorToTracker, Image, IcenavStatus)",
                    flush=True,
                )
                if config.accepted_commands:
                    names = sorted(c.value for c in config.accepted_commands)
                    print(f"  commands accepted on IcenavCommand: {', '.join(names)}")
                if config.token:
                    print(f"  command token: {config.token}")
                if gamepad is not None:
                    print(f"  gamepad: {pad} (plugging one in later is picked up)")
                until = f"for {args.duration:g} s" if args.duration else "until Ctrl-C or SIGTERM"
                print(f"  running {until}", flush=True)

            code = run_realtime(
                session,
                stop,
                bridge=bridge,
                forwarder=forwarder,
                duration_s=args.duration,
                ready=ready,
            )
    except IcenavError as exc:
        print(f"icenav serve: {exc}", file=sys.stderr)
        return 1
    finally:
        if bridge is not None:
            bridge.close()
        if gamepad is not None:
            gamepad.close()
    print("icenav serve: stopped")
    return code

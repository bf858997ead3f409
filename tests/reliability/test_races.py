"""The control core under interleavings: e-stops injected at every point where a task, a
reset or a mode request can be pre-empted, and e-stops from another thread every 0-2 ms
while short go-to-view tasks start and end (tests/support/races.py says what is checked)."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.control.controller import Controller
from icenav.control.modes import Mode
from icenav.devices.robot import RobotStatus
from tests.support.races import EventLog, drive_away_and_save, make_controller, run_random


class Injector:
    """Calls ``ctrl.estop`` (as another thread would, arriving exactly there) at the
    ``target``-th hook point reached; records the points seen."""

    def __init__(self, target: int) -> None:
        self.target = target
        self.seen: list[str] = []
        self.ctrl = None
        self.log: EventLog | None = None
        self.fired_at = ""

    def __call__(self, point: str) -> None:
        self.seen.append(point)
        if len(self.seen) - 1 == self.target and self.ctrl is not None:
            self.fired_at = point
            self.ctrl.estop("injector")
            assert self.log is not None
            self.log.add("estop_returned")


def _scenario(target: int, kind: str) -> tuple[Injector, object, EventLog]:
    log = EventLog()
    inj = Injector(-1)
    ctrl = make_controller(log, inj)
    drive_away_and_save(ctrl)
    for _ in range(20):
        ctrl.step()
    inj.seen.clear()
    inj.ctrl, inj.log, inj.target = ctrl, log, target
    if kind == "goto":  # a go to view, from its start to its end
        ctrl.goto_view("a")
    elif kind == "reset":  # a reset under way (after an e-stop that came before it)
        ctrl.estop("first")
        log.add("estop_returned")
        inj.seen.clear()
        ctrl.reset_fault()
    elif kind == "mode":  # a mode request while a go to view runs
        ctrl.goto_view("a")
        ctrl.step()
        inj.seen.clear()
        ctrl.request_mode(Mode.KNOB)
    for _ in range(60):
        ctrl.step()
    return inj, ctrl, log


@pytest.mark.parametrize("kind", ["goto", "reset", "mode"])
def test_an_estop_at_every_preemption_point_stops_for_good_and_a_reset_works(kind: str) -> None:
    probe, _, _ = _scenario(-1, kind)  # where can it be pre-empted? every hook point seen
    points = len(probe.seen)
    assert points > 10
    for target in range(points):
        inj, ctrl, log = _scenario(target, kind)
        assert inj.fired_at, (kind, target)
        where = f"{kind}: e-stop at point {target} ({inj.fired_at})"
        at_stop = ctrl.robot.read_state().q.copy()
        for _ in range(5):  # (and the snapshot, published every 5th cycle, is current)
            ctrl.step()
            np.testing.assert_array_equal(ctrl.robot.read_state().q, at_stop, err_msg=where)
        state = ctrl.snapshot()
        assert state.mode is Mode.ESTOP, where
        assert ctrl.robot.status is RobotStatus.ESTOP, where
        assert "controller error" not in state.message, where  # no cycle raised
        assert "EMERGENCY STOP by injector" in state.message, where
        assert log.violations() == 0, where  # nothing moved after the e-stop returned
        assert ctrl.task is None, where
        ticket = ctrl.reset_fault()  # asked after the e-stop: it takes effect
        ctrl.step()
        assert ticket.final(timeout=0).outcome.value == "done", (where, ticket)
        assert ctrl.mode is Mode.IDLE and ctrl.robot.status is RobotStatus.ENABLED, where


def test_a_reset_asked_before_an_estop_never_clears_it() -> None:
    log = EventLog()
    ctrl = make_controller(log)
    ctrl.estop("first")
    reset = ctrl.reset_fault()  # queued ...
    ctrl.estop("second")  # ... and an e-stop comes before the loop runs it
    ctrl.run_cycles(5)  # (the snapshot is published every 5th cycle)
    result = reset.final(timeout=0)
    assert result.outcome.value == "refused" and "an e-stop came after" in result.reason
    assert ctrl.mode is Mode.ESTOP and "second" in ctrl.snapshot().message
    again = ctrl.reset_fault()
    ctrl.run_cycles(5)
    assert again.final(timeout=0).outcome.value == "done" and ctrl.mode is Mode.IDLE


def test_an_estop_between_the_robots_reset_and_enable_refuses_the_reset() -> None:
    """An e-stop that lands after the robot was reset but before it was enabled (its first
    step takes no lock): the reset lost the race and says so; it is not a failed reset."""
    log = EventLog()
    box: dict[str, object] = {}

    def hook(point: str) -> None:
        if point == "reset_fault.after" and box.pop("armed", False):
            ctrl_ = box["ctrl"]
            assert isinstance(ctrl_, Controller)
            ctrl_.estop("late")

    ctrl = make_controller(log, hook)
    box["ctrl"] = ctrl
    ctrl.estop("first")
    box["armed"] = True
    reset = ctrl.reset_fault()
    ctrl.run_cycles(5)
    result = reset.final(timeout=0)
    assert result.outcome.value == "refused" and "an e-stop came after" in result.reason
    assert ctrl.mode is Mode.ESTOP and ctrl.robot.status is RobotStatus.ESTOP
    assert "late" in ctrl.snapshot().message
    again = ctrl.reset_fault()
    ctrl.run_cycles(5)
    assert again.final(timeout=0).outcome.value == "done" and ctrl.mode is Mode.IDLE


def test_a_request_in_estop_is_refused_and_never_applied_later() -> None:
    log = EventLog()
    ctrl = make_controller(log)
    drive_away_and_save(ctrl)
    ctrl.estop("operator")
    goto = ctrl.goto_view("a")
    mode = ctrl.request_mode(Mode.KNOB)
    ctrl.run_cycles(5)
    for t in (goto, mode):
        r = t.final(timeout=0)
        assert r.outcome.value == "refused" and "ESTOP" in r.reason
    assert "EMERGENCY STOP by operator" in ctrl.snapshot().message  # the cause is kept
    ctrl.reset_fault()
    ctrl.step()
    for _ in range(30):  # nothing refused runs after the reset
        ctrl.step()
        assert ctrl.mode is Mode.IDLE and ctrl.task is None


def test_random_estops_while_go_to_view_tasks_start_and_end() -> None:
    """100,000 cycles (``make bench`` runs 1,000,000: benchmarks/bench_races.py)."""
    log = EventLog()
    ctrl = make_controller(log)
    drive_away_and_save(ctrl)
    report = run_random(ctrl, log, 100_000, seed=7)
    print(report)
    assert report.cycles == 100_000 and report.cycle_gaps == 0
    assert report.deaths == 0 and report.violations == 0
    assert report.estops > 200 and report.gotos_started > 20  # the harness did meet the loop
    assert report.resets_done > 20 and report.resets_other == []
    assert report.final_mode == "idle"


# --- the same with devices that raise ---------------------------------------------------


def test_random_estops_with_a_can_adapter_that_raises_mid_move() -> None:
    """Emulated CiA 402 drives on python-can's virtual bus; the adapter raises
    ``can.CanOperationError`` on 2 % of its sends (mid-move): each ends in FAULT with the
    robot quick-stopped and the text shown, the loop goes on, resets work."""
    import random

    import can

    from icenav.control.config import ControllerConfig
    from icenav.control.controller import Controller
    from icenav.devices.canopen.emulated_drive import open_emulated_robot

    robot, drives = open_emulated_robot()
    try:
        robot.home()
        log = EventLog()
        send = robot.network.send_message
        rng = random.Random(3)
        broken = [False]

        def flaky(*args: object, **kwargs: object) -> None:
            if broken[0] and rng.random() < 0.02:
                raise can.CanOperationError("adapter vanished (injected)")
            send(*args, **kwargs)  # type: ignore[arg-type]

        robot.network.send_message = flaky  # type: ignore[method-assign]
        command = robot.command_position

        def logged(q: object) -> None:
            command(q)  # type: ignore[arg-type]
            log.add("command")

        robot.command_position = logged  # type: ignore[method-assign]
        reset = robot.reset_fault

        def logged_reset() -> None:
            reset()
            log.add("robot_reset")

        robot.reset_fault = logged_reset  # type: ignore[method-assign]
        ctrl: Controller

        def clock() -> float:
            return ctrl.time

        ctrl = Controller(robot, ControllerConfig(rate_hz=500.0, publish_every=5), clock=clock)
        drive_away_and_save(ctrl)
        broken[0] = True
        report = run_random(
            ctrl, log, 3000, seed=11, expected_faults=lambda t: "CanOperationError" in t
        )
        broken[0] = False
        print(report)
        assert report.cycle_gaps == 0 and report.deaths == 0 and report.violations == 0
        assert report.estops > 5 and report.injected_faults > 0
        assert all("injected" in r or "still ESTOP" in r for r in report.resets_other)
        if ctrl.machine.halted:  # the adapter is back: a reset takes effect
            ctrl.reset_fault()
            ctrl.run_cycles(3)
        assert ctrl.mode is Mode.IDLE
    finally:
        robot.close()
        drives.close()


@pytest.mark.parametrize("device", ["tracker", "imager"])
def test_random_estops_with_a_tracker_or_an_imager_that_raises(device: str) -> None:
    """On the twin: closed-loop spins read the tracker in the control path (a tracker that
    raises ends the cycle in FAULT, reset works), the display reads it and the imager renders
    each cycle's image (their errors are reported, never a fault)."""
    import random

    from icenav.apps.wiring import make_sim_controller
    from icenav.control.config import ControllerConfig

    t = [0.0]
    session = make_sim_controller(
        seed=101,
        imaging=device == "imager",
        config=ControllerConfig(rate_hz=500.0, publish_every=5, image_rate_hz=250.0),
        clock=lambda: t[0],
    )
    ctrl = session.controller
    rng = random.Random(5)
    try:
        log = EventLog()
        if device == "tracker":
            tracker = session.tracker
            get_frame = tracker.get_frame

            def flaky_frame() -> object:
                if rng.random() < 0.05:
                    raise RuntimeError("tracker driver crashed (injected)")
                return get_frame()

            tracker.get_frame = flaky_frame
        else:
            render = ctrl.publisher._imager  # noqa: SLF001 - the imager itself

            def flaky_imager(*args: object) -> object:
                if rng.random() < 0.3:
                    raise RuntimeError("renderer crashed (injected)")
                return render(*args)  # type: ignore[misc]

            ctrl.publisher._imager = flaky_imager  # noqa: SLF001
        for _ in range(60):  # bend: a spin needs a bend
            ctrl.jog([0.8, 0.0, 0.0, 0.0], "knob")
            t[0] += ctrl.config.dt
            ctrl.step()

        def tick() -> None:
            t[0] += ctrl.config.dt

        report = run_random(
            ctrl,
            log,
            3000,
            seed=13,
            tick=tick,
            task="spin",
            expected_faults=lambda text: "injected" in text,
        )
        print(report)
        assert report.cycle_gaps == 0 and report.deaths == 0 and report.violations == 0
        assert report.estops > 5 and report.final_mode == "idle"
        if device == "imager":
            assert report.injected_faults == 0  # the imager is not in the control path
            assert ctrl.latest_image() is not None
    finally:
        session.close()

"""Fault injection: drive faults, heartbeat loss, following error, tracker dropout, stale or
NaN gamepad input, clients that vanish or fight for control, a full or read-only store.

For each fault the invariants are the same: the robot ends stopped or in the commanded
state (never moving unasked), the operator sees a clear message in ``ControllerState``, and
what was recorded stays readable.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from icenav.apps.wiring import make_sim_controller
from icenav.control.controller import Controller, ControllerConfig
from icenav.control.state import Mode
from icenav.control.teleop import JoystickMapping
from icenav.devices.gamepad import JoystickSample
from icenav.devices.robot import RobotStatus
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.persistence.store import SessionStore
from tests.support.clock import Clock

M = JoystickMapping()


class Pad:
    """A gamepad whose next sample the test sets directly (axes, buttons, age, connected)."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.axes: tuple[float, ...] = (0.0,) * 6
        self.buttons: tuple[bool, ...] = (False,) * 12
        self.age_s = 0.0
        self.connected = True

    def hold(self, axes: tuple[float, ...], enable: bool = True) -> None:
        self.axes = axes + (0.0,) * (6 - len(axes))
        b = [False] * 12
        b[M.enable_button] = enable
        self.buttons = tuple(b)

    def release(self) -> None:
        self.hold((), enable=False)

    def poll(self) -> JoystickSample:
        if not self.connected:
            return JoystickSample((), (), self.clock(), connected=False)
        return JoystickSample(self.axes, self.buttons, self.clock() - self.age_s)

    def close(self) -> None:
        pass


@dataclass
class Rig:
    ctrl: Controller
    robot: SimulatedRobot
    clock: Clock
    pad: Pad

    def run(self, cycles: int) -> list[np.ndarray]:
        """Step ``cycles`` times; return the measured q of each cycle."""
        out = []
        for _ in range(cycles):
            self.clock.t += self.ctrl.config.dt
            out.append(self.ctrl.step().q_motor.copy())
        return out


def make_rig() -> Rig:
    clock = Clock()
    pad = Pad(clock)
    robot = SimulatedRobot(IdealPlant(), clock=clock)
    ctrl = Controller(robot, ControllerConfig(), input_source=pad, clock=clock)
    return Rig(ctrl, robot, clock, pad)


def still(qs: list[np.ndarray]) -> bool:
    """No joint moved over these cycles."""
    return bool(np.all(np.ptp(np.asarray(qs), axis=0) == 0.0))


# ------------------------------------------------------------------ simulated drives


def test_drive_fault_mid_move_stops_and_needs_a_reset() -> None:
    rig = make_rig()
    rig.pad.hold((0.5, -0.8, 0.0, 0.3, 0.4))
    moving = rig.run(30)
    assert not still(moving)
    rig.robot.inject_fault("drive 2 overcurrent")
    after = rig.run(50)  # the stick is still held: nothing may move
    state = rig.ctrl.snapshot()
    assert state.mode is Mode.FAULT
    assert "drive 2 overcurrent" in state.message and "reset" in state.message
    assert still(after)
    # a reset holds position; the held stick moves only after a fresh dead-man press cycle
    rig.pad.release()
    rig.run(1)  # the dead-man button let go: the gamepad gives control back
    rig.ctrl.reset_fault("operator")
    held = rig.run(20)
    assert rig.ctrl.mode is Mode.IDLE and still(held)
    np.testing.assert_array_equal(held[-1], after[-1])


def test_fault_during_go_to_view_drops_the_motion_for_good() -> None:
    rig = make_rig()
    rig.ctrl.save_view("start")
    rig.pad.hold((0.0, -1.0, 0.0, 0.0, 0.5))
    rig.run(100)
    rig.pad.release()
    rig.run(2)
    rig.ctrl.goto_view("start")
    rig.run(5)
    assert rig.ctrl.mode is Mode.GOTO_VIEW
    rig.robot.inject_fault("following error on phi2")
    frozen = rig.run(30)
    assert rig.ctrl.mode is Mode.FAULT and still(frozen)
    rig.ctrl.reset_fault()  # the script started the return: it holds control
    resumed = rig.run(100)
    assert rig.ctrl.mode is Mode.IDLE and still(resumed)  # the return is not resumed
    assert rig.ctrl.snapshot().progress is None


@pytest.mark.parametrize("where", ["idle", "knob", "goto"])
def test_estop_from_another_thread_stops_at_once(where: str) -> None:
    rig = make_rig()
    rig.ctrl.save_view("a")
    rig.pad.hold((0.7, 0.7, 0.0, 0.7, 0.7))
    rig.run(50 if where != "idle" else 0)
    if where == "goto":
        rig.pad.release()
        rig.run(2)
        rig.ctrl.goto_view("a")
        rig.run(5)
        assert rig.ctrl.mode is Mode.GOTO_VIEW
    t = threading.Thread(target=rig.ctrl.estop, args=("console",))
    t.start()
    t.join()
    after = rig.run(40)
    assert still(after) and rig.ctrl.mode is Mode.ESTOP
    assert rig.robot.status is RobotStatus.ESTOP
    assert "EMERGENCY STOP by console" in rig.ctrl.snapshot().message


# ------------------------------------------------------------------ gamepad input


def test_stale_gamepad_input_stops_motion_with_a_message() -> None:
    rig = make_rig()
    rig.pad.hold((0.0, 1.0, 0.0, 0.0, 0.0))
    assert not still(rig.run(20))
    rig.pad.age_s = rig.ctrl.config.watchdog_s * 1.5  # the pad thread froze
    frozen = rig.run(40)
    assert still(frozen[1:])
    assert "stale" in rig.ctrl.snapshot().message


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_gamepad_axes_never_move_the_robot(bad: float) -> None:
    rig = make_rig()
    rig.pad.hold((bad, bad, bad, bad, bad))
    qs = rig.run(50)
    assert still(qs)
    assert np.all(np.isfinite(qs))
    assert "not finite" in rig.ctrl.snapshot().message
    # one bad axis among good ones: the whole sample is refused, not half-applied
    rig.pad.hold((0.0, 1.0, 0.0, bad, 0.0))
    assert still(rig.run(30))


def test_gamepad_unplugged_mid_move_stops() -> None:
    rig = make_rig()
    rig.pad.hold((0.0, 0.0, 0.0, 1.0, 0.0))
    assert not still(rig.run(20))
    rig.pad.connected = False
    assert still(rig.run(40)[1:])


def test_huge_axis_values_are_held_to_the_velocity_limit() -> None:
    rig = make_rig()
    rig.pad.hold((1e9, -1e9, 0.0, 1e9, 1e9))
    qs = np.asarray(rig.run(50))
    step = np.max(np.abs(np.diff(qs, axis=0)), axis=0)
    vmax_step = np.asarray(rig.ctrl.config.max_velocity) * rig.ctrl.config.dt
    assert np.all(step <= vmax_step * (1 + 1e-9))


# ------------------------------------------------------------------ console clients


def test_client_disconnect_mid_jog_releases_control_and_stops() -> None:
    # what Console._on_disconnect does: release the control the browser held
    rig = make_rig()
    rig.pad.release()
    assert rig.ctrl.acquire_control("browser-1")
    rig.ctrl.jog([0.2, 0.0, 0.0, 0.0], "knob", client="browser-1")
    assert not still(rig.run(5))
    rig.ctrl.release_control("browser-1")
    assert still(rig.run(20)[1:])
    assert rig.ctrl.snapshot().control_owner is None


def test_client_that_vanishes_without_a_goodbye_is_stopped_by_the_watchdog() -> None:
    rig = make_rig()
    rig.pad.release()
    assert rig.ctrl.acquire_control("browser-1")
    rig.ctrl.jog([0.0, 0.3, 0.0, 1.0], "knob", client="browser-1")
    qs = rig.run(100)
    n_moving = int(np.count_nonzero(np.any(np.diff(np.asarray(qs), axis=0) != 0, axis=1)))
    # it moves for one watchdog period (the jog is not repeated), then holds
    assert n_moving == pytest.approx(rig.ctrl.config.watchdog_s * rig.ctrl.config.rate_hz, abs=2)
    assert still(qs[-50:])


def test_two_clients_commanding_at_once_only_the_owner_moves() -> None:
    rig = make_rig()
    rig.pad.release()
    assert rig.ctrl.acquire_control("browser-a")
    assert not rig.ctrl.acquire_control("browser-b")
    barrier = threading.Barrier(2)

    def spam(client: str, v: list[float]) -> None:
        barrier.wait()
        for _ in range(200):
            rig.ctrl.jog(v, "knob", client=client)

    threads = [
        threading.Thread(target=spam, args=("browser-a", [0.0, 0.0, 0.0, 2.0])),
        threading.Thread(target=spam, args=("browser-b", [0.0, 0.0, 0.0, -2.0])),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    qs = np.asarray(rig.run(10))
    assert np.all(np.diff(qs[:, 3]) >= 0.0) and qs[-1, 3] > 0  # only browser-a's direction
    assert "browser-b asked to jog but browser-a holds control" in rig.ctrl.snapshot().message
    # the gamepad always wins, and a browser cannot take it back while the dead-man is held
    rig.pad.hold((0.0, 0.0, 0.0, 0.0, 0.0))
    rig.run(1)
    assert rig.ctrl.snapshot().control_owner == "gamepad"
    assert not rig.ctrl.acquire_control("browser-a")


# ------------------------------------------------------------------ tracker


def test_tracker_dropout_reports_missing_never_a_stale_pose() -> None:
    from icenav.sim import TrackerConfig

    clock = Clock()
    session = make_sim_controller(imaging=False, clock=clock)
    try:
        tracker = session.tracker
        tracker.config = TrackerConfig(dropout_probability=0.5, dropout_mean_samples=5.0)
        seen: dict[str, int] = {}
        for _ in range(300):
            clock.t += session.controller.config.dt
            s = session.controller.step()
            seen[s.tracker_status] = seen.get(s.tracker_status, 0) + 1
            assert (s.sensor2base is None) == (s.tracker_status != "VALID")
        assert seen.get("MISSING", 0) > 0 and seen.get("VALID", 0) > 0
    finally:
        session.close()


def test_tracker_that_dies_is_reported_and_control_goes_on() -> None:
    clock = Clock()
    session = make_sim_controller(imaging=False, clock=clock)
    try:
        ctrl = session.controller
        session.tracker.stop()  # get_frame() now raises TrackerError
        ctrl.jog([0.1, 0.0, 0.0, 0.0], "knob")
        for _ in range(10):
            clock.t += ctrl.config.dt
            state = ctrl.step()
        assert state.tracker_status == "ERROR" and state.sensor2base is None
        assert "tracker" in state.message
        assert state.mode is Mode.KNOB  # the tracker is not in the control path
    finally:
        session.close()


# ------------------------------------------------------------------ the store


def _session(tmp_path: Path, clock: Clock) -> tuple[Controller, SessionStore, Callable[[], None]]:
    session = make_sim_controller(imaging=False, clock=clock, session=tmp_path / "s.icenav")
    assert session.store is not None
    return session.controller, session.store, session.close


def _drain(ctrl: Controller) -> None:
    """Wait until the store's writer thread has run every queued write (blocks on its queue:
    no sleep), so that a fault injected into the connection next hits a known point."""
    ctrl._recorder.drain()  # type: ignore[union-attr]  # noqa: SLF001


def _drive(ctrl: Controller, clock: Clock, cycles: int, v: list[float]) -> None:
    for _ in range(cycles):
        ctrl.jog(v, "knob")
        clock.t += ctrl.config.dt
        ctrl.step()


@pytest.mark.parametrize("fault", ["disk_full", "read_only"])
def test_store_failure_is_reported_robot_stays_safe_file_stays_consistent(
    tmp_path: Path, fault: str
) -> None:
    clock = Clock()
    ctrl, store, close = _session(tmp_path, clock)
    _drive(ctrl, clock, 150, [0.2, -0.1, 0.0, 1.0])
    ctrl.save_view("before")
    _drive(ctrl, clock, 1, [0.0, 0.0, 0.0, 0.0])
    _drain(ctrl)
    db = store._db  # noqa: SLF001 - the fault is injected into the connection itself
    if fault == "disk_full":
        pages = db.execute("PRAGMA page_count").fetchone()[0]
        db.execute(f"PRAGMA max_page_count={pages}")
    else:
        db.execute("PRAGMA query_only=1")
    q_before = ctrl.snapshot().q_motor.copy()
    _drive(ctrl, clock, 400, [0.0, 0.2, 0.0, -1.0])  # new states that cannot be stored
    ctrl.save_view("during")
    clock.t += ctrl.config.dt
    state = ctrl.step()
    # the view is committed on the store's writer thread: the operator is not told "saved"
    # (the cycle may also report a failed batch the writer finished meanwhile)
    assert "view 'during' saved" not in state.message or "NOT on disk" in state.message
    _drain(ctrl)  # the writer has tried (and failed); its answer is shown next cycle
    clock.t += ctrl.config.dt
    state = ctrl.step()
    assert "view 'during' saved in memory only, NOT on disk" in state.message
    assert "could not record" in state.message
    assert ("full" in state.message) if fault == "disk_full" else ("read-only" in state.message)
    assert state.mode in (Mode.KNOB, Mode.IDLE)
    # motion is still exactly what was commanded, and stops when the operator stops
    assert not np.allclose(state.q_motor, q_before)
    for _ in range(40):
        clock.t += ctrl.config.dt
        ctrl.step()
    q_hold = ctrl.snapshot().q_motor.copy()
    for _ in range(20):
        clock.t += ctrl.config.dt
        np.testing.assert_array_equal(ctrl.step().q_motor, q_hold)
    # the file: whatever was committed reads back as a consistent roadmap
    with pytest.raises(Exception):  # noqa: B017 - the close itself reports the failure
        close()
    with SessionStore(tmp_path / "s.icenav", read_only=True) as reopened:
        assert [v.name for v in reopened.load_views()] == ["before"]
        rm = reopened.load_roadmap()
        view = reopened.load_views().get("before")
        np.testing.assert_allclose(rm.vertices()[view.vertex], view.q)
        check = reopened._db.execute("PRAGMA integrity_check").fetchone()[0]  # noqa: SLF001
        assert check == "ok"
        # the trace is gap-free: every stored trace entry refers to a stored vertex
        assert rm.n_trace == 0 or int(rm.trace().max()) < rm.n_vertices


def test_store_recovers_after_a_transient_disk_full(tmp_path: Path) -> None:
    """Rows refused while the disk was full are written once space is back: nothing that
    the session file later claims to hold is missing (no silent gap)."""
    clock = Clock()
    ctrl, store, close = _session(tmp_path, clock)
    _drive(ctrl, clock, 100, [0.2, 0.0, 0.0, 1.0])
    _drain(ctrl)
    db = store._db  # noqa: SLF001
    pages = db.execute("PRAGMA page_count").fetchone()[0]
    db.execute(f"PRAGMA max_page_count={pages}")
    _drive(ctrl, clock, 300, [0.0, 0.2, 0.0, 1.0])
    _drain(ctrl)  # the writer's failed batches are reported at the next cycle
    _drive(ctrl, clock, 1, [0.0, 0.2, 0.0, 1.0])
    assert "could not record" in ctrl.snapshot().message
    _drain(ctrl)
    db.execute("PRAGMA max_page_count=1073741823")
    _drive(ctrl, clock, 100, [0.0, -0.2, 0.0, -1.0])
    ctrl.save_view("after")
    _drive(ctrl, clock, 1, [0.0, 0.0, 0.0, 0.0])
    live = ctrl.roadmap
    close()
    with SessionStore(tmp_path / "s.icenav", read_only=True) as reopened:
        rm = reopened.load_roadmap()
        assert rm.n_vertices == live.n_vertices
        np.testing.assert_array_equal(rm.vertices(), live.vertices())
        np.testing.assert_array_equal(rm.trace(), live.trace())
        assert rm.n_edges == live.n_edges
        assert [v.name for v in reopened.load_views()] == ["after"]


def test_session_file_that_cannot_be_opened_is_a_clear_error(tmp_path: Path) -> None:
    from icenav.errors import StoreError

    with pytest.raises(StoreError, match="cannot open session file .* read-only: it does not"):
        SessionStore(tmp_path / "missing.icenav", read_only=True)
    with pytest.raises(StoreError, match="cannot open session file"):
        SessionStore(tmp_path / "no such dir" / "s.icenav")
    with pytest.raises(StoreError, match="cannot open session file"):
        make_sim_controller(imaging=False, session=tmp_path / "no such dir" / "s.icenav")


# ------------------------------------------------------------------ emulated CANopen drives


@pytest.fixture
def canopen_controller() -> Iterator[tuple[Controller, object, Clock]]:
    from icenav.devices.canopen.emulated_drive import EmulatedDriveSet, emulated_robot_config
    from icenav.devices.canopen.robot import CANopenRobot

    channel = f"icenav-rel-{uuid.uuid4().hex[:8]}"
    drives = EmulatedDriveSet(channel)
    robot = CANopenRobot(emulated_robot_config(channel))
    clock = Clock()
    try:
        ctrl = Controller(robot, ControllerConfig(), clock=clock)
        yield ctrl, drives, clock
    finally:
        robot.close()
        drives.close()


def _positions(drives: object) -> np.ndarray:
    from icenav.devices.canopen.emulated_drive import EMULATED_NODE_IDS

    return np.array([drives[n].position for n in EMULATED_NODE_IDS])  # type: ignore[index]


@pytest.mark.parametrize("fault", ["drive_fault", "heartbeat_loss", "following_error"])
def test_canopen_fault_mid_move_stops_every_axis(
    canopen_controller: tuple[Controller, object, Clock], fault: str
) -> None:
    ctrl, drives, clock = canopen_controller

    def cycle(n: int) -> None:
        for _ in range(n):
            clock.t += ctrl.config.dt
            ctrl.jog([0.3, 0.3, 0.5, 3.0], "knob")
            ctrl.step()
            drives.tick(ctrl.config.dt)  # type: ignore[attr-defined]

    cycle(20)
    moving_from = _positions(drives)
    cycle(5)
    assert not np.allclose(_positions(drives), moving_from)
    if fault == "drive_fault":
        drives[2].inject_fault(0x2310)  # type: ignore[index]
        expected = "0x2310"
    elif fault == "heartbeat_loss":
        drives[2].inject_heartbeat_loss()  # type: ignore[index]
        expected = "heartbeat"
    else:
        drives[5].inject_following_error()  # type: ignore[index]
        expected = "following error"
    deadline = time.monotonic() + 5.0
    while ctrl.mode is not Mode.FAULT:
        assert time.monotonic() < deadline, f"no FAULT after {fault}: {ctrl.snapshot()}"
        cycle(1)
    state = ctrl.snapshot()
    assert expected in state.message and "reset" in state.message
    cycle(5)  # the quick stop ramps down
    stopped_at = _positions(drives)
    cycle(50)  # the operator keeps jogging: nothing moves
    np.testing.assert_allclose(_positions(drives), stopped_at, atol=1e-9)
    assert ctrl.mode is Mode.FAULT

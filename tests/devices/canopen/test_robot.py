"""CANopenRobot against five emulated CiA 402 drives on python-can's virtual bus.

Each test gets its own virtual channel. The drives move only when the test ticks them;
every wait is a condition polled with a timeout (never a sleep as synchronisation).
"""

from __future__ import annotations

import contextlib
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import can
import numpy as np
import pytest

from icenav.devices.canopen.cia402 import DriveState
from icenav.devices.canopen.config import ControlMode, RobotConfig
from icenav.devices.canopen.emulated_drive import (
    EMULATED_NODE_IDS,
    EmulatedDriveSet,
    emulated_robot_config,
    open_emulated_robot,
)
from icenav.devices.canopen.robot import CANopenRobot
from icenav.devices.robot import RobotBackend, RobotStatus
from icenav.errors import (
    DriveFaultError,
    EmergencyStopError,
    HardwareError,
    HeartbeatLostError,
    JointLimitError,
)

TIMEOUT_S = 5.0


def wait_until(pred: Callable[[], bool], timeout: float = TIMEOUT_S, what: str = "") -> None:
    """Poll ``pred`` until true; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what or pred}")
        time.sleep(0.001)


@dataclass
class Rig:
    robot: CANopenRobot
    drives: EmulatedDriveSet
    config: RobotConfig
    channel: str

    def move(self, q: list[float], dt: float = 0.01, max_ticks: int = 400) -> np.ndarray:
        """Command ``q``, tick until the robot reads it back; return the read q."""
        self.robot.command_position(q)
        target = np.asarray(q)
        tol = np.array([2e-4, 2e-4, 2e-4, 1e-4])
        for _ in range(max_ticks):
            self.drives.tick(dt)
            if np.all(np.abs(self.robot.read_state().q - target) < tol):
                break
        wait_until(
            lambda: bool(np.all(np.abs(self.robot.read_state().q - target) < tol)),
            what=f"q = {q}",
        )
        return self.robot.read_state().q


@contextlib.contextmanager
def _make_rig(request: pytest.FixtureRequest, **overrides: Any) -> Iterator[Rig]:
    channel = f"icenav-{request.node.name}-{uuid.uuid4().hex[:8]}"
    drives = EmulatedDriveSet(channel)
    config = emulated_robot_config(channel, **overrides)
    robot = CANopenRobot(config)
    try:
        yield Rig(robot, drives, config, channel)
    finally:
        robot.close()
        drives.close()


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    with _make_rig(request) as r:
        yield r


@pytest.fixture(params=list(ControlMode), ids=[m.value for m in ControlMode])
def any_mode_rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    with _make_rig(request, mode=request.param) as r:
        yield r


def _states(rig: Rig) -> list[DriveState]:
    return [rig.drives[n].state for n in EMULATED_NODE_IDS]


# ------------------------------------------------------------------ normal operation
def test_is_a_robot_backend(rig: Rig) -> None:
    assert isinstance(rig.robot, RobotBackend)
    assert rig.robot.status is RobotStatus.DISABLED
    assert all(rig.drives[n].nmt_state == "OPERATIONAL" for n in EMULATED_NODE_IDS)


def test_enable_move_and_read_back(any_mode_rig: Rig) -> None:
    rig = any_mode_rig
    rig.robot.enable()
    assert rig.robot.status is RobotStatus.ENABLED
    assert _states(rig) == [DriveState.OPERATION_ENABLED] * 5
    q_cmd = [0.3, -0.2, 0.5, 12.5]
    q = rig.move(q_cmd)
    np.testing.assert_allclose(q, q_cmd, atol=2e-4)
    # The drives hold the counts of the one conversion in config.py.
    for motor in rig.config.motors:
        j = ["phi1", "phi2", "phi3", "d4"].index(motor.joint)
        assert rig.drives[motor.node_id].position == motor.to_counts(q_cmd[j])
    # Both roll motors turned in step.
    assert rig.drives[3].position == rig.drives[4].position


def test_speed_limit_from_the_joint_configuration(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.command_position([1.0, 0.0, 0.0, 0.0])
    rig.drives.tick(0.1)
    # max_velocity of phi1 is 2 rad/s: one 0.1 s tick moves 0.2 rad, not the full 1 rad.
    motor = rig.config.motors[0]
    wait_until(lambda: rig.robot.read_state().q[0] > 0.1)
    assert rig.robot.read_state().q[0] == pytest.approx(0.2, abs=1.0 / motor.counts_per_unit)


def test_commands_are_refused_unless_enabled(rig: Rig) -> None:
    with pytest.raises(HardwareError, match="DISABLED; call enable"):
        rig.robot.command_position([0.0, 0.0, 0.0, 0.0])


def test_joint_limits_are_refused_not_clipped(rig: Rig) -> None:
    rig.robot.enable()
    with pytest.raises(JointLimitError, match="phi1"):
        rig.robot.command_position([2.0, 0.0, 0.0, 0.0])
    with pytest.raises(JointLimitError, match="d4 = 60 mm"):
        rig.robot.command_position([0.0, 0.0, 0.0, 60.0])
    assert rig.robot.status is RobotStatus.ENABLED


def test_home_makes_the_current_pose_zero(rig: Rig) -> None:
    rig.robot.enable()
    rig.move([0.2, 0.1, -0.4, 5.0])
    rig.robot.home()
    assert rig.robot.status is RobotStatus.ENABLED
    np.testing.assert_allclose(rig.robot.read_state().q, 0.0, atol=1e-9)
    assert [rig.drives[n].position for n in EMULATED_NODE_IDS] == [0] * 5
    np.testing.assert_allclose(rig.move([0.1, 0.0, 0.0, 1.0]), [0.1, 0.0, 0.0, 1.0], atol=2e-4)


def test_unsupported_homing_method_faults(request: pytest.FixtureRequest) -> None:
    from icenav.devices.canopen.config import HomingConfig

    with _make_rig(request, homing=HomingConfig(method=1, timeout_s=1.0)) as rig:
        with pytest.raises(DriveFaultError, match=r"homing error on axis ap_knob .*\(method 1\)"):
            rig.robot.home()
        assert rig.robot.status is RobotStatus.FAULT


def test_stop_holds_the_current_position(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.command_position([1.0, 0.0, 0.0, 0.0])
    rig.drives.tick(0.1)
    wait_until(lambda: rig.robot.read_state().q[0] > 0.1)
    rig.robot.stop()
    held = rig.robot.read_state().q[0]
    for _ in range(10):
        rig.drives.tick(0.1)
    assert rig.drives[1].position == rig.config.motors[0].to_counts(held)
    assert rig.robot.status is RobotStatus.ENABLED


# ------------------------------------------------------------------ bus traces
def _sniff(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=0)) is not None:
        out.append(msg)
    return out


def test_enable_sequence_bus_trace(request: pytest.FixtureRequest) -> None:
    channel = f"icenav-trace-{uuid.uuid4().hex[:8]}"
    sniffer = can.Bus(interface="virtual", channel=channel)
    drives = EmulatedDriveSet(channel)
    robot = CANopenRobot(emulated_robot_config(channel))
    try:
        _sniff(sniffer)
        robot.enable()
        frames = _sniff(sniffer)
    finally:
        robot.close()
        drives.close()
        sniffer.shutdown()
    # Expedited SDO downloads (client command 0x2B: 2 data bytes) to 0x6040 sub 0.
    cw_writes = [
        (m.arbitration_id - 0x600, int.from_bytes(m.data[4:6], "little"))
        for m in frames
        if 0x601 <= m.arbitration_id <= 0x67F
        and m.data[0] == 0x2B
        and m.data[1:4] == bytes([0x40, 0x60, 0x00])
    ]
    ids = list(EMULATED_NODE_IDS)
    assert cw_writes == (
        [(n, 0x0006) for n in ids] + [(n, 0x0007) for n in ids] + [(n, 0x000F) for n in ids]
    )
    # The mode of operation (0x6060 = 1, profile position) is set before any controlword.
    first_cw = next(
        i for i, m in enumerate(frames) if m.arbitration_id >= 0x600 and m.data[1:3] == b"\x40\x60"
    )
    mode_writes = [
        i
        for i, m in enumerate(frames)
        if 0x601 <= m.arbitration_id <= 0x67F and m.data[0] == 0x2F and m.data[1:3] == b"\x60\x60"
    ]
    assert len(mode_writes) == 5 and max(mode_writes) < first_cw
    assert all(frames[i].data[4] == 1 for i in mode_writes)


def test_profile_position_set_point_handshake_trace(rig: Rig) -> None:
    rig.robot.enable()
    sniffer = can.Bus(interface="virtual", channel=rig.channel)
    try:
        rig.robot.command_position([0.1, 0.0, 0.0, 0.0])
        frames = _sniff(sniffer)
    finally:
        sniffer.shutdown()
    node1 = [m for m in frames if m.arbitration_id in (0x201, 0x181)]
    rpdos = [(int.from_bytes(m.data[0:2], "little"), m) for m in node1 if m.arbitration_id == 0x201]
    # New set-point (bit 4) with change-immediately (bit 5), then bit 4 cleared.
    assert [cw for cw, _ in rpdos] == [0x003F, 0x002F]
    target = int.from_bytes(rpdos[0][1].data[2:6], "little", signed=True)
    assert target == rig.config.motors[0].to_counts(0.1)
    # Between the two, the drive acknowledged (statusword bit 12) in its TPDO1.
    i0 = node1.index(rpdos[0][1])
    i1 = node1.index(rpdos[1][1])
    acks = [m for m in node1[i0:i1] if m.arbitration_id == 0x181 and m.data[1] & 0x10]
    assert acks, "no set-point acknowledge between new set-point and its release"


def test_cyclic_synchronous_targets_wait_for_sync(request: pytest.FixtureRequest) -> None:
    with _make_rig(request, mode=ControlMode.CYCLIC_SYNCHRONOUS_POSITION) as rig:
        rig.robot.enable()
        sniffer = can.Bus(interface="virtual", channel=rig.channel)
        try:
            rig.robot.command_position([0.1, 0.0, 0.0, 0.0])
            frames = _sniff(sniffer)
        finally:
            sniffer.shutdown()
        ids = [m.arbitration_id for m in frames if m.arbitration_id in (0x80, *range(0x201, 0x206))]
        assert ids == [0x201, 0x202, 0x203, 0x204, 0x205, 0x80]


# ------------------------------------------------------------------ faults
def _expect_stopped(rig: Rig, error: type[HardwareError], match: str) -> None:
    wait_until(lambda: rig.robot.status is RobotStatus.FAULT, what="FAULT")
    state = rig.robot.read_state()
    assert state.status is RobotStatus.FAULT
    assert isinstance(rig.robot.error, error)
    assert pytest.approx(0) != len(state.message)
    with pytest.raises(error, match=match):
        rig.robot.command_position(state.q)
    with pytest.raises(error, match=match):
        rig.robot.enable()
    # No drive is left moving: every one is quick-stopped, faulted or powerless.
    moving_ok = {
        DriveState.QUICK_STOP_ACTIVE,
        DriveState.FAULT,
        DriveState.SWITCH_ON_DISABLED,
    }
    wait_until(lambda: set(_states(rig)) <= moving_ok, what="all drives stopped")
    before = [rig.drives[n].position for n in EMULATED_NODE_IDS]
    for _ in range(20):
        rig.drives.tick(0.05)
    assert [rig.drives[n].position for n in EMULATED_NODE_IDS] == before


def _recover(rig: Rig) -> None:
    rig.robot.reset_fault()
    assert rig.robot.status is RobotStatus.DISABLED
    assert rig.robot.error is None
    with pytest.raises(HardwareError, match="call enable"):
        rig.robot.command_position([0.0, 0.0, 0.0, 0.0])
    rig.robot.enable()
    q = rig.robot.read_state().q
    target = [q[0] + 0.05, q[1], q[2], q[3]]
    np.testing.assert_allclose(rig.move(target), target, atol=2e-4)


def test_drive_fault_in_one_roll_motor_stops_everything(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.command_position([0.5, 0.5, 1.0, 20.0])
    for _ in range(5):
        rig.drives.tick(0.01)
    rig.drives[4].inject_fault(0x2310)
    _expect_stopped(rig, DriveFaultError, r"roll_back \(node 4, joint phi3\).*0x2310")
    assert rig.robot.error is not None
    assert getattr(rig.robot.error, "code", None) == 0x2310
    assert getattr(rig.robot.error, "axis", None) == "roll_back"
    assert rig.drives[3].state is DriveState.QUICK_STOP_ACTIVE  # its partner stopped too
    _recover(rig)


def test_heartbeat_loss_stops_everything_until_it_returns(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.command_position([0.5, 0.5, 1.0, 20.0])
    rig.drives.tick(0.01)
    rig.drives[2].inject_heartbeat_loss()
    _expect_stopped(rig, HeartbeatLostError, r"lr_knob \(node 2, joint phi2\)")
    with pytest.raises(HeartbeatLostError, match="cannot reset: no heartbeat from axis lr_knob"):
        rig.robot.reset_fault()
    assert rig.robot.status is RobotStatus.FAULT
    rig.drives[2].clear_injections()

    def reset_ok() -> bool:
        try:
            rig.robot.reset_fault()
        except HeartbeatLostError:
            return False
        return True

    wait_until(reset_ok, what="heartbeat back")
    rig.robot.enable()
    np.testing.assert_allclose(rig.move([0.1, 0.1, 0.1, 1.0]), [0.1, 0.1, 0.1, 1.0], atol=2e-4)


def test_following_error_faults_the_robot(rig: Rig) -> None:
    rig.robot.enable()
    rig.drives[5].inject_following_error()
    rig.robot.command_position([0.0, 0.0, 0.0, 10.0])
    for _ in range(10):
        rig.drives.tick(0.01)
    _expect_stopped(rig, DriveFaultError, r"translation .*0x8611 \(following error\)")
    rig.drives[5].clear_injections()
    _recover(rig)


def test_roll_difference_faults_and_needs_homing(request: pytest.FixtureRequest) -> None:
    with _make_rig(request, roll_difference_limit=0.02) as rig:
        rig.robot.enable()
        # The back motor jams, but with a wide following-error window of its own: only the
        # robot's roll-difference supervision can catch it.
        rig.drives[4].node.set_data(0x6065, 0, (10**6).to_bytes(4, "little"))
        rig.drives[4].inject_following_error()
        rig.robot.command_position([0.0, 0.0, 0.3, 0.0])
        for _ in range(10):
            rig.drives.tick(0.005)
            if rig.robot.status is RobotStatus.FAULT:
                break
        _expect_stopped(rig, DriveFaultError, r"roll following difference: roll_front - roll_back")
        assert rig.drives[4].state is DriveState.QUICK_STOP_ACTIVE
        assert getattr(rig.robot.error, "axis", None) == "phi3"
        rig.robot.reset_fault()
        with pytest.raises(DriveFaultError, match="untwist the catheter and call home"):
            rig.robot.enable()
        rig.drives[4].clear_injections()
        rig.robot.home()
        np.testing.assert_allclose(rig.robot.read_state().q, 0.0, atol=1e-9)
        np.testing.assert_allclose(rig.move([0.0, 0.0, 0.2, 0.0]), [0, 0, 0.2, 0], atol=2e-4)


def test_estop_quick_stops_all_drives_at_once(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.command_position([1.0, 1.0, 1.0, 30.0])
    rig.drives.tick(0.05)
    rig.robot.estop()
    assert rig.robot.status is RobotStatus.ESTOP
    wait_until(lambda: _states(rig) == [DriveState.QUICK_STOP_ACTIVE] * 5, what="quick stop")
    before = [rig.drives[n].position for n in EMULATED_NODE_IDS]
    for _ in range(20):
        rig.drives.tick(0.05)
    assert [rig.drives[n].position for n in EMULATED_NODE_IDS] == before
    with pytest.raises(EmergencyStopError, match="reset_fault"):
        rig.robot.command_position([0.0, 0.0, 0.0, 0.0])
    with pytest.raises(EmergencyStopError):
        rig.robot.enable()
    assert rig.robot.read_state().status is RobotStatus.ESTOP
    _recover(rig)


def test_disable_powers_down(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.disable()
    assert rig.robot.status is RobotStatus.DISABLED
    assert _states(rig) == [DriveState.READY_TO_SWITCH_ON] * 5


def test_missing_drives_are_reported(request: pytest.FixtureRequest) -> None:
    channel = f"icenav-empty-{uuid.uuid4().hex[:8]}"
    config = emulated_robot_config(channel, sdo_timeout_s=0.05)
    with pytest.raises(HardwareError, match=r"ap_knob \(node 1.*no SDO answer"):
        CANopenRobot(config)


def test_open_emulated_robot_moves_with_background_ticks() -> None:
    robot, drives = open_emulated_robot(ControlMode.CYCLIC_SYNCHRONOUS_POSITION)
    try:
        robot.enable()
        target = np.array([0.05, -0.05, 0.1, 1.0])
        # Cyclic synchronous: the controller streams the target every cycle.
        deadline = time.monotonic() + TIMEOUT_S
        while np.max(np.abs(robot.read_state().q - target)) > 2e-4:
            if time.monotonic() > deadline:
                pytest.fail(f"target not reached: {robot.read_state()}")
            robot.command_position(target)
            time.sleep(0.002)  # the controller's cycle, not a synchronisation
        assert robot.read_state().status is RobotStatus.ENABLED
    finally:
        robot.close()
        drives.close()


def test_drive_leaving_operational_faults_and_reset_restarts_it(rig: Rig) -> None:
    rig.robot.enable()
    rig.robot.network[3].nmt.send_command(0x80)  # someone sends node 3 to PRE-OPERATIONAL
    _expect_stopped(rig, HeartbeatLostError, r"roll_front \(node 3.*left NMT OPERATIONAL")
    _recover(rig)
    assert rig.drives[3].nmt_state == "OPERATIONAL"

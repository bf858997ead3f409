"""An emulated CiA 402 position drive: a canopen ``LocalNode`` on a python-can bus.

It is what the tests, the benchmarks and ``icenav demo --robot emulated-canopen`` drive in
place of real motor drives. Each drive serves its object dictionary (the EDS bundled as
``icenav/devices/canopen/data/emulated_drive.eds``) over SDO, produces heartbeats (0x1017), answers
NMT,
runs the CiA 402 power state machine of :mod:`icenav.devices.canopen.cia402` on its controlword,
receives
RPDO1 (controlword, target position) and SYNC, transmits TPDO1 (statusword, position actual
value) and EMCY, and moves its position toward the target at a speed limit on each
:meth:`EmulatedDrive.tick` (called explicitly by tests, or by the background thread of
:class:`EmulatedDriveSet`).

Emulation simplifications (documented so nobody mistakes them for a drive's behaviour):
the position follows the demand exactly (no dynamics) unless a following error is injected;
leaving NMT OPERATIONAL quick-stops the drive (as with abort connection option code 0x6007 =
quick stop);
a quick stop or a fault stops at once (infinite deceleration); homing supports only the
methods 35 and 37 (home = current position) and reports a homing error for the others; in
cyclic synchronous position mode the controlword of an RPDO acts at once and only the target
waits for the next SYNC.

Fault injection: :meth:`EmulatedDrive.inject_fault` (a drive fault with an EMCY code),
:meth:`EmulatedDrive.inject_heartbeat_loss`, :meth:`EmulatedDrive.inject_following_error`
(the motor stops following, as a jammed axis does).
"""

from __future__ import annotations

import math
import struct
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from icenav.devices.canopen import cia402
from icenav.devices.canopen.cia402 import DriveState, OperationMode
from icenav.devices.canopen.config import (
    BusConfig,
    ControlMode,
    HeartbeatConfig,
    JointConfig,
    MotorConfig,
    RobotConfig,
    bundled_eds_path,
)
from icenav.devices.canopen.robot import CANopenRobot
from icenav.errors import ConfigurationError

__all__ = [
    "EMULATED_NODE_IDS",
    "EmulatedDrive",
    "EmulatedDriveSet",
    "emulated_robot_config",
    "open_emulated_robot",
]

EMULATED_NODE_IDS = (1, 2, 3, 4, 5)
"""Node ids of :func:`emulated_robot_config`: phi1, phi2, roll front, roll back, d4."""

_SUPPORTED_MODES = frozenset(int(m) for m in OperationMode)
_HOME_HERE_METHODS = frozenset({35, 37})


class EmulatedDrive:
    """One emulated CiA 402 drive (node ``node_id``) on ``network``.

    Positions are in encoder counts, velocities in counts/s, as on a real drive.
    Thread-safe: SDO, RPDO and SYNC arrive on the network's notifier thread, ticks on the
    caller's thread.
    """

    def __init__(self, network: canopen.Network, node_id: int, eds: Path | None = None):
        self.node = canopen.LocalNode(node_id, str(eds or bundled_eds_path()))
        self.node_id = node_id
        self._lock = threading.RLock()
        self._state = DriveState.SWITCH_ON_DISABLED
        self._cw = 0
        self._mode = int(self._param(0x6060))
        self._demand = 0.0
        self._actual = 0.0
        self._goal = 0.0
        self._csp_pending: int | None = None
        self._error_code = 0
        self._setpoint_ack = False
        self._homing_attained = False
        self._homing_error = False
        self._jammed = False
        self._heartbeat_stopped = False
        self._last_tpdo: tuple[int, int] | None = None
        self.controlword_log: list[int] = []
        """Every controlword the drive received (SDO or RPDO), in order."""
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        network.add_node(self.node)
        network.subscribe(cia402.RPDO1.cob_id(node_id), self._on_rpdo)
        network.subscribe(0x80, self._on_sync)
        network.subscribe(0, self._on_nmt)  # after the LocalNode's own NMT handler
        # Boot: INITIALISING (boot-up message) -> PRE-OPERATIONAL (heartbeat starts).
        self.node.nmt.send_command(0x81)
        self.node.nmt.send_command(0x80)

    # ----------------------------------------------------------------- state, read-only
    @property
    def state(self) -> DriveState:
        """Current CiA 402 power state."""
        with self._lock:
            return self._state

    @property
    def position(self) -> int:
        """Position actual value (counts)."""
        with self._lock:
            return round(self._actual)

    @property
    def nmt_state(self) -> str:
        """NMT state ("PRE-OPERATIONAL", "OPERATIONAL", ...)."""
        return self.node.nmt.state

    @property
    def statusword(self) -> int:
        """Current statusword (0x6041)."""
        with self._lock:
            return self._statusword()

    # ----------------------------------------------------------------- fault injection
    def inject_fault(self, code: int = 0x2310) -> None:
        """Fault the drive with EMCY / error code ``code`` (default: over-current)."""
        with self._lock:
            self._fault(code)

    def inject_heartbeat_loss(self) -> None:
        """Stop producing heartbeats (a cut cable or a crashed drive)."""
        with self._lock:
            self._heartbeat_stopped = True
            self.node.nmt.stop_heartbeat()

    def inject_following_error(self) -> None:
        """The motor stops following its demand (a jammed axis)."""
        with self._lock:
            self._jammed = True

    def clear_injections(self) -> None:
        """Undo the injected heartbeat loss and following error (a fault stays until reset)."""
        with self._lock:
            self._jammed = False
            if self._heartbeat_stopped:
                self._heartbeat_stopped = False
                self.node.nmt.start_heartbeat(int(self._param(0x1017)))

    # ----------------------------------------------------------------- motion
    def tick(self, dt: float) -> None:
        """Advance the drive by ``dt`` seconds: move, supervise the following error, send
        TPDO1."""
        with self._lock:
            if self._state is DriveState.OPERATION_ENABLED and self._mode in (
                OperationMode.PROFILE_POSITION,
                OperationMode.CYCLIC_SYNCHRONOUS_POSITION,
            ):
                vmax = float(self._param(0x607F))
                if self._mode == OperationMode.PROFILE_POSITION:
                    vmax = min(vmax, float(self._param(0x6081)))
                step = max(-vmax * dt, min(vmax * dt, self._goal - self._demand))
                self._demand += step
                if not self._jammed:
                    self._actual = self._demand
                if abs(self._demand - self._actual) > float(self._param(0x6065)):
                    self._fault(0x8611)
            self._send_tpdo(force=True)

    # ----------------------------------------------------------------- internals
    def _param(self, index: int) -> Any:
        raw = self.node.get_data(index, 0)
        od = self.node.object_dictionary[index]
        if not isinstance(od, ODVariable):
            raise ConfigurationError(f"object 0x{index:04X} of the EDS is not a variable")
        return od.decode_raw(raw)

    def _statusword(self) -> int:
        extra = 0
        fe = abs(self._demand - self._actual) > float(self._param(0x6065))
        if self._mode == OperationMode.PROFILE_POSITION:
            if self._setpoint_ack:
                extra |= cia402.SW_OPERATION_MODE_SPECIFIC
            if abs(self._goal - self._actual) < 0.5 and self._demand == self._goal:
                extra |= cia402.SW_TARGET_REACHED
            if fe:
                extra |= cia402.SW_FOLLOWING_ERROR
        elif self._mode == OperationMode.HOMING:
            if self._homing_attained:
                extra |= cia402.SW_OPERATION_MODE_SPECIFIC | cia402.SW_TARGET_REACHED
            if self._homing_error:
                extra |= cia402.SW_FOLLOWING_ERROR
        elif self._mode == OperationMode.CYCLIC_SYNCHRONOUS_POSITION:
            if self._state is DriveState.OPERATION_ENABLED:
                extra |= cia402.SW_OPERATION_MODE_SPECIFIC
            if fe:
                extra |= cia402.SW_FOLLOWING_ERROR
        return cia402.encode_statusword(self._state, extra)

    def _send_tpdo(self, force: bool = False) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        values = (self._statusword(), round(self._actual))
        if force or values != self._last_tpdo:
            self._last_tpdo = values
            self.node.network.send_message(
                cia402.TPDO1.cob_id(self.node_id), cia402.TPDO1.pack(*values)
            )

    def _fault(self, code: int) -> None:
        if self._state is DriveState.FAULT:
            return
        self._state = DriveState.FAULT  # via FAULT REACTION ACTIVE, which stops at once here
        self._demand = self._goal = self._actual
        self._error_code = code
        self.node.emcy.send(code, 0x01)
        self._send_tpdo(force=True)

    def _hold(self) -> None:
        self._demand = self._goal = self._actual
        self._csp_pending = None

    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        with self._lock:
            if index == 0x6041:
                return self._statusword()
            if index == 0x6064:
                return round(self._actual)
            if index == 0x6062:
                return round(self._demand)
            if index == 0x60F4:
                return round(self._demand - self._actual)
            if index == 0x6061:
                return self._mode
            if index == 0x603F:
                return self._error_code
            if index == 0x1001:
                return 0x01 if self._state is DriveState.FAULT else 0x00
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        value = od.decode_raw(data)
        with self._lock:
            if index == 0x6040:
                self._on_controlword(int(value))
            elif index == 0x6060:
                if int(value) not in _SUPPORTED_MODES:
                    raise SdoAbortedError(0x06090030)  # value range of parameter exceeded
                self._mode = int(value)
                self._homing_attained = self._homing_error = False
                self._hold()
                self._send_tpdo()  # the statusword's mode-specific bits changed
            elif index == 0x607A and self._mode == OperationMode.CYCLIC_SYNCHRONOUS_POSITION:
                self._csp_pending = int(value)

    def _on_controlword(self, cw: int) -> None:
        self.controlword_log.append(cw)
        previous = self._cw
        command = cia402.decode_command(cw, previous)
        old = self._state
        new = cia402.next_state(old, command)
        if command is cia402.Command.FAULT_RESET and old is DriveState.FAULT:
            self._error_code = 0
            self.node.emcy.reset()
        if new is not old:
            self._state = new
            self._hold()
            self._setpoint_ack = False
        self._cw = cw
        if self._state is DriveState.OPERATION_ENABLED:
            rising = bool(cw & cia402.CW_NEW_SET_POINT) and not previous & cia402.CW_NEW_SET_POINT
            if self._mode == OperationMode.PROFILE_POSITION:
                if rising:
                    self._goal = float(self._param(0x607A))
                    self._setpoint_ack = True
                elif not cw & cia402.CW_NEW_SET_POINT:
                    self._setpoint_ack = False
            elif self._mode == OperationMode.HOMING and rising:
                if int(self._param(0x6098)) in _HOME_HERE_METHODS:
                    self._actual = float(self._param(0x607C))
                    self._hold()
                    self._homing_attained = True
                    self._homing_error = False
                else:
                    self._homing_error = True
        self._send_tpdo()

    def _on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        cw, target = cia402.RPDO1.unpack(data)
        with self._lock:
            # Target first (CSP: pending until SYNC), then the controlword, as mapped.
            self.node.set_data(0x607A, 0, struct.pack("<i", target))
            self.node.data_store.setdefault(0x6040, {})[0] = struct.pack("<H", cw)
            self._on_controlword(cw)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # Abort connection option (0x6007) = quick stop: leaving OPERATIONAL stops the motor.
        with self._lock:
            if self.node.nmt.state != "OPERATIONAL" and self._state is DriveState.OPERATION_ENABLED:
                self._state = DriveState.QUICK_STOP_ACTIVE
                self._hold()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        with self._lock:
            if (
                self._mode == OperationMode.CYCLIC_SYNCHRONOUS_POSITION
                and self._state is DriveState.OPERATION_ENABLED
                and self._csp_pending is not None
            ):
                self._goal = float(self._csp_pending)
                self._csp_pending = None
            self._send_tpdo(force=True)


class EmulatedDriveSet:
    """Several emulated drives sharing one canopen network on a python-can bus.

    Parameters
    ----------
    channel : str
        Bus channel; on the ``virtual`` interface every bus with the same channel name in
        this process sees the others' frames (use a unique name per test).
    node_ids : sequence of int
        Node ids of the drives.
    interface : str
        python-can interface (``virtual`` for tests and the demo).
    """

    def __init__(
        self,
        channel: str,
        node_ids: tuple[int, ...] = EMULATED_NODE_IDS,
        interface: str = "virtual",
        eds: Path | None = None,
    ):
        self.bus = can.Bus(interface=interface, channel=channel)
        self.network = canopen.Network(self.bus)
        self.network.NOTIFIER_CYCLE = 0.05  # receive-thread poll period (fast close)
        self.network.connect()
        self.drives: dict[int, EmulatedDrive] = {
            nid: EmulatedDrive(self.network, nid, eds) for nid in node_ids
        }
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def __getitem__(self, node_id: int) -> EmulatedDrive:
        return self.drives[node_id]

    def tick(self, dt: float) -> None:
        """Advance every drive by ``dt`` seconds."""
        for drive in self.drives.values():
            drive.tick(dt)

    def start(self, period_s: float = 0.002) -> None:
        """Tick in a background thread with the real elapsed time (for demos)."""
        if self._thread is not None:
            return
        self._stop.clear()

        def run() -> None:
            last = time.monotonic()
            while not self._stop.wait(period_s):
                now = time.monotonic()
                self.tick(now - last)
                last = now

        self._thread = threading.Thread(target=run, name="emulated-drives", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the background thread (if any)."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5.0)
            self._thread = None

    def close(self) -> None:
        """Stop ticking and heartbeats, and release the bus."""
        self.stop()
        for drive in self.drives.values():
            drive.node.nmt.stop_heartbeat()
        self.network.disconnect()


def emulated_robot_config(
    channel: str,
    mode: ControlMode = ControlMode.PROFILE_POSITION,
    heartbeat: HeartbeatConfig | None = None,
    **overrides: Any,
) -> RobotConfig:
    """A robot configuration for five emulated drives on the virtual bus ``channel``.

    Encoders of 4096 counts/rev behind 10:1 gears (about 6519.6 counts/rad) for the knobs
    and the roll, and a 2 mm/rev lead screw (20480 counts/mm) for the translation.
    """
    if not channel:
        raise ConfigurationError("channel must be a non-empty virtual bus name")
    inf = math.inf
    joints = (
        JointConfig("phi1", -math.pi / 2, math.pi / 2, 2.0, 0.05),
        JointConfig("phi2", -math.pi / 2, math.pi / 2, 2.0, 0.05),
        JointConfig("phi3", -inf, inf, 2.0, 0.05),
        JointConfig("d4", -50.0, 50.0, 20.0, 1.0),
    )
    motors = (
        MotorConfig("ap_knob", "phi1", 1, 4096, 10.0),
        MotorConfig("lr_knob", "phi2", 2, 4096, 10.0),
        MotorConfig("roll_front", "phi3", 3, 4096, 10.0, role="front"),
        MotorConfig("roll_back", "phi3", 4, 4096, 10.0, role="back"),
        MotorConfig("translation", "d4", 5, 4096, 10.0, mm_per_rev=2.0),
    )
    return RobotConfig(
        joints=joints,
        motors=motors,
        bus=BusConfig(interface="virtual", channel=channel, bitrate=1_000_000),
        mode=mode,
        heartbeat=heartbeat or HeartbeatConfig(producer_ms=20, consumer_s=0.5),
        **overrides,
    )


def open_emulated_robot(
    mode: ControlMode = ControlMode.PROFILE_POSITION,
    channel: str | None = None,
    tick_period_s: float = 0.002,
) -> tuple[CANopenRobot, EmulatedDriveSet]:
    """A :class:`CANopenRobot` on five emulated drives that tick in a background thread.

    For ``icenav demo --robot emulated-canopen`` and for trying the CANopen path without
    hardware. Close both when done: ``robot.close(); drives.close()``.
    """
    name = channel or f"icenav-emulated-{uuid.uuid4().hex[:8]}"
    drives = EmulatedDriveSet(name)
    try:
        # the emulated drives are Python threads sharing the GIL with the controller, the
        # console and the renderer: on a loaded 2-core machine their answer can take longer
        # than a real drive's on the bus (0.1 s in examples/robot.toml), so the handshake
        # gets 1 s and the heartbeat consumer 2 s here; a drive that does not answer still
        # faults the robot
        config = emulated_robot_config(
            name,
            mode=mode,
            heartbeat=HeartbeatConfig(producer_ms=20, consumer_s=2.0),
            handshake_timeout_s=1.0,
        )
        robot = CANopenRobot(config)
    except BaseException:
        drives.close()
        raise
    drives.start(tick_period_s)
    return robot, drives

"""The robot on real motor drives: five CiA 402 drives on a CAN bus (python-can + canopen).

One drive per motor: the two knobs (phi1, phi2), the translation (d4) and two for the roll
axis phi3 (the *front* motor holds the catheter shaft, the *back* motor the handle). The two
roll motors are commanded in step; their difference is supervised, and a fault in either (or
in any drive) quick-stops all five.

Bus traffic:

* configuration, the CiA 402 state machine, homing and fault reset by SDO (confirmed: every
  controlword write is followed by a statusword read);
* cyclic data by PDO with the mapping of the bundled EDS: RPDO1 (0x200 + id) = controlword
  + target position, TPDO1 (0x180 + id) = statusword + position actual value;
* profile position: every command is a set-point with the handshake (new set-point bit 4,
  change immediately bit 5 -> the drive's set-point acknowledge, statusword bit 12 -> bit 4
  cleared); cyclic synchronous position: targets, then one SYNC so that all drives apply
  them together;
* heartbeat consumer supervision (each drive produces at ``heartbeat.producer_ms``; one
  silent for ``heartbeat.consumer_s`` is lost) and EMCY reception, checked by a background
  supervisor thread every ``supervision_period_s`` and at every :meth:`read_state`.

On any fault (EMCY, drive statusword FAULT, lost heartbeat, a drive leaving OPERATION
ENABLED, roll difference beyond ``roll_difference_limit``) all drives get a quick stop at once
(five RPDOs back to back, no waiting for answers), the robot goes to RobotStatus.FAULT and
keeps a DriveFaultError / HeartbeatLostError naming the axis and the code;
:meth:`command_position` raises it. Nothing moves again before :meth:`reset_fault` and
:meth:`enable`.
"""

from __future__ import annotations

import functools
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from numpy.typing import ArrayLike

from icenav._validation import JOINT_NAMES, check_joint_state
from icenav.devices.canopen import cia402
from icenav.devices.canopen.cia402 import DriveState, OperationMode
from icenav.devices.canopen.config import ControlMode, MotorConfig, RobotConfig, bundled_eds_path
from icenav.devices.robot import TRANSITIONS, JointState, RobotStatus
from icenav.errors import (
    DriveFaultError,
    EmergencyStopError,
    HardwareError,
    HeartbeatLostError,
    ShapeError,
)

__all__ = ["CANopenRobot"]

logger = logging.getLogger(__name__)

_OPERATIONAL = 5  # NMT state in the heartbeat
_NOTIFIER_CYCLE_S = 0.05  # receive-thread poll period: bounds the time close() takes


@dataclass
class _Axis:
    """Run-time state of one drive (mutable; guarded by the robot's locks)."""

    motor: MotorConfig
    node: canopen.RemoteNode
    statusword: int = 0
    position: int = 0
    tpdo_count: int = 0
    last_heartbeat: float | None = None
    nmt_state: int = 0
    emcy_code: int = 0
    command: int = 0

    @property
    def label(self) -> str:
        return f"{self.motor.name} (node {self.motor.node_id}, joint {self.motor.joint})"


class CANopenRobot:
    """A :class:`~icenav.devices.robot.RobotBackend` on five CiA 402 drives.

    Parameters
    ----------
    config : RobotConfig
        Drives, conversions, limits, mode, heartbeat and homing (see
        :func:`icenav.devices.canopen.config.load_robot_config`).
    bus : can.BusABC, optional
        An open python-can bus; default: opened from ``config.bus``. The robot owns it and
        shuts it down in :meth:`close`.
    clock : callable
        Monotonic clock (s) for timestamps and heartbeat supervision.

    Raises
    ------
    HardwareError
        A drive does not answer (SDO timeout) or sends no heartbeat at start.
    """

    def __init__(
        self,
        config: RobotConfig,
        bus: can.BusABC | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self._clock = clock
        self._state_lock = threading.RLock()
        self._io_lock = threading.RLock()
        self._cache = threading.Condition()
        self._status = RobotStatus.DISABLED
        self._error: HardwareError | None = None
        self._homing = False
        if bus is None:
            bus = can.Bus(
                interface=config.bus.interface,
                channel=config.bus.channel,
                bitrate=config.bus.bitrate,
            )
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = _NOTIFIER_CYCLE_S
        self.network.connect()
        self._axes: list[_Axis] = []
        for motor in config.motors:
            node = canopen.RemoteNode(motor.node_id, str(motor.eds or bundled_eds_path()))
            self.network.add_node(node)
            node.sdo.RESPONSE_TIMEOUT = config.sdo_timeout_s
            axis = _Axis(motor, node)
            node.nmt.add_heartbeat_callback(functools.partial(self._on_heartbeat, axis))
            node.emcy.add_callback(functools.partial(self._on_emcy, axis))
            self.network.subscribe(
                cia402.TPDO1.cob_id(motor.node_id), functools.partial(self._on_tpdo, axis)
            )
            self._axes.append(axis)
        self._roll = (
            next(a for a in self._axes if a.motor.joint == "phi3" and a.motor.role == "front"),
            next(a for a in self._axes if a.motor.joint == "phi3" and a.motor.role == "back"),
        )
        self._stop_supervisor = threading.Event()
        self._supervisor: threading.Thread | None = None
        try:
            self._start_nodes()
        except BaseException:
            self.network.disconnect()
            raise
        self._supervisor = threading.Thread(
            target=self._supervise_loop, name="canopen-supervisor", daemon=True
        )
        self._supervisor.start()

    # ================================================================ RobotBackend
    @property
    def status(self) -> RobotStatus:
        """Current status."""
        with self._state_lock:
            return self._status

    @property
    def error(self) -> HardwareError | None:
        """The fault (or e-stop) that stopped the robot; None when all is well."""
        with self._state_lock:
            return self._error

    def enable(self) -> None:
        """NMT-started drives -> OPERATION ENABLED holding their positions (-> ENABLED).

        Raises the stored error in FAULT / ESTOP, and DriveFaultError when a drive does not
        reach OPERATION ENABLED or the roll motors differ by more than the limit.
        """
        with self._io_lock:
            with self._state_lock:
                self._refuse_unless("enable")
                if self._status is RobotStatus.ENABLED:
                    return
            self._check_roll_alignment()
            self._power_up(self._operating_mode())
            with self._state_lock:
                self._refuse_unless("enable")
                self._status = RobotStatus.ENABLED

    def disable(self) -> None:
        """Shutdown (power stage off) on every drive (ENABLED -> DISABLED)."""
        with self._io_lock:
            with self._state_lock:
                self._refuse_unless("disable")
                self._status = RobotStatus.DISABLED
            self._guarded(lambda: self._write_all("controlword", cia402.CW_SHUTDOWN))

    def home(self) -> None:
        """CiA 402 homing (mode 6, method ``config.homing.method``) on all five drives.

        Allowed from DISABLED (the drives are enabled first) or ENABLED; afterwards the robot
        is ENABLED and q = 0 is the catheter's neutral state. With methods 35 / 37 the
        current position becomes home, so set the catheter to neutral (knobs centred,
        shaft untwisted) before calling it. This also realigns the two roll motors.
        """
        with self._io_lock:
            with self._state_lock:
                self._refuse_unless("enable")
                self._homing = True
            try:
                self._guarded(self._home)
            finally:
                with self._state_lock:
                    self._homing = False
            with self._state_lock:
                self._refuse_unless("enable")
                self._status = RobotStatus.ENABLED

    def read_state(self) -> JointState:
        """Joint state from the latest TPDO1 of each drive (runs the supervision first)."""
        self._supervise()
        q = self._joint_positions()
        with self._state_lock:
            message = str(self._error) if self._error is not None else ""
            return JointState(q=q, timestamp=self._clock(), status=self._status, message=message)

    def command_position(self, q_motor: ArrayLike) -> None:
        """New position target (phi1 rad, phi2 rad, phi3 rad, d4 mm) for all drives.

        Raises JointLimitError beyond a limit (nothing is clipped), the stored
        DriveFaultError / HeartbeatLostError / EmergencyStopError unless ENABLED.
        """
        q = check_joint_state(q_motor, self.config.limits, name="q_motor")
        if q.shape != (4,):
            raise ShapeError(f"q_motor must have shape (4,), got {q.shape}")
        targets = [
            a.motor.to_counts(float(q[JOINT_NAMES.index(a.motor.joint)])) for a in self._axes
        ]
        self._send_targets(targets)

    def stop(self) -> None:
        """Hold the current positions (stays ENABLED); a no-op unless ENABLED."""
        with self._state_lock:
            if self._status is not RobotStatus.ENABLED:
                return
        with self._cache:
            targets = [a.position for a in self._axes]
        self._send_targets(targets)

    def estop(self) -> None:
        """Quick stop on all five drives at once (-> ESTOP); needs reset_fault() + enable()."""
        with self._state_lock:
            self._status = TRANSITIONS[(self._status, "estop")]
            self._error = EmergencyStopError(
                "emergency stop: all five drives quick-stopped; call reset_fault() and "
                "enable() to move again"
            )
            self._quick_stop_all()

    def reset_fault(self) -> None:
        """Clear a FAULT or ESTOP (-> DISABLED): fault reset / disable voltage on every drive.

        Raises HeartbeatLostError if a drive is still silent and DriveFaultError if a drive
        stays in FAULT; the robot then stays in FAULT / ESTOP.
        """
        with self._io_lock:
            with self._state_lock:
                if self._status is RobotStatus.ENABLED:
                    return
            now = self._clock()
            with self._cache:
                silent = [a for a in self._axes if self._heartbeat_age(a, now) is not None]
                rebooted = [a for a in self._axes if a.nmt_state != _OPERATIONAL]
            if silent:
                a = silent[0]
                raise HeartbeatLostError(
                    f"cannot reset: no heartbeat from axis {a.label} within "
                    f"{self.config.heartbeat.consumer_s} s"
                )
            if rebooted:  # a drive that reset itself is back in PRE-OPERATIONAL
                self._nmt_start(rebooted)
            for axis in self._axes:
                state = cia402.decode_statusword(self._read(axis, "statusword"))
                if state is DriveState.FAULT:
                    self._write(axis, "controlword", cia402.CW_DISABLE_VOLTAGE)
                    self._write(axis, "controlword", cia402.CW_FAULT_RESET)
                elif state is not DriveState.SWITCH_ON_DISABLED:
                    self._write(axis, "controlword", cia402.CW_DISABLE_VOLTAGE)
            for axis in self._axes:
                state = cia402.decode_statusword(self._read(axis, "statusword"))
                if state is not DriveState.SWITCH_ON_DISABLED:
                    code = self._read(axis, "error_code")
                    raise DriveFaultError(
                        f"cannot reset: axis {axis.label} stays in {state.name} "
                        f"(error code 0x{code:04X}: {cia402.emcy_text(code)})",
                        axis=axis.motor.name,
                        code=code,
                    )
            with self._cache:
                for axis in self._axes:
                    axis.emcy_code = 0
            with self._state_lock:
                self._status = TRANSITIONS[(self._status, "reset_fault")]
                self._error = None

    def close(self) -> None:
        """Stop supervision, shut the drives down if enabled, release the bus."""
        if self._supervisor is None:
            return
        self._stop_supervisor.set()
        self._supervisor.join(timeout=5.0)
        self._supervisor = None
        if self.status is RobotStatus.ENABLED:
            try:
                self.disable()
            except HardwareError as exc:  # pragma: no cover - best effort on the way out
                logger.warning("disable on close failed: %s", exc)
        self.network.disconnect()

    def __enter__(self) -> CANopenRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ================================================================ start-up, enable
    def _start_nodes(self) -> None:
        hb = self.config.heartbeat
        for axis in self._axes:
            self._write(axis, "producer_heartbeat_time", hb.producer_ms)
        self._nmt_start(self._axes)
        for axis in self._axes:
            self._refresh(axis)

    def _nmt_start(self, axes: list[_Axis]) -> None:
        """NMT start ``axes`` and wait for their OPERATIONAL heartbeats."""
        for axis in axes:
            axis.node.nmt.state = "OPERATIONAL"
        timeout = max(1.0, 3.0 * self.config.heartbeat.consumer_s)
        deadline = self._clock() + timeout
        with self._cache:
            while True:
                missing = [a for a in axes if a.nmt_state != _OPERATIONAL]
                if not missing:
                    return
                remaining = deadline - self._clock()
                if remaining <= 0:
                    raise HeartbeatLostError(
                        f"axis {missing[0].label}: no OPERATIONAL heartbeat within "
                        f"{timeout:.2f} s after NMT start"
                    )
                self._cache.wait(min(remaining, 0.05))

    def _operating_mode(self) -> OperationMode:
        if self.config.mode is ControlMode.CYCLIC_SYNCHRONOUS_POSITION:
            return OperationMode.CYCLIC_SYNCHRONOUS_POSITION
        return OperationMode.PROFILE_POSITION

    def _power_up(self, mode: OperationMode) -> None:
        """Mode, limits, target = actual, then shutdown / switch on / enable on all drives."""

        def run() -> None:
            for axis in self._axes:
                joint = self.config.joints[JOINT_NAMES.index(axis.motor.joint)]
                self._write(axis, "modes_of_operation", int(mode))
                if mode is OperationMode.CYCLIC_SYNCHRONOUS_POSITION:
                    self._write_index(axis, 0x1006, "<I", round(self.config.sync_period_s * 1e6))
                self._write(
                    axis, "profile_velocity", axis.motor.magnitude_to_counts(joint.max_velocity)
                )
                window = axis.motor.magnitude_to_counts(joint.following_error_window)
                self._write(axis, "following_error_window", window)
                self._refresh(axis)
                self._write(axis, "target_position", axis.position)
                axis.command = axis.position
            steps = (
                (cia402.CW_SHUTDOWN, DriveState.READY_TO_SWITCH_ON),
                (cia402.CW_SWITCH_ON, DriveState.SWITCHED_ON),
                (cia402.CW_ENABLE_OPERATION, DriveState.OPERATION_ENABLED),
            )
            for controlword, expected in steps:
                self._abort_if_stopped()
                self._write_all("controlword", controlword)
                for axis in self._axes:
                    self._expect(axis, expected)

        self._guarded(run)

    def _home(self) -> None:
        self._power_up(OperationMode.HOMING)
        method = self.config.homing.method
        self._write_all("homing_method", method)
        self._write_all("controlword", cia402.CW_ENABLE_OPERATION | cia402.CW_NEW_SET_POINT)
        deadline = self._clock() + self.config.homing.timeout_s
        pending = list(self._axes)
        while pending:
            self._abort_if_stopped()
            for axis in list(pending):
                sw = self._read(axis, "statusword")
                if sw & cia402.SW_FOLLOWING_ERROR:
                    raise DriveFaultError(
                        f"homing error on axis {axis.label} (method {method})",
                        axis=axis.motor.name,
                    )
                done = cia402.SW_OPERATION_MODE_SPECIFIC | cia402.SW_TARGET_REACHED
                if sw & done == done:
                    pending.remove(axis)
            if not pending:
                break
            if self._clock() > deadline:
                names = ", ".join(a.motor.name for a in pending)
                raise DriveFaultError(
                    f"homing (method {method}) did not finish within "
                    f"{self.config.homing.timeout_s} s on axis {names}",
                    axis=pending[0].motor.name,
                )
            with self._cache:
                self._cache.wait(0.02)
        mode = self._operating_mode()
        self._write_all("controlword", cia402.CW_ENABLE_OPERATION)
        for axis in self._axes:
            self._write(axis, "modes_of_operation", int(mode))
            self._refresh(axis)
            self._write(axis, "target_position", axis.position)
            axis.command = axis.position
            self._expect(axis, DriveState.OPERATION_ENABLED)

    def _check_roll_alignment(self) -> None:
        diff = self._roll_difference()
        if abs(diff) > self.config.roll_difference_limit:
            front, back = self._roll
            raise DriveFaultError(
                f"roll motors {front.motor.name} and {back.motor.name} differ by {diff:.4f} rad "
                f"(limit {self.config.roll_difference_limit} rad): untwist the catheter and "
                "call home()",
                axis="phi3",
                code=0x8611,
            )

    # ================================================================ commands
    def _send_targets(self, targets: list[int]) -> None:
        pp = self.config.mode is ControlMode.PROFILE_POSITION
        cw = cia402.CW_ENABLE_OPERATION
        with self._state_lock:
            if self._status is not RobotStatus.ENABLED or self._homing:
                raise self._refusal()
            before = self._tpdo_counts()
            bits = cia402.CW_NEW_SET_POINT | cia402.CW_CHANGE_SET_IMMEDIATELY if pp else 0
            for axis, target in zip(self._axes, targets, strict=True):
                axis.command = target
                self._send_rpdo(axis, cw | bits, target)
            if not pp:
                self.network.sync.transmit()
                return
        # Profile position handshake: set-point acknowledge (bit 12) seen in a TPDO sent
        # after the new set-point, then bit 4 cleared and the acknowledge seen dropping,
        # so that a later TPDO can never carry a stale acknowledge.
        self._await_acknowledge(before, True)
        with self._state_lock:
            if self._status is not RobotStatus.ENABLED:
                raise self._refusal()
            before = self._tpdo_counts()
            for axis, target in zip(self._axes, targets, strict=True):
                self._send_rpdo(axis, cw | cia402.CW_CHANGE_SET_IMMEDIATELY, target)
        self._await_acknowledge(before, False)

    def _tpdo_counts(self) -> list[int]:
        with self._cache:
            return [a.tpdo_count for a in self._axes]

    def _await_acknowledge(self, before: list[int], acknowledged: bool) -> None:
        """Wait until every drive's TPDO1 newer than ``before`` shows bit 12 = ``acknowledged``.

        On timeout the robot faults (all drives quick-stopped) and the error is raised.
        """
        deadline = self._clock() + self.config.handshake_timeout_s
        with self._cache:
            while True:
                missing = [
                    a
                    for a, n in zip(self._axes, before, strict=True)
                    if a.tpdo_count <= n
                    or bool(a.statusword & cia402.SW_OPERATION_MODE_SPECIFIC) != acknowledged
                ]
                remaining = deadline - self._clock()
                if not missing or remaining <= 0:
                    break
                self._cache.wait(remaining)
        if not missing:
            return
        with self._state_lock:
            if self._status is RobotStatus.ENABLED:
                a = missing[0]
                what = "set-point acknowledge" if acknowledged else "release of the acknowledge"
                self._enter_fault(
                    DriveFaultError(
                        f"axis {a.label}: no {what} within {self.config.handshake_timeout_s} s",
                        axis=a.motor.name,
                    )
                )
            raise self._refusal()

    def _send_rpdo(self, axis: _Axis, controlword: int, target: int) -> None:
        self.network.send_message(
            cia402.RPDO1.cob_id(axis.motor.node_id), cia402.RPDO1.pack(controlword, target)
        )

    def _quick_stop_all(self) -> None:
        """Quick stop to every drive, back to back, without waiting (state lock held)."""
        with self._cache:
            positions = [a.position for a in self._axes]
        for axis, pos in zip(self._axes, positions, strict=True):
            try:
                self._send_rpdo(axis, cia402.CW_QUICK_STOP, pos)
            except (can.CanError, RuntimeError) as exc:  # keep stopping the others
                logger.error("quick stop to %s failed: %s", axis.label, exc)
        if self.config.mode is ControlMode.CYCLIC_SYNCHRONOUS_POSITION:
            try:
                self.network.sync.transmit()
            except (can.CanError, RuntimeError) as exc:
                logger.error("SYNC after quick stop failed: %s", exc)

    def _abort_if_stopped(self) -> None:
        """Raise the stored error if a fault or e-stop happened during a sequence."""
        with self._state_lock:
            if self._error is not None:
                raise self._error

    def _refuse_unless(self, event: str) -> None:
        if (self._status, event) not in TRANSITIONS:
            raise self._refusal()

    def _refusal(self) -> HardwareError:
        if self._error is not None:
            return self._error
        if self._homing:
            return HardwareError("the robot is homing; commands are refused until it finishes")
        return HardwareError(
            f"the robot is {self._status.name}; call enable() before commanding motion"
        )

    # ================================================================ supervision
    def _supervise_loop(self) -> None:
        while not self._stop_supervisor.wait(self.config.supervision_period_s):
            try:
                self._supervise()
            except Exception:  # pragma: no cover - the supervisor must never die silently
                logger.exception("supervision failed")

    def _supervise(self) -> None:
        with self._state_lock:
            if self._status in (RobotStatus.FAULT, RobotStatus.ESTOP):
                return
            error = self._detect_fault()
            if error is not None:
                self._enter_fault(error)

    def _detect_fault(self) -> HardwareError | None:
        now = self._clock()
        enabled = self._status is RobotStatus.ENABLED
        with self._cache:
            for axis in self._axes:
                age = self._heartbeat_age(axis, now)
                if age is not None:
                    return HeartbeatLostError(
                        f"heartbeat lost: axis {axis.label} silent for {age:.3f} s "
                        f"(consumer time {self.config.heartbeat.consumer_s} s, EMCY 0x8130)"
                    )
            for axis in self._axes:
                if axis.nmt_state != _OPERATIONAL:
                    return HeartbeatLostError(
                        f"axis {axis.label} left NMT OPERATIONAL (heartbeat state {axis.nmt_state})"
                    )
            for axis in self._axes:
                state = cia402.decode_statusword(axis.statusword)
                code = axis.emcy_code
                if code or state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
                    return DriveFaultError(
                        f"drive fault on axis {axis.label}: error code 0x{code:04X} "
                        f"({cia402.emcy_text(code)}), drive state {state.name}",
                        axis=axis.motor.name,
                        code=code,
                    )
                if enabled and not self._homing and state is not DriveState.OPERATION_ENABLED:
                    return DriveFaultError(
                        f"axis {axis.label} left OPERATION ENABLED (now {state.name})",
                        axis=axis.motor.name,
                    )
        if enabled and not self._homing:
            diff = self._roll_difference()
            if abs(diff) > self.config.roll_difference_limit:
                front, back = self._roll
                return DriveFaultError(
                    f"roll following difference: {front.motor.name} - {back.motor.name} = "
                    f"{diff:.4f} rad exceeds the limit {self.config.roll_difference_limit} rad "
                    "(code 0x8611)",
                    axis="phi3",
                    code=0x8611,
                )
        return None

    def _enter_fault(self, error: HardwareError) -> None:
        """-> FAULT, keep ``error``, quick-stop every drive (state lock held)."""
        self._status = TRANSITIONS[(self._status, "fault")]
        self._error = error
        logger.error("robot FAULT: %s", error)
        self._quick_stop_all()

    def _heartbeat_age(self, axis: _Axis, now: float) -> float | None:
        """Age of the last heartbeat if beyond the consumer time, else None."""
        if axis.last_heartbeat is None:
            return float("inf")
        age = now - axis.last_heartbeat
        return age if age > self.config.heartbeat.consumer_s else None

    def _roll_difference(self) -> float:
        front, back = self._roll
        with self._cache:
            return front.motor.from_counts(front.position) - back.motor.from_counts(back.position)

    def _joint_positions(self) -> np.ndarray:
        q = np.zeros(4)
        with self._cache:
            for j, name in enumerate(JOINT_NAMES):
                axes = [a for a in self._axes if a.motor.joint == name]
                q[j] = np.mean([a.motor.from_counts(a.position) for a in axes])
        return q

    # ================================================================ bus callbacks
    def _on_heartbeat(self, axis: _Axis, state: int) -> None:
        with self._cache:
            axis.last_heartbeat = self._clock()
            axis.nmt_state = state & 0x7F
            self._cache.notify_all()

    def _on_emcy(self, axis: _Axis, entry: EmcyError) -> None:
        if entry.code & 0xFF00 == 0:
            return  # error reset
        with self._cache:
            axis.emcy_code = entry.code
            self._cache.notify_all()

    def _on_tpdo(self, axis: _Axis, can_id: int, data: bytearray, timestamp: float) -> None:
        statusword, position = cia402.TPDO1.unpack(data)
        with self._cache:
            axis.statusword = statusword
            axis.position = position
            axis.tpdo_count += 1
            self._cache.notify_all()

    # ================================================================ SDO helpers
    def _guarded(self, fn: Callable[[], None]) -> None:
        """Run an SDO sequence; a HardwareError on the way faults the robot."""
        try:
            fn()
        except HardwareError as exc:
            with self._state_lock:
                if self._status not in (RobotStatus.FAULT, RobotStatus.ESTOP):
                    self._enter_fault(exc)
            raise

    def _write_all(self, name: str, value: int) -> None:
        for axis in self._axes:
            self._write(axis, name, value)

    def _write(self, axis: _Axis, name: str, value: int) -> None:
        obj = cia402.OBJECTS[name]
        self._write_index(axis, obj.index, obj.fmt, value)

    def _write_index(self, axis: _Axis, index: int, fmt: str, value: int) -> None:
        try:
            axis.node.sdo.download(index, 0, struct.pack(fmt, value))
        except SdoAbortedError as exc:
            raise HardwareError(
                f"axis {axis.label}: writing 0x{index:04X} = {value} refused: {exc}"
            ) from exc
        except SdoCommunicationError as exc:
            raise HardwareError(
                f"axis {axis.label}: no SDO answer writing 0x{index:04X} within "
                f"{self.config.sdo_timeout_s} s ({exc}); is the drive powered and its node "
                f"id {axis.motor.node_id}?"
            ) from exc

    def _read(self, axis: _Axis, name: str) -> int:
        obj = cia402.OBJECTS[name]
        try:
            raw = axis.node.sdo.upload(obj.index, 0)
        except SdoAbortedError as exc:
            raise HardwareError(f"axis {axis.label}: reading {name} refused: {exc}") from exc
        except SdoCommunicationError as exc:
            raise HardwareError(
                f"axis {axis.label}: no SDO answer reading {name} within "
                f"{self.config.sdo_timeout_s} s ({exc})"
            ) from exc
        return int(struct.unpack(obj.fmt, raw[: struct.calcsize(obj.fmt)])[0])

    def _refresh(self, axis: _Axis) -> None:
        """Statusword and position by SDO into the cache."""
        sw = self._read(axis, "statusword")
        pos = self._read(axis, "position_actual_value")
        with self._cache:
            axis.statusword = sw
            axis.position = pos

    def _expect(self, axis: _Axis, expected: DriveState) -> None:
        sw = self._read(axis, "statusword")
        with self._cache:
            axis.statusword = sw
        state = cia402.decode_statusword(sw)
        if state is not expected:
            code = self._read(axis, "error_code") if state is DriveState.FAULT else 0
            raise DriveFaultError(
                f"axis {axis.label}: expected {expected.name}, drive reports {state.name} "
                f"(statusword 0x{sw:04X}, error code 0x{code:04X}: {cia402.emcy_text(code)})",
                axis=axis.motor.name,
                code=code,
            )

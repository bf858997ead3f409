"""The CiA 402 drive profile in one place: states, controlword / statusword bits, objects.

Shared by the master (:mod:`icenav.devices.canopen.robot`) and the emulated drive
(:mod:`icenav.devices.canopen.emulated_drive`), so both read the same table.

The power state machine (CiA 402, Fig. "Finite state automaton")::

    NOT READY TO SWITCH ON --(1, automatic)--> SWITCH ON DISABLED
    SWITCH ON DISABLED --shutdown (2)--> READY TO SWITCH ON --switch on (3)--> SWITCHED ON
    SWITCHED ON --enable operation (4)--> OPERATION ENABLED
    OPERATION ENABLED --quick stop (11)--> QUICK STOP ACTIVE --disable voltage (12)--> ...
    any --drive fault (13)--> FAULT REACTION ACTIVE --(14)--> FAULT --fault reset (15)--> ...

The transitions are the table :data:`TRANSITIONS`; a (state, command) pair missing from it
leaves the state unchanged, as a drive ignores a command that does not apply.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from icenav.errors import HardwareError

__all__ = [
    "CW_CHANGE_SET_IMMEDIATELY",
    "CW_DISABLE_VOLTAGE",
    "CW_ENABLE_OPERATION",
    "CW_FAULT_RESET",
    "CW_HALT",
    "CW_NEW_SET_POINT",
    "CW_QUICK_STOP",
    "CW_SHUTDOWN",
    "CW_SWITCH_ON",
    "Command",
    "DriveState",
    "EMCY_CODES",
    "OBJECTS",
    "OperationMode",
    "Pdo",
    "RPDO1",
    "SW_FOLLOWING_ERROR",
    "SW_OPERATION_MODE_SPECIFIC",
    "SW_TARGET_REACHED",
    "SW_VOLTAGE_ENABLED",
    "SW_WARNING",
    "TPDO1",
    "TRANSITIONS",
    "decode_command",
    "decode_statusword",
    "emcy_text",
    "encode_statusword",
    "next_state",
]


class DriveState(enum.Enum):
    """The CiA 402 power states; the value is the statusword pattern (bits 0-3, 5, 6)."""

    NOT_READY_TO_SWITCH_ON = 0x00
    """Booting; the drive goes on to SWITCH ON DISABLED by itself."""
    SWITCH_ON_DISABLED = 0x40
    """Power stage off; the drive accepts a shutdown command."""
    READY_TO_SWITCH_ON = 0x21
    """Waiting for switch on."""
    SWITCHED_ON = 0x23
    """Power stage on, not following set-points."""
    OPERATION_ENABLED = 0x27
    """Following set-points."""
    QUICK_STOP_ACTIVE = 0x07
    """Stopping / stopped by a quick stop; no motion until re-enabled."""
    FAULT_REACTION_ACTIVE = 0x0F
    """Reacting to a fault (stopping)."""
    FAULT = 0x08
    """Faulted; needs a fault reset."""


class Command(enum.Enum):
    """Device-control commands decoded from the controlword (bits 0-3 and 7)."""

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"
    ENABLE_OPERATION = "enable operation"
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    FAULT_RESET = "fault reset"
    NONE = "none"


class OperationMode(enum.IntEnum):
    """Modes of operation (object 0x6060 / 0x6061) that icenav uses."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    HOMING = 6
    CYCLIC_SYNCHRONOUS_POSITION = 8


# Controlword (0x6040) bits and commands.
CW_SWITCH_ON_BIT = 0x0001
CW_ENABLE_VOLTAGE_BIT = 0x0002
CW_QUICK_STOP_BIT = 0x0004  # active low: 0 requests a quick stop
CW_ENABLE_OPERATION_BIT = 0x0008
CW_NEW_SET_POINT = 0x0010
"""Bit 4: new set-point (profile position) / start homing (homing mode)."""
CW_CHANGE_SET_IMMEDIATELY = 0x0020
"""Bit 5: the new set-point replaces the current one at once (profile position)."""
CW_FAULT_RESET = 0x0080
"""Bit 7: fault reset on its rising edge."""
CW_HALT = 0x0100
"""Bit 8: halt."""
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002

# Statusword (0x6041) bits besides the state pattern.
SW_VOLTAGE_ENABLED = 0x0010
SW_WARNING = 0x0080
SW_REMOTE = 0x0200
SW_TARGET_REACHED = 0x0400
"""Bit 10: target reached (profile position, homing)."""
SW_OPERATION_MODE_SPECIFIC = 0x1000
"""Bit 12: set-point acknowledge (PP), homing attained (HM), following the command (CSP)."""
SW_FOLLOWING_ERROR = 0x2000
"""Bit 13: following error (PP, CSP) / homing error (HM)."""

_STATE_MASKS: tuple[tuple[int, DriveState], ...] = (
    (0x4F, DriveState.NOT_READY_TO_SWITCH_ON),
    (0x4F, DriveState.SWITCH_ON_DISABLED),
    (0x6F, DriveState.READY_TO_SWITCH_ON),
    (0x6F, DriveState.SWITCHED_ON),
    (0x6F, DriveState.OPERATION_ENABLED),
    (0x6F, DriveState.QUICK_STOP_ACTIVE),
    (0x4F, DriveState.FAULT_REACTION_ACTIVE),
    (0x4F, DriveState.FAULT),
)

TRANSITIONS: dict[tuple[DriveState, Command], DriveState] = {
    # (2) shutdown
    (DriveState.SWITCH_ON_DISABLED, Command.SHUTDOWN): DriveState.READY_TO_SWITCH_ON,
    # (3) switch on; (3 + 4) switch on and enable in one step, as most drives allow
    (DriveState.READY_TO_SWITCH_ON, Command.SWITCH_ON): DriveState.SWITCHED_ON,
    (DriveState.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION): DriveState.OPERATION_ENABLED,
    # (4) enable operation
    (DriveState.SWITCHED_ON, Command.ENABLE_OPERATION): DriveState.OPERATION_ENABLED,
    # (5) disable operation (= switch on)
    (DriveState.OPERATION_ENABLED, Command.SWITCH_ON): DriveState.SWITCHED_ON,
    # (6), (8) shutdown
    (DriveState.SWITCHED_ON, Command.SHUTDOWN): DriveState.READY_TO_SWITCH_ON,
    (DriveState.OPERATION_ENABLED, Command.SHUTDOWN): DriveState.READY_TO_SWITCH_ON,
    # (7), (9), (10), (12) disable voltage; quick stop where no motion is possible
    (DriveState.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): DriveState.SWITCH_ON_DISABLED,
    (DriveState.READY_TO_SWITCH_ON, Command.QUICK_STOP): DriveState.SWITCH_ON_DISABLED,
    (DriveState.SWITCHED_ON, Command.DISABLE_VOLTAGE): DriveState.SWITCH_ON_DISABLED,
    (DriveState.SWITCHED_ON, Command.QUICK_STOP): DriveState.SWITCH_ON_DISABLED,
    (DriveState.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): DriveState.SWITCH_ON_DISABLED,
    (DriveState.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): DriveState.SWITCH_ON_DISABLED,
    # (11) quick stop
    (DriveState.OPERATION_ENABLED, Command.QUICK_STOP): DriveState.QUICK_STOP_ACTIVE,
    # (16) enable operation from quick stop
    (DriveState.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION): DriveState.OPERATION_ENABLED,
    # (15) fault reset
    (DriveState.FAULT, Command.FAULT_RESET): DriveState.SWITCH_ON_DISABLED,
}
"""(state, command) -> next state of the CiA 402 power state machine (transition number in
the comments). Faults (13, 14) are raised by the drive itself, not commanded."""


def decode_command(controlword: int, previous_controlword: int = 0) -> Command:
    """Decode the device-control command of a controlword (CiA 402 Table "Command coding").

    ``previous_controlword`` is needed for the fault reset, which acts on the rising edge of
    bit 7.
    """
    cw = int(controlword) & 0xFFFF
    if cw & CW_FAULT_RESET and not previous_controlword & CW_FAULT_RESET:
        return Command.FAULT_RESET
    if cw & CW_FAULT_RESET:
        return Command.NONE  # bit 7 held high: no new command
    if not cw & CW_ENABLE_VOLTAGE_BIT:
        return Command.DISABLE_VOLTAGE  # 0xxx xx0x
    if not cw & CW_QUICK_STOP_BIT:
        return Command.QUICK_STOP  # 0xxx x01x
    if not cw & CW_SWITCH_ON_BIT:
        return Command.SHUTDOWN  # 0xxx x110
    if cw & CW_ENABLE_OPERATION_BIT:
        return Command.ENABLE_OPERATION  # 0xxx 1111
    return Command.SWITCH_ON  # 0xxx 0111 (also "disable operation")


def next_state(state: DriveState, command: Command) -> DriveState:
    """The state after ``command`` (unchanged when the table has no such transition)."""
    return TRANSITIONS.get((state, command), state)


def decode_statusword(statusword: int) -> DriveState:
    """The power state a statusword reports."""
    sw = int(statusword)
    for mask, state in _STATE_MASKS:
        if sw & mask == state.value:
            return state
    raise HardwareError(f"statusword 0x{sw:04X} matches no CiA 402 state")


def encode_statusword(state: DriveState, extra_bits: int = 0) -> int:
    """The statusword of ``state`` with ``extra_bits`` (bits 4, 7, 9-15) set."""
    voltage = SW_VOLTAGE_ENABLED if state in _POWERED else 0
    return (state.value | voltage | SW_REMOTE | extra_bits) & 0xFFFF


_POWERED = frozenset(
    {
        DriveState.SWITCHED_ON,
        DriveState.OPERATION_ENABLED,
        DriveState.QUICK_STOP_ACTIVE,
        DriveState.FAULT_REACTION_ACTIVE,
    }
)


@dataclass(frozen=True)
class Obj:
    """One object of the drive's object dictionary that icenav uses."""

    index: int
    """Object index (sub-index 0)."""
    name: str
    """Name as in CiA 402 / CiA 301."""
    fmt: str
    """struct format of the value (little-endian)."""


OBJECTS: dict[str, Obj] = {
    o.name: o
    for o in (
        Obj(0x1001, "error_register", "<B"),
        Obj(0x1017, "producer_heartbeat_time", "<H"),
        Obj(0x603F, "error_code", "<H"),
        Obj(0x6040, "controlword", "<H"),
        Obj(0x6041, "statusword", "<H"),
        Obj(0x605A, "quick_stop_option_code", "<h"),
        Obj(0x6060, "modes_of_operation", "<b"),
        Obj(0x6061, "modes_of_operation_display", "<b"),
        Obj(0x6062, "position_demand_value", "<i"),
        Obj(0x6064, "position_actual_value", "<i"),
        Obj(0x6065, "following_error_window", "<I"),
        Obj(0x607A, "target_position", "<i"),
        Obj(0x607C, "home_offset", "<i"),
        Obj(0x607F, "max_profile_velocity", "<I"),
        Obj(0x6081, "profile_velocity", "<I"),
        Obj(0x6085, "quick_stop_deceleration", "<I"),
        Obj(0x6098, "homing_method", "<b"),
        Obj(0x60F4, "following_error_actual_value", "<i"),
    )
}
"""The CiA 301 / 402 objects icenav reads or writes, by name (positions in encoder counts,
velocities in counts/s)."""


@dataclass(frozen=True)
class Pdo:
    """A fixed PDO layout (as mapped in the EDS: 0x1600 / 0x1A00)."""

    cob_base: int
    """COB-ID without the node id (0x200 for RPDO1, 0x180 for TPDO1)."""
    objects: tuple[str, ...]
    """Mapped objects, in order (names of :data:`OBJECTS`)."""
    fmt: str
    """struct format of the whole payload."""

    def cob_id(self, node_id: int) -> int:
        """COB-ID of this PDO for ``node_id``."""
        return self.cob_base + node_id

    def pack(self, *values: int) -> bytes:
        """Payload for ``values`` (in the order of :attr:`objects`)."""
        return struct.pack(self.fmt, *values)

    def unpack(self, data: bytes | bytearray) -> tuple[int, ...]:
        """Values of a payload."""
        return struct.unpack(self.fmt, bytes(data))


RPDO1 = Pdo(0x200, ("controlword", "target_position"), "<Hi")
"""Master -> drive: controlword and target position (counts)."""
TPDO1 = Pdo(0x180, ("statusword", "position_actual_value"), "<Hi")
"""Drive -> master: statusword and actual position (counts)."""

EMCY_CODES: dict[int, str] = {
    0x0000: "error reset / no error",
    0x1000: "generic error",
    0x2310: "continuous over-current",
    0x3210: "DC link over-voltage",
    0x4210: "excess temperature (device)",
    0x5530: "EEPROM / hardware error",
    0x7305: "incremental sensor 1 fault (encoder)",
    0x8130: "life guard error or heartbeat error",
    0x8611: "following error",
    0xFF00: "device specific",
}
"""CiA 301 / 402 emergency (EMCY) error codes with their meaning (a selection)."""


def emcy_text(code: int) -> str:
    """Human-readable meaning of an EMCY / 0x603F error code."""
    if code in EMCY_CODES:
        return EMCY_CODES[code]
    for mask in (0xFFF0, 0xFF00, 0xF000):
        if code & mask in EMCY_CODES:
            return EMCY_CODES[code & mask]
    return "unknown error"

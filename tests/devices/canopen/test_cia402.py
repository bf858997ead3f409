"""The CiA 402 state machine table, controlword decoding and statusword coding."""

from __future__ import annotations

import itertools

import pytest

from icenav.devices.canopen import cia402
from icenav.devices.canopen.cia402 import Command, DriveState, decode_command, next_state

# Reference: CiA 402 "Command coding" table, written out bit by bit (independent of the
# if-chain in decode_command): (bit7, bit3, bit2, bit1, bit0) patterns, x = don't care.
REFERENCE_CODING = {
    Command.SHUTDOWN: "0x110",
    Command.SWITCH_ON: "00111",
    Command.ENABLE_OPERATION: "01111",
    Command.DISABLE_VOLTAGE: "0xx0x",
    Command.QUICK_STOP: "0x01x",
}


def _matches(cw: int, pattern: str) -> bool:
    bits = [(cw >> 7) & 1, (cw >> 3) & 1, (cw >> 2) & 1, (cw >> 1) & 1, cw & 1]
    return all(p == "x" or int(p) == b for p, b in zip(pattern, bits, strict=True))


def test_decode_command_agrees_with_the_coding_table_for_every_controlword() -> None:
    for cw in range(0, 0x200):
        if cw & 0x80:
            continue  # fault-reset bit: edge-triggered, tested separately
        expected = [c for c, p in REFERENCE_CODING.items() if _matches(cw, p)]
        assert [decode_command(cw, previous_controlword=0)] == expected, f"0x{cw:04X}"


def test_fault_reset_acts_on_the_rising_edge_only() -> None:
    assert decode_command(0x80, 0x00) is Command.FAULT_RESET
    assert decode_command(0x80, 0x80) is Command.NONE
    assert decode_command(0x8F, 0x0F) is Command.FAULT_RESET


def test_enable_sequence_reaches_operation_enabled() -> None:
    state = DriveState.SWITCH_ON_DISABLED
    for cw in (cia402.CW_SHUTDOWN, cia402.CW_SWITCH_ON, cia402.CW_ENABLE_OPERATION):
        state = next_state(state, decode_command(cw))
    assert state is DriveState.OPERATION_ENABLED


def test_no_command_leaves_fault_except_fault_reset() -> None:
    for command in Command:
        expected = (
            DriveState.SWITCH_ON_DISABLED if command is Command.FAULT_RESET else DriveState.FAULT
        )
        assert next_state(DriveState.FAULT, command) is expected


def test_only_enable_operation_reaches_operation_enabled() -> None:
    for state, command in itertools.product(DriveState, Command):
        if next_state(state, command) is DriveState.OPERATION_ENABLED and (
            state is not DriveState.OPERATION_ENABLED
        ):
            assert command is Command.ENABLE_OPERATION


def test_quick_stop_from_operation_enabled_and_back() -> None:
    s = next_state(DriveState.OPERATION_ENABLED, decode_command(cia402.CW_QUICK_STOP))
    assert s is DriveState.QUICK_STOP_ACTIVE
    assert next_state(s, Command.DISABLE_VOLTAGE) is DriveState.SWITCH_ON_DISABLED


@pytest.mark.parametrize("state", list(DriveState))
@pytest.mark.parametrize("extra", [0, 0x0400, 0x1000, 0x2000, 0x3480])
def test_statusword_round_trip(state: DriveState, extra: int) -> None:
    sw = cia402.encode_statusword(state, extra)
    assert cia402.decode_statusword(sw) is state
    assert sw & extra == extra


def test_statusword_values_of_the_standard() -> None:
    # Values from CiA 402 (bits 0-3, 5, 6), as canopen's BaseNode402 decodes them.
    assert cia402.encode_statusword(DriveState.OPERATION_ENABLED) & 0x6F == 0x27
    assert cia402.encode_statusword(DriveState.SWITCH_ON_DISABLED) & 0x4F == 0x40
    assert cia402.decode_statusword(0x0237) is DriveState.OPERATION_ENABLED
    assert cia402.decode_statusword(0x0218) is DriveState.FAULT


def test_pdo_layout_round_trip_and_cob_ids() -> None:
    data = cia402.RPDO1.pack(0x3F, -123456)
    assert len(data) == 6
    assert cia402.RPDO1.unpack(data) == (0x3F, -123456)
    assert cia402.RPDO1.cob_id(3) == 0x203
    assert cia402.TPDO1.cob_id(3) == 0x183


def test_emcy_text() -> None:
    assert cia402.emcy_text(0x8611) == "following error"
    assert cia402.emcy_text(0x2311) == "continuous over-current"
    assert cia402.emcy_text(0x0001) == "error reset / no error"


# ------------------------------------------------------------------ independent reference
_NAMES = {s: s.name.replace("_", " ") for s in DriveState}


def test_transitions_agree_with_canopens_state402_table() -> None:
    from canopen.profiles.p402 import State402

    for (src, dst), cw in State402.TRANSITIONTABLE.items():
        if src in ("START", "NOT READY TO SWITCH ON", "FAULT REACTION ACTIVE"):
            continue  # automatic transitions, not commanded
        state = next(s for s, n in _NAMES.items() if n == src)
        got = next_state(state, decode_command(cw, previous_controlword=0))
        assert _NAMES[got] == dst, f"{src} --0x{cw:04X}--> {dst}, table gives {got.name}"


def test_emulated_drive_follows_canopens_base_node_402() -> None:
    """canopen's own BaseNode402 (a master) walks the emulated drive's state machine."""
    import uuid

    import canopen
    from canopen.profiles.p402 import BaseNode402

    from icenav.devices.canopen.config import bundled_eds_path
    from icenav.devices.canopen.emulated_drive import EmulatedDriveSet

    channel = f"icenav-402-{uuid.uuid4().hex[:8]}"
    drives = EmulatedDriveSet(channel, node_ids=(7,))
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="virtual", channel=channel)
    try:
        node = BaseNode402(7, str(bundled_eds_path()))
        network.add_node(node)
        node.setup_402_state_machine(read_pdos=False)  # controlword / statusword by SDO
        node.state = "OPERATION ENABLED"
        assert drives[7].state is DriveState.OPERATION_ENABLED
        node.state = "QUICK STOP ACTIVE"
        assert drives[7].state is DriveState.QUICK_STOP_ACTIVE
        node.state = "SWITCH ON DISABLED"
        assert drives[7].state is DriveState.SWITCH_ON_DISABLED
        drives[7].inject_fault(0x4210)
        assert node.is_faulted()
        assert node.sdo[0x603F].raw == 0x4210
        node.reset_from_fault()  # canopen's fault reset ends in OPERATION ENABLED
        assert drives[7].state is DriveState.OPERATION_ENABLED
        assert node.sdo[0x603F].raw == 0
    finally:
        network.disconnect()
        drives.close()

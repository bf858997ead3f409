"""The mode machine: one table, the only writer of the mode; FAULT and ESTOP left only by a
reset; a reset asked before the latest e-stop never clears it."""

from __future__ import annotations

import pytest

from icenav.control.modes import AUTOMATIC, HALTED, TELEOP, TRANSITIONS, Mode, ModeMachine, Via
from icenav.errors import InvalidValueError


def test_faults_and_estops_are_left_only_by_a_reset() -> None:
    for (mode, via), targets in TRANSITIONS.items():
        if mode in HALTED:
            assert via in (Via.ESTOP, Via.RESET), (mode, via)
            assert targets == ({Mode.ESTOP} if via is Via.ESTOP else {Mode.IDLE})
        assert (mode, Via.ESTOP) in TRANSITIONS  # an e-stop from every mode
    for mode in TELEOP | AUTOMATIC:
        assert (mode, Via.RESET) not in TRANSITIONS
    assert TRANSITIONS[(Mode.ESTOP, Via.RESET)] == {Mode.IDLE}
    assert (Mode.ESTOP, Via.FAULT) not in TRANSITIONS  # a fault never replaces an e-stop


def test_requests_in_a_halt_are_refused_with_the_cause() -> None:
    changes = []
    m = ModeMachine(on_change=changes.append)
    assert m.go(Mode.KNOB, Via.REQUEST) is None and m.mode is Mode.KNOB
    m.estop("EMERGENCY STOP by browser-2", seq=5)
    for to, via in [(Mode.IDLE, Via.REQUEST), (Mode.GOTO_VIEW, Via.START), (Mode.IDLE, Via.END)]:
        reason = m.go(to, via)
        assert reason is not None and "ESTOP" in reason and "browser-2" in reason
    assert m.mode is Mode.ESTOP and m.cause == "EMERGENCY STOP by browser-2"
    assert not m.fault("drive 3 overcurrent") and m.mode is Mode.ESTOP
    assert [c.new for c in changes] == [Mode.KNOB, Mode.ESTOP]
    with pytest.raises(InvalidValueError, match="use estop"):
        m.go(Mode.IDLE, Via.RESET)


def test_a_reset_older_than_the_latest_estop_is_refused() -> None:
    m = ModeMachine()
    m.estop("first", seq=3)
    m.estop("second", seq=9)
    assert "an e-stop came after" in (m.reset(seq=7) or "")
    assert m.mode is Mode.ESTOP
    assert m.reset(seq=10) is None and m.mode is Mode.IDLE and m.cause == ""
    assert "nothing to reset" in (m.reset(seq=11) or "")


def test_the_first_fault_cause_stays() -> None:
    m = ModeMachine()
    assert m.fault("heartbeat lost on node 3")
    assert not m.fault("something later")
    assert m.mode is Mode.FAULT and m.cause == "heartbeat lost on node 3"
    m.estop("operator", seq=1)  # an e-stop during a fault
    assert m.mode is Mode.ESTOP

"""Authorization in one place: who may send what, in the Python API (the console's browser
test does it in a real Chromium)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.control.authorization import TokenGate
from icenav.control.commands import Outcome, SaveView, Source
from icenav.control.controller import Controller, ControllerConfig
from icenav.control.modes import Mode
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot


def make() -> Controller:
    return Controller(SimulatedRobot(IdealPlant()), ControllerConfig())


def outcome(ticket: object) -> tuple[str, str]:
    r = ticket.final(timeout=0)  # type: ignore[attr-defined]
    return r.outcome.value, r.reason


def test_each_state_changing_command_from_a_non_holder_is_refused_and_logged() -> None:
    events: list[tuple[str, dict[str, object]]] = []
    ctrl = make()
    ctrl.set_recorder(lambda e, p: events.append((e, p)))
    assert ctrl.acquire_control("browser-1")
    ctrl.save_view("a", client="browser-1")
    ctrl.step()
    b = "browser-2"
    tickets = [
        ctrl.jog([0.5, 0, 0, 0], "knob", client=b),
        ctrl.request_mode(Mode.KNOB, client=b),
        ctrl.goto_view("a", client=b),
        ctrl.save_view("b", client=b),
        ctrl.rename_view("a", "c", client=b),
        ctrl.delete_view("a", client=b),
        ctrl.start_spin(client=b),
        ctrl.start_calibration("dense", client=b),
        ctrl.set_compensation(False, client=b),
        ctrl.export("a", client=b),
        ctrl.reset_fault(client=b),
    ]
    ctrl.step()
    for t in tickets:
        out, why = outcome(t)
        assert out == "refused" and "browser-1 holds control" in why, (t, why)
    assert [v.name for v in ctrl.views] == ["a"] and ctrl.mode is Mode.IDLE
    refused = [p for e, p in events if e == "command" and p["outcome"] == "refused"]
    assert len(refused) == len(tickets) and all(p["client"] == b for p in refused)


def test_stop_and_estop_from_anyone_and_a_reset_by_a_non_holder_keeps_the_estop() -> None:
    ctrl = make()
    assert ctrl.acquire_control("browser-1")
    ctrl.estop("browser-2")
    reset = ctrl.reset_fault(client="browser-2")
    ctrl.step()
    assert outcome(reset)[0] == "refused" and ctrl.mode is Mode.ESTOP
    stop = ctrl.stop(client="browser-2")
    ctrl.step()
    assert outcome(stop)[0] == "done"
    ok = ctrl.reset_fault(client="browser-1")
    ctrl.step()
    assert outcome(ok)[0] == "done" and ctrl.mode is Mode.IDLE


def test_view_only_clients_may_only_stop_and_are_told_why() -> None:
    ctrl = make()
    ctrl.set_view_only("browser-9", True)
    assert not ctrl.acquire_control("browser-9")
    t = ctrl.submit(SaveView("x", source=Source("console", "browser-9")))
    ctrl.step()
    out, why = outcome(t)
    assert out == "refused" and "view only" in why and "token" in why
    stop = ctrl.stop("browser-9")
    ctrl.step()
    assert outcome(stop)[0] == "done"


def test_free_control_is_taken_by_the_first_state_changing_command() -> None:
    ctrl = make()
    t = ctrl.jog([0.2, 0, 0, 0], "knob", client="igtl-slicer")
    ctrl.step()
    assert outcome(t)[0] == "done" and ctrl.snapshot().control_owner == "igtl-slicer"
    assert not ctrl.acquire_control("browser-1")


def test_a_command_asked_before_a_release_cannot_take_control_back() -> None:
    ctrl = make()
    assert ctrl.acquire_control("browser-1")
    jog = ctrl.jog([0.5, 0, 0, 0], "knob", client="browser-1")
    ctrl.release_control("browser-1")
    ctrl.step()
    out, why = outcome(jog)
    assert out == "refused" and "released control" in why
    assert ctrl.snapshot().control_owner is None
    assert np.all(ctrl.robot.read_state().q == 0)


def test_the_holder_disconnecting_stops_what_it_started() -> None:
    ctrl = make()
    assert ctrl.acquire_control("browser-1")
    ctrl.save_view("home", client="browser-1")
    for _ in range(60):
        ctrl.jog([math.radians(50), 0, 0, 2.0], "knob", client="browser-1")
        ctrl.step()
    goto = ctrl.goto_view("home", client="browser-1")
    ctrl.run_cycles(5)
    assert ctrl.mode is Mode.GOTO_VIEW
    ctrl.disconnect("browser-1")
    ctrl.step()
    held = ctrl.robot.read_state().q.copy()
    ctrl.run_cycles(20)
    np.testing.assert_array_equal(ctrl.robot.read_state().q, held)
    out, why = outcome(goto)
    assert out == "failed" and "browser-1 disconnected" in why
    assert ctrl.mode is Mode.IDLE and ctrl.snapshot().control_owner is None


def test_token_gate_is_rate_limited_with_an_alarm() -> None:
    t = [0.0]
    alarms: list[str] = []
    gate = TokenGate("s3cret-token-0123456789", clock=lambda: t[0], on_alarm=alarms.append)
    for _ in range(3):
        assert not gate.check("browser-1", "guess").ok
    v = gate.check("browser-1", "guess")
    assert not v.ok and "next try in 1 s" in v.reason and len(alarms) == 1
    blocked = gate.check("browser-1", "s3cret-token-0123456789")  # uncompared while waiting
    assert not blocked.ok and "wait" in blocked.reason
    t[0] += 1.5
    assert gate.check("browser-1", "s3cret-token-0123456789").ok
    assert gate.check("browser-2", "s3cret-token-0123456789").ok  # per client
    for k in range(20):  # many clients (reconnecting): the global limit
        gate.check(f"browser-{100 + k}", "guess")
    assert not gate.check("browser-3", "s3cret-token-0123456789").ok
    assert any("from all clients" in a for a in alarms)
    t[0] += 61.0
    assert gate.check("browser-3", "s3cret-token-0123456789").ok


@pytest.mark.parametrize("bad", [Outcome.REFUSED])
def test_outcome_names_are_the_contract(bad: Outcome) -> None:
    assert {o.name for o in Outcome} == {"ACCEPTED", "REFUSED", "DONE", "FAILED"}
    assert bad.value == "refused"

"""Commands as data: validation where they are made, tickets that report the decision and
the end, the event log of every outcome (the contract the OpenIGTLink server codes against)."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from icenav.control.commands import (
    GoToView,
    Jog,
    Outcome,
    SaveView,
    Source,
)
from icenav.control.controller import Controller, ControllerConfig
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.errors import CommandTimeoutError, InvalidValueError


def make() -> Controller:
    return Controller(SimulatedRobot(IdealPlant()), ControllerConfig())


def test_commands_are_checked_where_they_are_made() -> None:
    with pytest.raises(InvalidValueError, match="jog takes frame"):
        Jog(np.zeros(3), "knob")
    with pytest.raises(InvalidValueError, match="finite"):
        Jog(np.array([math.nan, 0, 0, 0]), "knob")
    with pytest.raises(InvalidValueError, match="kind must be one of"):
        Source("robot", "x")
    with pytest.raises(InvalidValueError, match="client must be a string"):
        Source("script", "")
    assert Source.of("browser-3").kind == "console" and Source.of("igtl-1").kind == "igtl"
    assert Source.of("gamepad").kind == "gamepad" and Source.of("lab").kind == "script"


def test_a_ticket_reports_the_decision_then_the_end_and_the_log_has_both() -> None:
    events: list[dict[str, object]] = []
    ctrl = make()
    ctrl.set_recorder(lambda e, p: events.append(p) if e == "command" else None)
    for _ in range(40):
        ctrl.jog([0.5, 0.0, 0.0, 2.0], "knob")
        ctrl.step()
    ctrl.save_view("v")
    ctrl.step()
    for _ in range(40):
        ctrl.jog([-0.5, 0.0, 0.0, -2.0], "knob")
        ctrl.step()
    ctrl.release_control("script")  # the script's jogs took control: give it to Slicer
    decided: list[Outcome] = []
    ticket = ctrl.submit(GoToView("v", source=Source("igtl", "igtl-slicer")))
    ticket.add_callback(lambda r: decided.append(r.outcome), when="decided")
    with pytest.raises(CommandTimeoutError, match="was not decided within 0.01 s"):
        ticket.result(timeout=0.01)  # stepped by hand: nothing decides until step()
    ctrl.step()
    assert ticket.result(timeout=0).outcome is Outcome.ACCEPTED and decided == [Outcome.ACCEPTED]
    assert not ticket.finished
    ctrl.run_until(lambda s: ticket.finished, 5000)
    final = ticket.final(timeout=0)
    assert final.outcome is Outcome.DONE and "go to view 'v': done" in final.reason
    goto = [e for e in events if str(e["command"]).startswith("go_to_view")]
    assert [e["outcome"] for e in goto] == ["accepted", "done"]
    assert goto[0]["kind"] == "igtl" and goto[0]["client"] == "igtl-slicer"
    jogs = [e for e in events if e["command"] == "jog knob"]
    assert len(jogs) == 1  # a stream of jogs is logged when its outcome changes


def test_result_wakes_a_waiting_thread_when_the_loop_decides() -> None:
    ctrl = make()
    ticket = ctrl.submit(SaveView("from-a-thread"))
    got: list[Outcome] = []
    waiter = threading.Thread(target=lambda: got.append(ticket.final(timeout=30).outcome))
    waiter.start()
    ctrl.step()
    waiter.join(30)
    assert got == [Outcome.DONE]

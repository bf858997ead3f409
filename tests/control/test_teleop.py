"""The gamepad's buttons: edges become the commands every adapter sends."""

from __future__ import annotations

from typing import Any

from icenav.control.commands import GAMEPAD, GoToView, RefineView, SaveView
from icenav.control.controller import Controller, ControllerConfig
from icenav.control.modes import Mode
from icenav.control.teleop import GamepadReader, JoystickMapping
from icenav.devices.gamepad import Keyframe, ScriptedInput
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from tests.support.clock import Clock

M = JoystickMapping()


def reader(keyframes: list[Keyframe], clock: Clock) -> GamepadReader:
    return GamepadReader(ScriptedInput(keyframes, clock=clock), M, watchdog_s=0.2, clock=clock)


def test_view_buttons_act_on_their_edge_only() -> None:
    clock = Clock()
    pad = reader(
        [
            Keyframe(0.0, buttons=(M.save_view_button,)),
            Keyframe(0.1, buttons=(M.goto_view_button,)),
            Keyframe(0.2, buttons=(M.refine_view_button,)),
        ],
        clock,
    )
    seen: list[Any] = []
    for i in range(30):  # 0.3 s at 100 Hz: each button held for 10 readings
        clock.t = i * 0.01
        seen += pad.read(Mode.IDLE, None, 2, "aortic").commands
    # commands compare by identity (each carries its own ticket state): compare what they ask
    assert [(type(c), c.view, c.source) for c in seen] == [
        (SaveView, "view 3", GAMEPAD),
        (GoToView, "aortic", GAMEPAD),
        (RefineView, "aortic", GAMEPAD),
    ]


def test_go_to_and_refine_need_a_selected_view() -> None:
    clock = Clock()
    pad = reader([Keyframe(0.0, buttons=(M.goto_view_button, M.refine_view_button))], clock)
    assert pad.read(Mode.IDLE, None, 0, None).commands == ()


def test_the_loop_decides_the_gamepads_refine_for_the_view_it_saved() -> None:
    clock = Clock()
    robot = SimulatedRobot(IdealPlant(), clock=clock)
    script = [
        Keyframe(0.0, buttons=(M.enable_button, M.save_view_button)),
        Keyframe(0.1, buttons=(M.enable_button,)),
        Keyframe(0.2, buttons=(M.enable_button, M.refine_view_button)),
    ]
    ctrl = Controller(
        robot, ControllerConfig(), input_source=ScriptedInput(script, clock=clock), clock=clock
    )
    events: list[dict[str, Any]] = []
    ctrl.set_recorder(lambda kind, payload: events.append(payload) if kind == "command" else None)
    for _ in range(40):
        clock.t += ctrl.config.dt
        ctrl.step()
    refines = [e for e in events if e["command"].startswith("refine")]
    assert [e["client"] for e in refines] == [GAMEPAD.client]
    assert "view 1" in refines[0]["command"]
    # no EM tracker on this robot: the loop refuses and says why
    assert refines[0]["outcome"] != "ok" and refines[0]["reason"]

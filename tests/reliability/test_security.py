"""Security defaults: loopback binding, OpenIGTLink commands off unless enabled, a token for
commands when exposed, and client strings that never become paths."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from icenav.errors import InvalidValueError
from icenav.io.igtl import (
    IgtlBridge,
    IgtlCommand,
    IgtlConfig,
    IgtlOutcome,
    IgtlReply,
    IgtlRequest,
)
from tests.support.console import FakeClient

TOKEN = "s3cret-token-0123456789"
PEER = "127.0.0.1:40000"


def _bridge(config: IgtlConfig) -> tuple[IgtlBridge, list[IgtlRequest]]:
    """A real bridge (port 0) whose command callback records and accepts."""
    got: list[IgtlRequest] = []

    def sink(request: IgtlRequest) -> IgtlReply:
        got.append(request)
        return IgtlReply(IgtlOutcome.ACCEPTED)

    return IgtlBridge(config, on_command=sink), got


def test_defaults_bind_loopback_and_accept_no_commands() -> None:
    from icenav.apps.demo import _parser
    from icenav.console.app import Console

    cfg = IgtlConfig()
    assert cfg.local_only and cfg.accepted_commands == frozenset() and cfg.token == ""
    assert inspect.signature(Console).parameters["host"].default == "127.0.0.1"
    assert _parser().parse_args([]).host == "127.0.0.1"


def test_real_bridge_listens_on_loopback_only() -> None:
    with IgtlBridge(IgtlConfig(port=0)) as bridge:
        assert bridge.host == "127.0.0.1"
        bridge.handle_line("stop", 0.0, PEER)
        (record,) = bridge.command_log  # commands are off by default
        assert record.outcome is IgtlOutcome.REFUSED and "not enabled" in record.reason


def test_commands_need_the_token_when_one_is_set() -> None:
    bridge, got = _bridge(IgtlConfig(port=0, accepted_commands=frozenset(IgtlCommand), token=TOKEN))
    with bridge:
        for text in ["stop", "wrong stop", f"{TOKEN}x stop", f" {TOKEN[:-1]} stop"]:
            bridge.handle_line(text, 0.0, PEER)
        assert got == []
        assert all(r.command == "<redacted>" for r in bridge.command_log)  # never logged
        assert all(TOKEN[:8] not in r.reason for r in bridge.command_log)
        bridge.handle_line(f"{TOKEN} go_to_view apex", 1.0, PEER)
        assert got == [IgtlRequest(IgtlCommand.GO_TO_VIEW, "apex", 1.0, PEER)]


def test_token_guesses_are_limited_per_host() -> None:
    bridge, got = _bridge(IgtlConfig(port=0, accepted_commands=frozenset(IgtlCommand), token=TOKEN))
    with bridge:
        for k in range(5):
            bridge.handle_line(f"guess{k} stop", 0.0, f"10.0.0.9:{k}")
        # the sixth try from that host is refused unchecked, even with the right token
        bridge.handle_line(f"{TOKEN} stop", 0.0, "10.0.0.9:99")
        assert got == []
        assert "too many wrong tokens from 10.0.0.9" in bridge.command_log[-1].reason
        bridge.handle_line(f"{TOKEN} stop", 0.0, "10.0.0.7:1")  # another host is not held
        assert [r.command for r in got] == [IgtlCommand.STOP]


def test_exposed_bridge_with_commands_needs_a_strong_token() -> None:
    cmds = frozenset({IgtlCommand.STOP})
    with pytest.raises(InvalidValueError, match="need a token of >= 16 characters"):
        IgtlConfig(local_only=False, accepted_commands=cmds)
    with pytest.raises(InvalidValueError, match="need a token"):
        IgtlConfig(local_only=False, accepted_commands=cmds, token="short")
    with pytest.raises(InvalidValueError, match="must not contain spaces"):
        IgtlConfig(token="two words here!!")
    IgtlConfig(local_only=False, accepted_commands=cmds, token=TOKEN)  # accepted
    IgtlConfig(local_only=False)  # streaming only, no commands: no token needed


def test_view_names_from_igtl_are_passed_as_data() -> None:
    bridge, got = _bridge(IgtlConfig(port=0, accepted_commands=frozenset(IgtlCommand)))
    with bridge:
        bridge.handle_line("save_view ../../../tmp/evil", 0.0, PEER)
    assert got[0].argument == "../../../tmp/evil"  # a name; the controller never opens it


# ------------------------------------------------------------------ the console's token


def test_console_browser_needs_the_token_to_control_but_not_to_stop() -> None:
    from icenav.console.app import Console
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.control.state import Mode
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    console = Console(ctrl, host="0.0.0.0", port=0, control_token=TOKEN)
    console._on_connect(FakeClient(1))  # noqa: SLF001 - the connection handler, no server
    panel = console._panels[1]  # noqa: SLF001
    ctrl.step()
    assert ctrl.snapshot().control_owner is None  # not taken on connect without the token
    panel.spin.click()
    panel.save.click()
    assert ctrl.step().mode is Mode.IDLE and ctrl.snapshot().views == ()
    assert panel.token is not None
    panel.token.value = "guess"
    panel.take.click()
    assert ctrl.step().control_owner is None and "wrong control token" in panel.note.content
    panel.token.value = TOKEN
    panel.take.click()
    state = ctrl.step()
    assert state.control_owner == panel.name
    panel.save.click()
    assert [v.name for v in ctrl.step().views] == ["view-1"]  # a refused save keeps the name
    # a second browser without the token can still stop everything
    console._on_connect(FakeClient(2))  # noqa: SLF001
    other = console._panels[2]  # noqa: SLF001
    assert not other.authorised
    assert ctrl.acquire_control(other.name) is False  # view only: the controller refuses
    console._reset_for(other)  # noqa: SLF001 - the safety bar's Reset, from that browser:
    # a view-only reset is refused by the controller, and told why
    ctrl.step()
    assert "view only" in other.feedback_text
    ctrl.estop(client=other.name)
    assert ctrl.step().mode is Mode.ESTOP


def test_console_on_loopback_needs_no_token() -> None:
    from icenav.apps.demo import control_token_for
    from icenav.console.app import Console
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    assert control_token_for("127.0.0.1") is None
    t1, t2 = control_token_for("0.0.0.0"), control_token_for("0.0.0.0")
    assert t1 and t2 and t1 != t2 and len(t1) >= 16
    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    console = Console(ctrl, port=0)
    console._on_connect(FakeClient(1))  # noqa: SLF001
    assert console._panels[1].token is None and console._panels[1].authorised  # noqa: SLF001
    assert ctrl.step().control_owner == console._panels[1].name  # noqa: SLF001


def test_console_disconnect_mid_jog_releases_control_and_the_robot_stops() -> None:
    """(A fault test, here beside the fake viser client it needs.)"""
    import numpy as np

    from icenav.console.app import Console
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    console = Console(ctrl, port=0)
    client = FakeClient(7)
    console._on_connect(client)  # noqa: SLF001
    panel = console._panels[7]  # noqa: SLF001
    assert ctrl.step().control_owner == panel.name
    q0 = ctrl.snapshot().q_motor.copy()
    ctrl.jog([0.0, 0.0, 0.0, 2.0], "knob", client=panel.name)  # what a held jog button sends
    ctrl.run_cycles(2)  # the encoders show the command one cycle later
    assert not np.array_equal(ctrl.snapshot().q_motor, q0)
    console._last_state = ctrl.snapshot()  # noqa: SLF001 - what the refresh thread keeps
    console._on_disconnect(client)  # noqa: SLF001 - the browser tab is closed mid-jog
    ctrl.step()
    held = ctrl.step().q_motor.copy()
    for _ in range(30):
        np.testing.assert_array_equal(ctrl.step().q_motor, held)
    assert ctrl.snapshot().control_owner is None and 7 not in console._panels  # noqa: SLF001


def test_console_export_of_a_saved_view_stays_in_the_export_directory(tmp_path: Path) -> None:
    """The Export DICOM button on the real controller (twin with its ultrasound image): a
    view named like a path is written as a program-made name inside the export directory,
    with the pose and image the controller saved with it."""
    import numpy as np

    from icenav.apps.wiring import make_sim_controller
    from icenav.console.app import Console
    from icenav.persistence.dicom import read_view_clip

    session = make_sim_controller(seed=0)
    ctrl = session.controller
    try:
        exports = tmp_path / "session" / "exports"
        console = Console(ctrl, host="0.0.0.0", port=0, control_token=TOKEN, export_dir=exports)
        console._on_connect(FakeClient(1))  # noqa: SLF001
        panel = console._panels[1]  # noqa: SLF001
        ctrl.run_cycles(3)
        panel.view_name.value = "../../outside"
        panel.save.click()  # no token yet: dropped
        assert ctrl.step().views == ()
        panel.token.value = TOKEN
        panel.take.click()
        panel.save.click()
        (view,) = ctrl.step().views
        assert view.name == "../../outside" and view.has_image
        panel.views.value = view.name
        panel.export.click()
        ctrl.step()  # the controller decides the export
        console._serve_panels()  # noqa: SLF001 - the refresh thread writes it
        written = [p for p in tmp_path.rglob("*") if p.is_file()]
        assert len(written) == 1 and written[0].parent == exports
        assert str(written[0]) in panel.export_note.content
        clip = read_view_clip(written[0])
        saved = ctrl.views.get(view.name)
        assert clip.view_name == view.name
        np.testing.assert_array_equal(clip.q_motor, saved.q)
        np.testing.assert_array_equal(clip.tip2base, saved.tip2base)
        image = ctrl.view_image(view.name)
        assert image is not None
        np.testing.assert_array_equal(clip.frames[0], image.pixels)
    finally:
        session.close()

"""Tests of the console server without a browser, against a recording test double.

``RecordingController`` (tests/support/console.py) is a test double of the
ControllerCommands protocol: it records the commands it gets, decides them with the
controller's own authorization, and publishes the states a test gives it. It does no
control; the browser test drives the real ``icenav.control.controller.Controller``.
"""

from __future__ import annotations

import asyncio
import threading
import urllib.request
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pydicom
import pytest

from icenav.console import Console, ConsoleConfig
from icenav.control.commands import Source
from icenav.control.state import ControllerCommands, ImageFrame, Mode, ViewSummary
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import forward
from icenav.persistence.dicom import PRIVATE_CREATOR, read_view_clip
from tests.support.clock import Clock
from tests.support.console import FakeClient, RecordingController, WireClient, make_state


def test_recording_controller_satisfies_the_protocol() -> None:
    ctl: ControllerCommands = RecordingController()  # mypy checks the structural match
    assert ctl.snapshot().mode is Mode.IDLE


@pytest.fixture
def console() -> Any:
    ctl = RecordingController()
    # a huge refresh period: the test drives refresh_once() itself, the thread never draws
    c = Console(ctl, port=0, refresh_hz=0.01)
    c.start()
    yield c
    c.stop()


def test_console_serves_the_viser_client_on_a_free_port(console: Console) -> None:
    assert console.port > 0
    assert console.url == f"http://127.0.0.1:{console.port}"
    with urllib.request.urlopen(console.url, timeout=10) as resp:
        body = resp.read().decode("utf-8", "replace")
    assert resp.status == 200 and "<html" in body.lower()


def test_refresh_draws_the_newest_state_only(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    assert console.refresh_once() is True  # the snapshot offered at start
    assert console.refresh_once() is False  # nothing new
    q = np.array([0.3, 0.1, 0.2, 7.0])
    for k in range(5):
        ctl.publish(make_state(q, cycle=k, time=0.01 * k, n_vertices=k, mode=Mode.KNOB))
    assert console.refresh_once() is True
    stats = console.stats()
    assert stats.states_offered == 6 and stats.refreshes == 2  # 4 of 5 coalesced
    status = console._status.content
    assert "Jogging the knobs" in status and "4 vertices" in status and "VALID" in status
    # scene follows the state: tip frame at the true tip, in metres
    np.testing.assert_allclose(console.scene.tip_true.position, forward(q)[:3, 3] * 1e-3, atol=1e-9)
    assert console.scene.sensor.visible
    ctl.publish(make_state(q, cycle=9, time=0.1, sensor2base=None, tracker_status="MISSING"))
    console.refresh_once()
    assert not console.scene.sensor.visible
    assert "MISSING" in console._status.content


def test_status_and_plot_refresh_at_status_hz() -> None:
    ctl = RecordingController()
    c = Console(ctl, port=0, refresh_hz=30.0, status_hz=10.0)  # every 3rd refresh
    with c:
        c._stop.set()  # the test refreshes by itself
        c.refresh_once()  # refresh 0: drawn
        for k in range(1, 7):
            ctl.publish(make_state(cycle=k, time=1.0 * k))
            c.refresh_once()
            drawn = f"Running for** {1.0 * k:.1f} s" in c._status.content
            assert drawn == (k % 3 == 0), (k, c._status.content[:200])
        ctl.publish(make_state(cycle=7, time=7.0, mode=Mode.KNOB))  # a mode change: at once
        c.refresh_once()
        assert "Jogging the knobs" in c._status.content


def test_jog_button_sends_the_mode_s_jog_only_with_control(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    panel = SimpleNamespace(
        name="browser-7",
        can_control=False,
        enabled=False,
        source=Source("console", "browser-7"),
        tell=lambda *a: None,
        clear=lambda *a: None,
    )
    hold = console._jog_hold(panel, 2, -1)
    release = console._jog_release(panel)
    ctl.publish(make_state(mode=Mode.TIP))
    console.refresh_once()
    asyncio.run(hold(None))
    asyncio.run(release(None))
    assert not [c for c in ctl.calls if c[0] == "jog"]  # view only: nothing sent
    panel.can_control = panel.enabled = True
    asyncio.run(hold(None))
    (vel, frame), client = ctl.wait_for_call("jog")
    assert frame == "tip" and client == "browser-7"
    assert vel[2] == -console.mapping.tip_speed and np.count_nonzero(vel) == 1
    asyncio.run(release(None))  # the release stops it with a zero jog at once
    assert np.count_nonzero(ctl.calls[-1][1][0]) == 0 and ctl.calls[-1][1][1] == "tip"
    for mode in (Mode.IDLE, Mode.GOTO_VIEW):  # outside tip mode: the knobs
        ctl.calls.clear()
        ctl.publish(make_state(mode=mode))
        console.refresh_once()
        asyncio.run(hold(None))
        (vel, frame), _ = ctl.wait_for_call("jog")
        assert frame == "knob" and vel[2] == -console.mapping.roll_rate
        asyncio.run(release(None))


def _jogs(ctl: RecordingController) -> list[str]:
    """The jog commands the double got, in order: "move" or "zero"."""
    with ctl.call_event:
        return ["zero" if not np.any(c[1][0]) else "move" for c in ctl.calls if c[0] == "jog"]


def _wait_jogs(ctl: RecordingController, done: Any, what: str) -> list[str]:
    with ctl.call_event:
        ok = ctl.call_event.wait_for(lambda: done(_jogs(ctl)), timeout=10.0)
    assert ok, f"{what}: the jogs were {_jogs(ctl)}"
    return _jogs(ctl)


def test_a_page_s_holds_release_and_lost_release_over_viser_s_websocket() -> None:
    """A page's hold and click messages through the real viser server (no browser): holds
    sent back to back with the click end in the zero jog, never a jog after it (the
    callbacks run in the order the page sent them); holds that stop (a lost release) meet
    the dead-man, which sends the zero jog, and nothing moves after it; the next press
    jogs again. A later message's callback (Release control) marks that every earlier
    message was handled."""
    ctl = RecordingController()
    c = Console(ctl, port=0, refresh_hz=0.01, config=ConsoleConfig(jog_deadman_s=0.15))
    c.start()
    w = WireClient(c.port)
    try:
        w.become_browser()
        w.until(
            lambda w: any(p.get("label") == "AP knob (phi1) +" for p in w.props.values()), "jog"
        )
        ctl.wait_for_call("acquire_control")
        ctl.publish(make_state())
        c.refresh_once()
        (panel,) = c._panels.values()
        assert panel.can_control
        button = panel.jog_buttons[1][0]
        for _ in range(5):
            w.hold(button, c.jog_hz)
        w.click(button)
        w.click(panel.release)  # the marker: handled after everything above
        ctl.wait_for_call("release_control")
        jogs = _wait_jogs(ctl, lambda j: j and j[-1] == "zero", "the release")
        assert jogs[0] == "move" and jogs.count("zero") == 1
        assert c.jog.held() == set()
        # a lost release: the holds stop, the dead-man sends the zero jog
        ctl.calls.clear()
        c.jog.events.clear()
        w.hold(button, c.jog_hz)
        _wait_jogs(ctl, lambda j: "zero" in j, "the dead-man's stop")
        assert [e.what for e in c.jog.events][:2] == ["press", "pause"]
        ctl.calls.clear()
        w.click(panel.take)  # the marker
        ctl.wait_for_call("acquire_control")
        assert _jogs(ctl) == [] and c.jog.held() == set()
        assert "Jog paused" in panel.feedback_text
        w.click(button)  # the (late) pointer-up; the next press jogs
        w.hold(button, c.jog_hz)
        assert _wait_jogs(ctl, bool, "the next press")[0] == "move"
        w.click(button)
        _wait_jogs(ctl, lambda j: j[-1] == "zero", "its release")
    finally:
        w.close()
        c.stop()


def test_the_jog_callbacks_run_on_viser_s_event_loop_in_message_order(console: Console) -> None:
    """viser runs ``async`` callbacks on its event loop in message order and plain ones in
    a thread pool in no set order: the jog's hold and release must be ``async``."""
    import inspect

    client = FakeClient(0)
    console._on_connect(client)
    panel = console._panels[0]
    for b, _, _ in panel.jog_buttons:
        assert b.callbacks and all(inspect.iscoroutinefunction(cb) for cb in b.callbacks)


def test_progress_bar_follows_state_progress(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    ctl.publish(make_state(mode=Mode.CALIBRATING, progress=0.4, progress_label="dense"))
    console.refresh_once()
    assert console._progress.visible and console._progress.value == pytest.approx(40.0)
    assert "dense: 40 %" in console._progress_label.content
    ctl.publish(make_state(mode=Mode.IDLE, progress=None))
    console.refresh_once()
    assert not console._progress.visible


def test_image_is_sent_once_per_new_frame(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    console.refresh_once()
    assert console._image_placeholder.visible and not console._image.visible
    rng = np.random.default_rng(0)
    for k in range(3):
        ctl.image = ImageFrame(rng.integers(0, 255, (64, 48), dtype=np.uint8), 0.05 * k)
        console.refresh_once()
        console.refresh_once()  # same frame again: not re-sent
    assert console.stats().images_sent == 3
    assert console._image.visible and not console._image_placeholder.visible
    assert console.scene.image is None  # identity ijk2tip: placement unknown, panel only


def test_image_with_placement_is_drawn_in_its_plane(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    q = np.array([0.4, 0.1, -0.3, 6.0])
    ctl.publish(make_state(q, cycle=1, time=0.01))
    s = 0.5  # mm per pixel: row -> depth along tip x, column -> lateral along tip z
    ijk2tip = np.array([[0, s, 0, 0.25], [0, 0, 1, 0], [s, 0, 0, -31.75], [0, 0, 0, 1.0]])
    ctl.image = ImageFrame(np.zeros((128, 128), np.uint8), 0.01, ijk2tip)
    console.refresh_once()
    img = console.scene.image
    assert img is not None
    # the centre pixel (63.5, 63.5) maps to the plane centre (images up to 256 px: not resampled)
    expected = forward(q) @ ijk2tip @ np.array([63.5, 63.5, 0, 1])
    np.testing.assert_allclose(img.position, expected[:3] * 1e-3, atol=1e-9)
    assert img.render_width == pytest.approx(128 * s * 1e-3)


def test_view_markers_follow_the_library(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    console.refresh_once()
    q = np.array([0.2, 0.0, 0.0, 3.0])
    v = ViewSummary("apex", q, 0.0)
    ctl.publish(make_state(q, views=(v,), cycle=1, time=0.01))
    console.refresh_once()
    assert set(console.scene.marker_handles) == {"apex"}
    sphere, _ = console.scene.marker_handles["apex"]
    np.testing.assert_allclose(sphere.position, forward(q)[:3, 3] * 1e-3, atol=1e-9)
    ctl.publish(make_state(q, views=(), cycle=2, time=0.02))
    console.refresh_once()
    assert console.scene.marker_handles == {}


def test_console_settings_are_checked(tmp_path: Path) -> None:
    verts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0.0]])
    mesh = ("ra", verts, [[0, 1, 2]], (1, 2, 3), 0.3)
    c = Console(RecordingController(), port=0, anatomy_mesh=[mesh])
    assert c.anatomy[0].name == "ra"
    with pytest.raises(ConfigurationError, match="refresh_hz"):
        Console(RecordingController(), refresh_hz=0)
    with pytest.raises(ConfigurationError, match="max_roadmap_points"):
        Console(RecordingController(), max_roadmap_points=1)
    with pytest.raises(ConfigurationError, match="status_hz"):
        Console(RecordingController(), status_hz=-1)
    with pytest.raises(ConfigurationError, match="port"):
        Console(RecordingController(), port=70000)
    for token in ("", " padded "):
        with pytest.raises(ConfigurationError, match="control_token must be non-empty"):
            Console(RecordingController(), control_token=token)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigurationError, match="not a directory"):
        Console(RecordingController(), export_dir=tmp_path / "file")
    with pytest.raises(ConfigurationError, match="not started"):
        _ = c.url
    with c:  # the mesh goes into the scene (scene units: m)
        assert c.port > 0


def test_restart_draws_afresh() -> None:
    ctl = RecordingController()
    c = Console(ctl, port=0, refresh_hz=0.01)
    q = np.array([0.2, 0.0, 0.0, 3.0])
    ctl.publish(make_state(q, views=(ViewSummary("apex", q, 0.0),)))
    handles = []
    for _ in range(2):
        with c:
            c.refresh_once()
            assert set(c.scene.marker_handles) == {"apex"}
            handles.append(c.scene.marker_handles["apex"][0])
            assert c.last_error == ""
    assert handles[0] is not handles[1]  # redrawn on the new server, not stale handles


def test_listener_after_stop_is_inert() -> None:
    ctl = RecordingController()
    c = Console(ctl, port=0, refresh_hz=0.01)
    c.start()
    c.stop()
    n = c.stats().states_offered
    ctl.publish(make_state())
    assert c.stats().states_offered == n


@pytest.mark.parametrize(
    "name",
    [
        "icenav.console",
        "icenav.console.app",
        "icenav.console.scene",
        "icenav.console.scene_view",
        "icenav.console.display",
        "icenav.console.labels",
        "icenav.console.client_panel",
        "icenav.console.panels",
    ],
)
def test_all_is_sorted_and_resolves(name: str) -> None:
    import importlib

    module = importlib.import_module(name)
    exported = list(module.__all__)
    assert exported == sorted(exported), f"{name}.__all__ is not sorted"
    for member in exported:
        assert hasattr(module, member), f"{name}.{member} is in __all__ but missing"


# ------------------------------------------------------------------ DICOM export


def _view_with_image(ctl: RecordingController, name: str, q: np.ndarray) -> ImageFrame:
    """Give the double a saved view ``name`` at q, with its image (0.5 mm pixels)."""
    pixels = np.random.default_rng(3).integers(0, 255, (40, 30), dtype=np.uint8)
    ijk2tip = np.array([[0, 0.5, 0, 0], [0, 0, 1, 0], [0.5, 0, 0, -7.5], [0, 0, 0, 1.0]])
    frame = ImageFrame(pixels, 12.5, ijk2tip)
    ctl.view_images[name] = frame
    views = (*ctl.snapshot().views, ViewSummary(name, q, 1_795_000_000.25, True))
    ctl.publish(make_state(views=views))
    return frame


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file())


def test_export_button_writes_the_selected_view_into_the_export_directory(
    tmp_path: Path,
) -> None:
    ctl = RecordingController()
    exports = tmp_path / "session" / "exports"
    console = Console(ctl, port=0, export_dir=exports)
    console._on_connect(FakeClient(1))
    panel = console._panels[1]
    assert ctl.owner == panel.name and panel.export is not None  # no token: control at once
    q = np.array([0.3, -0.2, 0.4, 5.0])
    name = "../../../tmp/evil\\apex"  # a view name is data: it never becomes a path
    frame = _view_with_image(ctl, name, q)
    panel.views.value = name
    panel.export.click()
    console._serve_panels()  # the refresh thread writes accepted exports
    note = panel.export_note.content
    (path,) = _files(tmp_path)
    assert path.parent == exports and path.name.startswith("tmp_evil_apex_")
    assert note.startswith(f"Exported view **{name}** to `{path}`")  # where the file went

    ds = pydicom.dcmread(path)  # an independent reader
    assert ds.SOPClassUID == "1.2.840.10008.5.1.4.1.1.3.1" and int(ds.NumberOfFrames) == 1
    np.testing.assert_array_equal(ds.pixel_array, frame.pixels)
    block = ds.private_block(0x0011, PRIVATE_CREATOR)
    np.testing.assert_allclose(list(block[0x01].value), q)
    # the double has no view library: the pose is the model pose of the view's motor state
    np.testing.assert_allclose(np.reshape(block[0x02].value, (4, 4)), forward(q), atol=1e-12)
    assert float(ds.SequenceOfUltrasoundRegions[0].PhysicalDeltaX) == pytest.approx(0.05)  # cm
    assert ds.AcquisitionDateTime.startswith("20261118110640.25")  # created_s, in UTC
    assert read_view_clip(path).view_name == name


def test_export_is_refused_without_the_token_or_control(tmp_path: Path) -> None:
    ctl = RecordingController()
    exports = tmp_path / "exports"
    console = Console(ctl, port=0, control_token="s3cret-token-0123456789", export_dir=exports)
    console._on_connect(FakeClient(1))
    panel = console._panels[1]
    _view_with_image(ctl, "apex", np.zeros(4))
    panel.views.value = "apex"
    panel.export.click()
    console._serve_panels()  # the refresh thread writes accepted exports
    assert "Export refused" in panel.export_note.content and "token" in panel.export_note.content
    assert _files(tmp_path) == []
    # the token entered, but another client holds control: still refused
    ctl.owner = "gamepad"
    panel.token.value = "s3cret-token-0123456789"
    panel.take.click()
    ctl.publish(ctl.snapshot())
    panel.export.click()
    console._serve_panels()  # the refresh thread writes accepted exports
    assert "gamepad holds control" in panel.export_note.content and _files(tmp_path) == []
    # in control: a name that is not a saved view, and a view without an image, are refused
    ctl.owner = None
    panel.take.click()
    ctl.publish(ctl.snapshot())
    assert ctl.snapshot().control_owner == panel.name
    for value, why in [
        ("../../etc/passwd", "no saved view named '../../etc/passwd'"),
        ("/tmp/x.dcm", "no saved view named"),
    ]:
        panel.views.value = value  # what a tampered browser could send
        panel.export.click()
        console._serve_panels()  # the refresh thread writes accepted exports
        assert why in panel.export_note.content, panel.export_note.content
    views = (*ctl.snapshot().views, ViewSummary("blind", np.zeros(4), 0.0, False))
    ctl.publish(make_state(views=views))
    panel.views.value = "blind"
    panel.export.click()
    console._serve_panels()  # the refresh thread writes accepted exports
    assert "has no saved image" in panel.export_note.content
    assert _files(tmp_path) == []
    panel.views.value = "apex"
    panel.export.click()
    console._serve_panels()  # the refresh thread writes accepted exports
    assert len(_files(exports)) == 1 and "Exported view **apex**" in panel.export_note.content


def test_no_export_button_without_an_export_directory() -> None:
    console = Console(RecordingController(), port=0)
    console._on_connect(FakeClient(1))
    assert console._panels[1].export is None
    assert "Export is off" in console.export_view("apex")


def test_an_update_to_a_just_closed_browser_is_not_a_console_error() -> None:
    """A browser that closes between the refresh taking its panel and updating it makes viser
    warn that the update will not be delivered (an exception where warnings are errors):
    benign, not shown as a console error; any other failure is."""
    import threading
    import time

    ctl = RecordingController()
    c = Console(ctl, port=0, refresh_hz=100.0)
    raised = {"n": 0}
    message = ["Queued a GuiUpdateMessage on a closed connection; it will never be delivered."]
    done = threading.Event()

    def refresh() -> None:
        raised["n"] += 1
        if raised["n"] >= 5:
            done.set()
        if message[0].startswith("boom"):
            raise RuntimeError(message[0])
        raise UserWarning(message[0])

    with c:
        c.refresh_once = refresh  # type: ignore[method-assign]
        assert done.wait(5.0)
        assert c.last_error == ""
        message[0] = "boom: a real failure"
        deadline = time.monotonic() + 5.0
        while c.last_error == "" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert c.last_error == "RuntimeError: boom: a real failure"


def test_a_console_port_in_use_is_an_error_naming_it() -> None:
    import socket

    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
    from icenav.errors import ConfigurationError

    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        console = Console(ctrl, port=port)
        with pytest.raises(ConfigurationError, match=f"console port {port} on 127.0.0.1 is in use"):
            console.start()
        assert console._server is None  # noqa: SLF001 - nothing left serving elsewhere


# ---------------------------------------------------------------- the halt banner
ESTOP_BY = "e-stop by {}: reset to continue"


def _banner_shown(c: Console) -> bool:
    """The halt banner in the alarm area and its Reset button (enabled) as the page was
    sent them (the handles' state); the two never differ."""
    shown = "icenav-halt" in c._alarm.content
    assert c._reset.visible and c._reset.disabled is not shown  # Reset keeps its place
    return shown


def test_the_banner_follows_estops_and_resets_coalesced_between_draws(console: Console) -> None:
    """E-STOP, reset, E-STOP, fault landing between two draws: each draw shows the latest
    state only, with its cause."""
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    console.refresh_once()
    assert not _banner_shown(console)
    ctl.publish(make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-0")))
    console.refresh_once()
    assert _banner_shown(console) and "browser #0" in console._alarm.content
    ctl.publish(make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-1")))
    ctl.publish(make_state(mode=Mode.IDLE, message="reset by browser-0; holding position"))
    console.refresh_once()  # the second E-STOP was never drawn: its reset hides the banner
    assert not _banner_shown(console)
    ctl.publish(make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-2")))
    ctl.publish(make_state(mode=Mode.IDLE))
    ctl.publish(make_state(mode=Mode.FAULT, message="drive 2 following error"))
    console.refresh_once()
    assert _banner_shown(console)
    assert "FAULT" in console._alarm.content and "drive 2 following error" in console._alarm.content
    ctl.publish(make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-3")))
    console.refresh_once()  # halted before and after: the cause still follows
    assert "browser #3" in console._alarm.content and "FAULT" not in console._alarm.content
    ctl.publish(make_state(mode=Mode.IDLE))
    console.refresh_once()
    assert not _banner_shown(console)


def test_a_draw_that_failed_halfway_is_done_again_without_a_new_state(console: Console) -> None:
    """The reset's state is taken, its draw raises before the banner (here the gamepad
    query, once; the refresh thread shows any such error and goes on) and the controller
    publishes nothing more: the next refresh still hides the banner (the state taken was
    once lost with the failed draw, the banner left shown until the next publish)."""
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    ctl.publish(make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-0")))
    console.refresh_once()
    assert _banner_shown(console)
    gamepad = console.gamepad_state
    failures = iter([UserWarning("Queued a GuiUpdateMessage on a closed connection")])

    def fails_once() -> Any:
        for exc in failures:
            raise exc
        return gamepad()

    console.gamepad_state = fails_once  # type: ignore[method-assign]
    ctl.publish(make_state(mode=Mode.IDLE, message="reset by browser-0; holding position"))
    with pytest.raises(UserWarning):
        console.refresh_once()
    assert _banner_shown(console)  # the failed draw left the E-STOP's banner
    assert console.refresh_once() is True  # no new state: the controller's current one
    assert not _banner_shown(console)
    assert console.refresh_once() is False  # drawn: not again


def test_a_halt_the_controller_told_no_listener_reaches_the_banner() -> None:
    """A listener before the console's raises, so every publish fails: the controller
    faults and keeps its FAULT state for readers (``publish_minimal``) without calling the
    console's listener; the console still shows the banner with the cause."""
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())

    def broken(state: Any) -> None:
        raise RuntimeError("a broken listener")

    ctrl.add_listener(broken)
    with Console(ctrl, port=0, refresh_hz=0.01) as c:
        c.refresh_once()
        assert not _banner_shown(c)
        offered = c.stats().states_offered
        state = ctrl.run_cycles(3)
        assert state.mode is Mode.FAULT and c.stats().states_offered == offered
        assert c.refresh_once() is True
        assert _banner_shown(c) and "a broken listener" in c._alarm.content
        assert "FAULT" in c._safety.content


HOLD_POINTS = {
    # name: (what is held, publish after it returned (True) or before it runs, a new state
    # waiting in the slot)
    "after an empty take": ("take", True, False),
    "after the take": ("take", True, True),
    "after the snapshot": ("snapshot", True, True),
    "before the bar": ("gamepad_state", False, True),
    "after the bar": ("draw_scene", False, True),
}
"""Where a refresh is held while the control thread publishes (the refresh's order: take
the newest state from the slot, ask the controller's snapshot, draw the safety bar (it
asks the gamepad first), the scene, the panels)."""


@pytest.mark.parametrize("where", list(HOLD_POINTS))
@pytest.mark.parametrize("halt_first", [True, False], ids=["reset lands", "e-stop lands"])
def test_a_state_published_while_a_refresh_runs_is_shown_by_the_next(
    console: Console, where: str, halt_first: bool
) -> None:
    """The control thread publishes (a reset, or an E-STOP) while the refresh thread is
    held at each point of a refresh: the next refresh leaves the banner showing the
    controller's state, and a refresh after that draws nothing new."""
    import dataclasses
    import threading

    ctl: RecordingController = console.controller  # type: ignore[assignment]
    estop = make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-0"))
    idle = make_state(mode=Mode.IDLE, message="reset by browser-0; holding position")
    first, then = (estop, idle) if halt_first else (idle, estop)
    ctl.publish(first)
    console.refresh_once()
    held_name, after, waiting = HOLD_POINTS[where]
    if waiting:  # the same mode, one cycle later: a state for the held refresh to draw
        ctl.publish(dataclasses.replace(first, cycle=1, time=0.01))

    control = threading.Thread(target=ctl.publish, args=(then,), name="control")
    met = threading.Event()

    def publish_here() -> None:  # the control thread runs now; the refresh thread waits
        if not met.is_set():
            met.set()
            control.start()
            control.join()

    owner: Any = {"take": console._slot, "snapshot": ctl, "draw_scene": console.scene}.get(
        held_name, console
    )
    attr = "draw_state" if held_name == "draw_scene" else held_name
    fn = getattr(owner, attr)

    def held(*args: Any) -> Any:
        if not after:
            publish_here()
        out = fn(*args)
        if after:
            publish_here()
        return out

    setattr(owner, attr, held)
    refresher = threading.Thread(target=console.refresh_once, name="refresh")
    refresher.start()
    refresher.join()
    assert met.is_set()
    console.refresh_once()
    assert _banner_shown(console) is (then.mode is Mode.ESTOP)
    assert console.refresh_once() is False
    assert _banner_shown(console) is (then.mode is Mode.ESTOP)


def test_pages_connecting_before_during_and_after_a_halt_are_sent_the_current_banner(
    console: Console,
) -> None:
    """What the browsers are sent, read off viser's websocket (no browser): a page
    connected before the E-STOP gets the banner and then its removal; a page connecting
    while halted gets it in the replay; a page connecting while the refresh drawing the
    reset is held before the bar (it connects in that moment) ends with it hidden, as
    does a page connecting after the reset."""
    import threading

    ctl: RecordingController = console.controller  # type: ignore[assignment]
    console.refresh_once()
    pages: list[WireClient] = []

    def page() -> WireClient:
        w = WireClient(console.port)
        pages.append(w)
        w.until(lambda w: w.replayed, "the end of the replay")
        return w

    def shown(w: WireClient) -> bool | None:
        alarm, disabled = w.prop(console._alarm, "content"), w.prop(console._reset, "disabled")
        if alarm is None or disabled is None:
            return None
        assert w.visible(console._alarm) and w.visible(console._reset)
        assert ("icenav-halt" in alarm) is not disabled
        return "icenav-halt" in alarm

    try:
        before = page()
        assert shown(before) is False
        ctl.publish(make_state(mode=Mode.ESTOP, message=ESTOP_BY.format("browser-0")))
        console.refresh_once()
        before.until(lambda w: shown(w) is True, "the banner")
        assert shown(page()) is True
        racing: list[WireClient] = []
        gamepad = console.gamepad_state

        def connect_then_draw() -> Any:  # the page connects while the refresh is held
            if not racing:
                racing.append(page())
                assert shown(racing[0]) is True
            return gamepad()

        console.gamepad_state = connect_then_draw  # type: ignore[method-assign]
        ctl.publish(make_state(mode=Mode.IDLE, message="reset by browser-0; holding position"))
        refresher = threading.Thread(target=console.refresh_once, name="refresh")
        refresher.start()
        refresher.join()
        for w in (before, racing[0]):
            w.until(lambda w: shown(w) is False, "the banner hidden")
        assert shown(page()) is False
    finally:
        for w in pages:
            w.close()


# ---------------------------------------------------------------- the stale-state banner
def _stale_shown(c: Console) -> bool:
    return "icenav-stale" in c._alarm.content


def _press_estop(c: Console, client_id: int) -> None:
    """The shared E-STOP button pressed by browser ``client_id`` (its callbacks, as viser
    calls them from its thread pool)."""
    for cb in c._estop._impl.update_cb:  # noqa: SLF001 - viser's handle keeps them there
        cb(SimpleNamespace(client_id=client_id, client=None, target=c._estop))


def test_the_stale_banner_shows_while_no_state_comes_and_goes_when_states_resume() -> None:
    """A double that stops publishing, on the console's injected clock: the banner shows
    once the newest state is older than ``stale_after_s`` with its age, follows the age,
    and goes at the first new state (from the mailbox, or the controller's snapshot)."""
    ctl = RecordingController()
    clock = Clock()
    with Console(ctl, port=0, refresh_hz=0.01, clock=clock, config=ConsoleConfig(0.5)) as c:
        c.refresh_once()  # the snapshot offered at start, seen at t = 0
        assert not _stale_shown(c)
        clock.t = 0.5
        c.refresh_once()
        assert not _stale_shown(c)  # at the threshold: not beyond it
        clock.t = 0.54
        assert c.refresh_once() is False and _stale_shown(c)
        assert "No state from the controller for 0.5 s" in c._alarm.content
        clock.t = 2.0
        c.refresh_once()
        assert "for 2.0 s: the robot&#x27;s state is unknown" in c._alarm.content
        assert not _banner_shown(c)  # the last state was IDLE: no halt banner
        ctl.publish(make_state(cycle=1, time=0.01))  # states resume
        assert c.refresh_once() is True and not _stale_shown(c)
        clock.t = 3.0
        c.refresh_once()
        assert _stale_shown(c)
        ctl._state = make_state(cycle=2, time=0.02)  # told to no listener: the snapshot
        c.refresh_once()
        assert not _stale_shown(c)


def test_a_stalled_real_controller_shows_stale_and_both_banners_keep_the_cause() -> None:
    """The real controller stepped by hand (its loop "hangs" between steps): an E-STOP
    pressed on the console meanwhile reaches the controller at once, but no state shows it
    (console10's finding); the stale banner says the state is unknown until the loop runs
    again, then the halt banner shows the cause; stalled again, both show, the cause kept."""
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    clock = Clock()
    with Console(ctrl, port=0, refresh_hz=0.01, clock=clock) as c:
        ctrl.run_cycles(1)
        c.refresh_once()
        assert not _stale_shown(c) and not _banner_shown(c)
        clock.t = 0.8  # the loop stalls: no cycle, no state
        _press_estop(c, 1)
        assert ctrl.mode is Mode.ESTOP  # the indicator never stood in the E-STOP's way
        c.refresh_once()
        assert _stale_shown(c) and not _banner_shown(c)  # the page cannot know the E-STOP
        ctrl.run_cycles(1)  # the loop runs again
        c.refresh_once()
        assert not _stale_shown(c) and _banner_shown(c) and "browser #1" in c._alarm.content
        clock.t = 2.0  # stalls again: both banners, the halt's cause kept
        c.refresh_once()
        assert _stale_shown(c) and _banner_shown(c) and "browser #1" in c._alarm.content
        assert "for 1.2 s" in c._alarm.content
        ctrl.run_cycles(1)
        c.refresh_once()
        assert not _stale_shown(c) and _banner_shown(c)


def test_a_threshold_below_the_controllers_publish_period_is_refused() -> None:
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig(publish_every=100))
    with pytest.raises(ConfigurationError, match="publish period"):
        Console(ctrl, port=0, config=ConsoleConfig(0.5))


class _HangingRobot:
    """A simulated robot whose ``read_state`` blocks once told to (a driver call that does
    not return: the control loop hangs inside a cycle, before it publishes)."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self.hang = threading.Event()
        self.hung = threading.Event()
        self.go_on = threading.Event()

    def read_state(self) -> Any:
        if self.hang.is_set():
            self.hung.set()
            self.go_on.wait(timeout=30.0)
        return self._inner.read_state()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def test_a_hung_real_time_loop_shows_stale_and_the_estop_then_reaches_the_banner() -> None:
    """The real controller's real-time loop held inside a cycle by a robot call (events,
    no sleeps; the supervisor set far away so the E-STOP is the console's): the console's
    E-STOP reaches the controller at once, the page says the state is unknown (the E-STOP
    is in no state yet), and once the call returns the halt banner shows the cause."""
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import IdealPlant, SimulatedRobot

    robot = _HangingRobot(SimulatedRobot(IdealPlant()))
    config = ControllerConfig(stall_estop_s=60.0, plan_in_process=False)
    ctrl = Controller(robot, config)  # type: ignore[arg-type]
    estopped = threading.Event()
    ctrl.add_listener(lambda s: estopped.set() if s.mode is Mode.ESTOP else None)
    clock = Clock()
    with Console(ctrl, port=0, refresh_hz=0.01, clock=clock) as c:
        ctrl.start()
        try:
            robot.hang.set()
            assert robot.hung.wait(timeout=30.0)  # the loop is stuck: no state from now on
            c.refresh_once()  # (states published before it got stuck)
            clock.t += 0.6
            _press_estop(c, 2)
            assert ctrl.mode is Mode.ESTOP
            c.refresh_once()
            assert _stale_shown(c) and not _banner_shown(c)
            assert "for 0.6 s" in c._alarm.content
            robot.hang.clear()
            robot.go_on.set()  # the call returns: the loop publishes the E-STOP
            assert estopped.wait(timeout=30.0)
            c.refresh_once()
            assert not _stale_shown(c) and _banner_shown(c) and "browser #2" in c._alarm.content
        finally:
            robot.go_on.set()
            ctrl.shutdown()

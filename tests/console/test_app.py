"""Tests of the console server without a browser, against a recording test double.

``RecordingController`` is a test double of the ControllerCommands protocol: it records the
requests it gets and publishes the states a test gives it. It does no control; the browser
test drives the real ``icenav.controller.Controller``.
"""

from __future__ import annotations

import dataclasses
import threading
import urllib.request
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
import pytest

from icenav.console import Console
from icenav.errors import ConfigurationError
from icenav.hw.base import RobotStatus
from icenav.kinematics import backbone, forward
from icenav.state import (
    CalibrationKind,
    ControllerCommands,
    ControllerState,
    ImageFrame,
    Mode,
    ViewSummary,
)


def make_state(q: np.ndarray | None = None, **kw: Any) -> ControllerState:
    """A plausible snapshot at joint state q (model = motor, truth = model)."""
    q = np.zeros(4) if q is None else np.asarray(q, dtype=np.float64)
    tip = forward(q)
    bb = backbone(q, n=20).points_in_base
    base: dict[str, Any] = dict(
        time=0.0,
        cycle=0,
        mode=Mode.IDLE,
        robot_status=RobotStatus.ENABLED,
        q_motor=q,
        q_model=q,
        tip2base_model=tip,
        tip2base_true=tip,
        backbone_model=bb,
        backbone_true=bb,
        sensor2base=tip,
        tracker_status="VALID",
    )
    base.update(kw)
    return ControllerState(**base)


class RecordingController:
    """Test double of ControllerCommands: records requests, publishes given states."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple[Any, ...], str]] = []
        self.call_event = threading.Condition()
        self.owner: str | None = None
        self.image: ImageFrame | None = None
        self.view_images: dict[str, ImageFrame] = {}
        self._state = make_state()
        self._listeners: list[Callable[[ControllerState], None]] = []

    def _rec(self, name: str, args: tuple[Any, ...], client: str) -> None:
        with self.call_event:
            self.calls.append((name, args, client))
            self.call_event.notify_all()

    def wait_for_call(self, name: str, timeout: float = 10.0) -> tuple[Any, ...]:
        """Block until a request ``name`` was recorded; return (args, client)."""
        with self.call_event:
            ok = self.call_event.wait_for(
                lambda: any(c[0] == name for c in self.calls), timeout=timeout
            )
        assert ok, f"no {name} request within {timeout} s; got {[c[0] for c in self.calls]}"
        return next((c[1], c[2]) for c in self.calls if c[0] == name)

    def publish(self, state: ControllerState) -> None:
        """Hand ``state`` (with this double's control owner) to the listeners."""
        state = dataclasses.replace(state, control_owner=self.owner)
        self._state = state
        for cb in list(self._listeners):
            cb(state)

    # requests
    def request_mode(self, mode: Mode, client: str = "script") -> None:
        self._rec("request_mode", (mode,), client)

    def jog(self, velocity: Any, frame: Literal["knob", "tip"], client: str = "script") -> None:
        self._rec("jog", (np.asarray(velocity), frame), client)

    def save_view(self, name: str, client: str = "script") -> None:
        self._rec("save_view", (name,), client)

    def goto_view(self, name: str, client: str = "script") -> None:
        self._rec("goto_view", (name,), client)

    def delete_view(self, name: str, client: str = "script") -> None:
        self._rec("delete_view", (name,), client)

    def start_spin(self, client: str = "script") -> None:
        self._rec("start_spin", (), client)

    def start_calibration(self, kind: CalibrationKind, client: str = "script") -> None:
        self._rec("start_calibration", (kind,), client)

    def set_compensation(self, enabled: bool, client: str = "script") -> None:
        self._rec("set_compensation", (enabled,), client)

    def stop(self, client: str = "script") -> None:
        self._rec("stop", (), client)

    def estop(self, client: str = "script") -> None:
        self._rec("estop", (), client)

    def reset_fault(self, client: str = "script") -> None:
        self._rec("reset_fault", (), client)

    def acquire_control(self, client: str) -> bool:
        self._rec("acquire_control", (), client)
        if self.owner in (None, client) or client == "gamepad":
            self.owner = client
            return True
        return False

    def release_control(self, client: str) -> None:
        self._rec("release_control", (), client)
        if self.owner == client:
            self.owner = None

    # reads
    def snapshot(self) -> ControllerState:
        return self._state

    def latest_image(self) -> ImageFrame | None:
        return self.image

    def view_image(self, name: str) -> ImageFrame | None:
        return self.view_images.get(name)

    def add_listener(self, callback: Callable[[ControllerState], None]) -> None:
        self._listeners.append(callback)


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
    assert "KNOB" in status and "4 vertices" in status and "VALID" in status
    # scene follows the state: tip frame at the true tip, in metres
    np.testing.assert_allclose(console._tip_true.position, forward(q)[:3, 3] * 1e-3, atol=1e-9)
    assert console._sensor.visible
    ctl.publish(make_state(q, cycle=9, time=0.1, sensor2base=None, tracker_status="MISSING"))
    console.refresh_once()
    assert not console._sensor.visible
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
            drawn = f"t** = {1.0 * k:.1f} s" in c._status.content
            assert drawn == (k % 3 == 0), (k, c._status.content[:200])
        ctl.publish(make_state(cycle=7, time=7.0, mode=Mode.KNOB))  # a mode change: at once
        c.refresh_once()
        assert "KNOB" in c._status.content


def test_jog_button_sends_the_mode_s_jog_only_with_control(console: Console) -> None:
    from types import SimpleNamespace

    ctl: RecordingController = console.controller  # type: ignore[assignment]
    panel = SimpleNamespace(name="browser-7", can_control=False)
    hold = console._jog_callback(panel, 2, -1)  # type: ignore[arg-type]
    ctl.publish(make_state(mode=Mode.TIP))
    console.refresh_once()
    hold(None)
    assert not [c for c in ctl.calls if c[0] == "jog"]  # view only: nothing sent
    panel.can_control = True
    hold(None)
    (vel, frame), client = ctl.wait_for_call("jog")
    assert frame == "tip" and client == "browser-7"
    assert vel[2] == -console.mapping.tip_speed and np.count_nonzero(vel) == 1
    for mode in (Mode.IDLE, Mode.GOTO_VIEW):  # outside tip mode: the knobs
        ctl.calls.clear()
        ctl.publish(make_state(mode=mode))
        console.refresh_once()
        hold(None)
        (vel, frame), _ = ctl.wait_for_call("jog")
        assert frame == "knob" and vel[2] == -console.mapping.roll_rate


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
    assert console._scene_image is None  # identity ijk2tip: placement unknown, panel only


def test_image_with_placement_is_drawn_in_its_plane(console: Console) -> None:
    ctl: RecordingController = console.controller  # type: ignore[assignment]
    q = np.array([0.4, 0.1, -0.3, 6.0])
    ctl.publish(make_state(q, cycle=1, time=0.01))
    s = 0.5  # mm per pixel: row -> depth along tip x, column -> lateral along tip z
    ijk2tip = np.array([[0, s, 0, 0.25], [0, 0, 1, 0], [s, 0, 0, -31.75], [0, 0, 0, 1.0]])
    ctl.image = ImageFrame(np.zeros((128, 128), np.uint8), 0.01, ijk2tip)
    console.refresh_once()
    img = console._scene_image
    assert img is not None
    # the centre pixel (63.5, 63.5) of the 256-pixel enlarged image maps to the plane centre
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
    assert set(console._marker_handles) == {"apex"}
    sphere, _ = console._marker_handles["apex"]
    np.testing.assert_allclose(sphere.position, forward(q)[:3, 3] * 1e-3, atol=1e-9)
    ctl.publish(make_state(q, views=(), cycle=2, time=0.02))
    console.refresh_once()
    assert console._marker_handles == {}


def test_console_settings_are_checked() -> None:
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
            assert set(c._marker_handles) == {"apex"}
            handles.append(c._marker_handles["apex"][0])
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
    ["icenav.console", "icenav.console.app", "icenav.console.scene", "icenav.console.panels"],
)
def test_all_is_sorted_and_resolves(name: str) -> None:
    import importlib

    module = importlib.import_module(name)
    exported = list(module.__all__)
    assert exported == sorted(exported), f"{name}.__all__ is not sorted"
    for member in exported:
        assert hasattr(module, member), f"{name}.{member} is in __all__ but missing"

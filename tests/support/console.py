"""Shared helpers of the console tests: a recording test double of the controller's
protocol, plausible snapshots, and a fake viser client (no server, no browser)."""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import threading
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from icenav.control.authorization import Authorizer
from icenav.control.calibration_runner import CalibrationPreview
from icenav.control.commands import (
    Calibrate,
    Command,
    CommandResult,
    DeleteView,
    EStop,
    Export,
    GoToView,
    Jog,
    Outcome,
    RefineView,
    RenameView,
    Reset,
    SaveView,
    SetCompensation,
    SetMode,
    Source,
    Spin,
    Stop,
    Ticket,
)
from icenav.control.state import CalibrationKind, ControllerState, ImageFrame, Mode
from icenav.devices.robot import RobotStatus
from icenav.geometry.kinematics import backbone, forward


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


def _args(command: Command) -> tuple[Any, ...]:
    if isinstance(command, Jog):
        return (np.asarray(command.velocity), command.frame)
    if isinstance(command, SetMode):
        return (command.mode,)
    if isinstance(command, SaveView | GoToView | RefineView | DeleteView | Export):
        return (command.view,)
    if isinstance(command, RenameView):
        return (command.view, command.new_name)
    if isinstance(command, Calibrate):
        return (command.kind,)
    if isinstance(command, SetCompensation):
        return (command.enabled,)
    return ()


class RecordingController:
    """Test double of ControllerCommands: records the commands it gets (by name: "jog",
    "save_view", ...) and decides them at once with the controller's ownership rule (Stop
    and E-STOP from anyone, the rest only from the holder or while control is free, never
    from a view-only client); publishes the states a test gives it. It does no control:
    the browser test drives the real controller."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple[Any, ...], str]] = []
        self.call_event = threading.Condition()
        self.auth = Authorizer()
        """The controller's own authorization (the double decides as the controller does)."""
        self.notes: list[str] = []
        self.image: ImageFrame | None = None
        self.view_images: dict[str, ImageFrame] = {}
        self._state = make_state()
        self._listeners: list[Callable[[ControllerState], None]] = []
        self._seq = itertools.count()

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

    @property
    def owner(self) -> str | None:
        """Who holds control."""
        return self.auth.holder

    @owner.setter
    def owner(self, client: str | None) -> None:
        """Make ``client`` the holder (None: free), as if it had taken control."""
        holder = self.auth.holder
        if holder is not None:
            self.auth.release(Source.of(holder), next(self._seq))
        if client is not None:
            assert self.auth.take(Source("gamepad", client)) is None

    def publish(self, state: ControllerState) -> None:
        """Hand ``state`` (with this double's control owner) to the listeners."""
        state = dataclasses.replace(state, control_owner=self.owner)
        self._state = state
        for cb in list(self._listeners):
            cb(state)

    # commands
    def submit(self, command: Command) -> Ticket:
        client = command.source.client
        self._rec(command.name, _args(command), client)
        ticket = Ticket(next(self._seq), command)
        reason = self.auth.authorize(command, ticket.seq) or ""
        outcome = Outcome.REFUSED if reason else Outcome.DONE
        ticket.resolve(CommandResult(ticket.seq, command, outcome, reason))
        return ticket

    def request_mode(self, mode: Mode, client: str = "script") -> Ticket:
        return self.submit(SetMode(mode, source=Source.of(client)))

    def jog(self, velocity: Any, frame: Literal["knob", "tip"], client: str = "script") -> Ticket:
        return self.submit(Jog(np.asarray(velocity), frame, source=Source.of(client)))

    def save_view(self, name: str, client: str = "script") -> Ticket:
        return self.submit(SaveView(name, source=Source.of(client)))

    def goto_view(self, name: str, client: str = "script") -> Ticket:
        return self.submit(GoToView(name, source=Source.of(client)))

    def rename_view(self, name: str, new_name: str, client: str = "script") -> Ticket:
        return self.submit(RenameView(name, new_name, source=Source.of(client)))

    def delete_view(self, name: str, client: str = "script") -> Ticket:
        return self.submit(DeleteView(name, source=Source.of(client)))

    def start_spin(self, client: str = "script") -> Ticket:
        return self.submit(Spin(source=Source.of(client)))

    def start_calibration(self, kind: CalibrationKind, client: str = "script") -> Ticket:
        return self.submit(Calibrate(kind, source=Source.of(client)))

    def preview_calibration(self, kind: CalibrationKind) -> CalibrationPreview:
        return CalibrationPreview(kind, f"{kind} (double)", 5, 5, 90.0, 1.5)

    def set_compensation(self, enabled: bool, client: str = "script") -> Ticket:
        return self.submit(SetCompensation(enabled, source=Source.of(client)))

    def stop(self, client: str = "script") -> Ticket:
        return self.submit(Stop(source=Source.of(client)))

    def estop(self, client: str = "script") -> Ticket:
        return self.submit(EStop(source=Source.of(client)))

    def reset_fault(self, client: str = "script") -> Ticket:
        return self.submit(Reset(source=Source.of(client)))

    def acquire_control(self, client: str) -> bool:
        self._rec("acquire_control", (), client)
        return self.auth.take(Source.of(client)) is None

    def release_control(self, client: str) -> None:
        self._rec("release_control", (), client)
        self.auth.release(Source.of(client), next(self._seq))

    def disconnect(self, client: str) -> None:
        self._rec("disconnect", (), client)
        self.auth.disconnect(Source.of(client), next(self._seq))

    def set_view_only(self, client: str, view_only: bool) -> None:
        self.auth.set_view_only(client, view_only)

    def note(self, text: str) -> None:
        self.notes.append(text)

    # reads
    def snapshot(self) -> ControllerState:
        return self._state

    def latest_image(self) -> ImageFrame | None:
        return self.image

    def view_image(self, name: str) -> ImageFrame | None:
        return self.view_images.get(name)

    def add_listener(self, callback: Callable[[ControllerState], None]) -> None:
        self._listeners.append(callback)


class FakeHandle:
    """Stands in for a viser GUI handle: keeps its value and the callbacks given to it."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        self.value = kwargs.get("initial_value", "")
        self.content = args[0] if args else ""
        self.label = kwargs.get("label", args[0] if args else "")
        self.callbacks: list[Callable[[Any], None]] = []
        self.closed = False
        self.removed = False
        self.disabled = bool(kwargs.get("disabled", False))
        self.visible = bool(kwargs.get("visible", True))
        self.options = kwargs.get("options", args[1] if len(args) > 1 else ())

    def on_click(self, fn: Callable[[Any], None]) -> Callable[[Any], None]:
        self.callbacks.append(fn)
        return fn

    on_update = on_click

    def on_hold(self, fn: Callable[[Any], None], callback_hz: float = 0.0) -> object:
        return self.on_click(fn)

    def click(self) -> None:
        """What viser does when a browser clicks the button."""

        class Ev:
            client = object()
            client_id = 1

        for fn in self.callbacks:
            fn(Ev())

    def add_tab(self, *args: object, **kwargs: object) -> contextlib.nullcontext[None]:
        return contextlib.nullcontext()

    def __enter__(self) -> FakeHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def close(self) -> None:
        self.closed = True

    def remove(self) -> None:
        self.removed = True


class FakeGui:
    """A viser client's ``gui``: every ``add_*`` makes a :class:`FakeHandle`; the latest
    handles made are kept in order (a modal's markdown and buttons)."""

    def __init__(self) -> None:
        self.made: list[FakeHandle] = []

    def __getattr__(self, name: str) -> object:
        def make(*args: object, **kwargs: object) -> FakeHandle:
            h = FakeHandle(*args, **kwargs)
            self.made.append(h)
            return h

        return make


class FakeClient:
    """A browser connection as the console's connection handler sees it (no server)."""

    def __init__(self, client_id: int) -> None:
        self.client_id = client_id
        self.gui = FakeGui()


class WireClient:
    """A browser's view of the console without a browser: a websocket client of the viser
    server that decodes what the server sends (zstd-compressed msgpack windows, viser's
    wire format) and keeps the latest properties of each GUI element, as the page applies
    them. Waits are reads on the socket (with a timeout), never sleeps. It sends nothing,
    so it sees what every browser is sent (the safety bar, the image, the scene) but is no
    browser to the console: viser calls the console's connection handler (a panel, control)
    only after a client's first camera message.

    Parameters
    ----------
    port : int
        The console's port (``Console.port``).
    """

    def __init__(self, port: int) -> None:
        import viser
        from websockets.sync.client import connect
        from websockets.typing import Subprotocol

        self.props: dict[str, dict[str, Any]] = {}
        """uuid -> the element's properties as received (create, then updates)."""
        self.replayed = False
        """True once the server's replay of what was drawn before the connection ended."""
        self._ws = connect(
            f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(f"viser-v{viser.__version__}")]
        )

    def close(self) -> None:
        self._ws.close()

    def send(self, message: dict[str, Any]) -> None:
        """Send a message as a page would (msgpack; ``type`` names viser's class)."""
        import msgspec

        self._ws.send(msgspec.msgpack.encode(message))

    def become_browser(self) -> None:
        """Send a first camera message: viser then calls the console's connection
        handler, which gives this client a panel (and control, when free)."""
        self.send(
            {
                "type": "ViewerCameraMessage",
                "wxyz": (1.0, 0.0, 0.0, 0.0),
                "position": (0.0, 0.0, 1.0),
                "fov": 1.0,
                "near": 0.01,
                "far": 100.0,
                "image_height": 600,
                "image_width": 800,
                "look_at": (0.0, 0.0, 0.0),
                "up_direction": (0.0, 0.0, 1.0),
            }
        )

    def hold(self, handle: Any, hz: float) -> None:
        """A "still held" message of button ``handle`` (its page timer at ``hz``)."""
        self.send({"type": "GuiButtonHoldMessage", "uuid": handle._impl.uuid, "frequency": hz})

    def click(self, handle: Any) -> None:
        """A click of button ``handle`` (for a held button: the pointer-up)."""
        self.send(
            {"type": "GuiUpdateMessage", "uuid": handle._impl.uuid, "updates": {"value": True}}
        )

    def _read(self, timeout_s: float) -> None:
        import msgspec
        import zstandard

        raw = self._ws.recv(timeout=timeout_s)
        assert isinstance(raw, bytes)
        size, compressed = (int.from_bytes(raw[i : i + 8], "little") for i in (0, 8))
        inner = zstandard.ZstdDecompressor().decompress(
            raw[16 : 16 + compressed], max_output_size=size
        )
        for m in msgspec.msgpack.decode(inner)["messages"]:
            if m["type"] == "ReplayDoneMessage":
                self.replayed = True
            elif m["type"] == "GuiUpdateMessage":
                self.props.setdefault(m["uuid"], {}).update(m["updates"])
            elif isinstance(m.get("props"), dict) and "uuid" in m:
                self.props[m["uuid"]] = dict(m["props"])

    def until(self, done: Callable[[WireClient], bool], what: str, timeout_s: float = 10.0) -> None:
        """Read the server's messages until ``done(self)``."""
        import time

        deadline = time.monotonic() + timeout_s
        while not done(self):
            left = deadline - time.monotonic()
            assert left > 0, f"the wire client never saw {what}"
            with contextlib.suppress(TimeoutError):
                self._read(left)

    def prop(self, handle: Any, name: str) -> Any:
        """The property ``name`` of ``handle`` as the page was sent it (None: not yet)."""
        return self.props.get(handle._impl.uuid, {}).get(name)

    def visible(self, handle: Any) -> bool | None:
        """Whether the page shows ``handle`` (None: the element never arrived)."""
        p = self.props.get(handle._impl.uuid)
        return None if p is None else bool(p.get("visible", True))


# ---------------------------------------------------------------- the jog, both sides
POINTER_LOG_JS = """
window.__icenavPointer = [];
const icenavLog = (e) => {
  window.__icenavPointer.push(e);
  if (window.__icenavPointer.length > 400) window.__icenavPointer.shift();
};
for (const type of ['pointerdown', 'pointerup', 'pointercancel', 'lostpointercapture', 'click']) {
  addEventListener(type, (e) => {
    const b = e.target && e.target.closest ? e.target.closest('button') : null;
    icenavLog({type, t: Math.round(performance.now()), x: Math.round(e.clientX),
               y: Math.round(e.clientY), trusted: e.isTrusted,
               button: b ? b.textContent.trim() : String(e.target && e.target.nodeName)});
  }, true);
}
new PerformanceObserver((list) => { for (const e of list.getEntries()) {
  icenavLog({type: 'layout-shift', t: Math.round(e.startTime),
    moved: e.sources.map((s) => [(s.node && s.node.textContent || '').trim().slice(0, 24),
                                Math.round(s.previousRect.y), Math.round(s.currentRect.y)])});
}}).observe({type: 'layout-shift', buffered: true});
"""
"""An init script (``page.add_init_script``): the page's pointer events (target button,
position) and layout shifts (what moved, from which y to which), for a failing jog check."""

JOG_PAGE_JS = """([x, y]) => {
  const hit = document.elementFromPoint(x, y);
  const under = hit && hit.closest ? hit.closest('button') : null;
  const boxes = {};
  for (const b of document.querySelectorAll('button')) {
    const t = b.textContent.trim();
    if (/knob|roll|translation|tip /.test(t)) boxes[t] = Math.round(b.getBoundingClientRect().y);
  }
  const guard = window.__icenavJogGuard;
  return {under: under ? under.textContent.trim() : (hit ? hit.nodeName : null), boxes,
          guard: guard ? guard.log.slice(-8) : null,
          page: (window.__icenavPointer || []).slice(-16)};
}"""
"""The page's side of a held jog at the pointer (x, y): the button under it, the jog
buttons' tops, the jog guard's log, the latest pointer events and layout shifts."""

BUTTON_TOPS_JS = """(names) => names.map((n) => {
  const b = [...document.querySelectorAll('button')].find((b) => b.textContent.trim() === n);
  return b ? Math.round(b.getBoundingClientRect().y) : null;
})"""
"""The tops (CSS pixels) of the buttons named ``names`` (None: not on the page)."""


def page_read(page: Any, js: str, *args: Any) -> Any:
    """``page.evaluate(js, *args)`` for a failure's report: what it could not read is said, not
    raised (a diagnostic never hides the failure it describes)."""
    try:
        return page.evaluate(js, *args)
    except Exception as exc:
        return f"not read: {exc}"


def jog_report(console: Any, page: Any, xy: tuple[float, float], since: int = 0) -> str:
    """Both sides of a held jog, for a failing check: what the server saw (the jog's
    presses, releases and trips since event ``since``, the controller's jog) and what the
    page saw (:data:`JOG_PAGE_JS` at the pointer ``xy``)."""
    events = [(round(e.t, 3), e.key, e.what, e.button, e.detail) for e in list(console.jog.events)][
        since:
    ]
    ctl = console.controller
    seen = page_read(page, JOG_PAGE_JS, list(xy))
    return (
        f"server: jog events {events}, held {console.jog.held()}, tripped "
        f"{console.jog.tripped()}, controller jog {getattr(ctl, '_jog', None)!r}; "
        f"page at {xy}: {seen}"
    )

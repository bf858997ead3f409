"""The operator console: a viser server showing the controller's state and sending its requests.

Threads
-------
- The control thread calls the console's listener with each published state; the listener
  only drops the state into a :class:`~icenav.console.panels.LatestSlot` (never blocks).
- One refresh thread wakes at ``refresh_hz``, takes the newest state (older ones are
  coalesced away), updates the scene and panels, and sends a new ICE image when there is one.
- viser's thread pool runs the GUI callbacks, which only submit commands to the controller
  (:mod:`icenav.console.commands`); what the controller decided is shown in the panel of the
  browser that asked. Export DICOM writes its file on the refresh thread once accepted.

Several browsers may connect. The E-STOP and Stop buttons, the status, the image, the plot
and the 3-D scene are shared; each browser has its own driving controls, enabled only while
it holds control. Who may do what is the controller's decision
(:mod:`icenav.control.authorization`), not the console's. Delete view and Calibrate ask for
confirmation. With a control token (``Console(..., control_token=...)``, as ``icenav demo``
sets when exposed) a browser is view only until it entered the token (constant-time
comparison, rate-limited guesses with a logged alarm: ``TokenGate``).
"""

from __future__ import annotations

import contextlib
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icenav.console.commands import NO_VIEWS, Confirmation, ConsoleCommands, next_name
from icenav.console.panels import (
    JOG_AXES,
    MODE_CHOICES,
    JointHistory,
    LatestSlot,
    client_name,
    control_view,
    gray_to_rgb,
    jog_command,
    mode_from_choice,
    progress_percent,
    status_markdown,
    summary_markdown,
    views_markdown,
)
from icenav.console.scene import AnatomyMesh, as_anatomy_meshes
from icenav.console.scene_view import IMAGE_MAX_WIDTH, IMAGE_MIN_WIDTH, SceneView
from icenav.control.authorization import TokenGate
from icenav.control.commands import (
    CommandResult,
    GoToView,
    Jog,
    Outcome,
    Reset,
    SaveView,
    SetCompensation,
    SetMode,
    Source,
    Spin,
)
from icenav.control.state import (
    CalibrationKind,
    ControllerCommands,
    ControllerState,
    ImageFrame,
    Mode,
)
from icenav.control.teleop import JoystickMapping
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.persistence.dicom import ExportDirectory

__all__ = ["Console", "ConsoleStats"]

CALIBRATIONS: dict[str, CalibrationKind] = {
    "Dense raster": "dense",
    "5-point": "five_point",
    "Dense + hysteresis": "dense+hysteresis",
}


@dataclass(frozen=True)
class ConsoleStats:
    """Counters of the console's work since it was made."""

    states_offered: int
    """States the controller handed to the listener."""
    refreshes: int
    """Refreshes that drew a state (the rest were coalesced)."""
    images_sent: int
    """ICE images sent to the browsers."""
    clients: int
    """Browsers connected now."""


class _ClientPanel:
    """One browser's own controls (viser handles created on its connection)."""

    def __init__(self, console: Console, client: Any):
        self.client = client
        self.name = client_name(client.client_id)
        self.can_control: bool | None = None
        self.note_text = ""
        self.jog_mode: Mode | None = None
        self.view_options: tuple[str, ...] = ()
        gui = client.gui
        c = console
        self.source = Source("console", self.name)
        """The source of this browser's commands."""
        self.note = gui.add_markdown("", order=1.0)
        self.feedback = gui.add_markdown("", order=1.01)
        """What the controller decided about this browser's latest refused or failed
        command (set on the refresh thread from :attr:`feedback_text`)."""
        self.feedback_text = ""
        self.feedback_shown = ""
        self.confirm: Confirmation | None = None
        """The confirmation dialog open in this browser (Delete view, Calibrate), if any."""
        self.exports: deque[str] = deque(maxlen=8)
        """Views whose export the controller accepted, to write on the refresh thread."""
        self.export_text = ""
        self.export_shown = ""
        self.authorised = console.control_token is None
        self.token = None
        if console.control_token is not None:  # reliability: part 4 (security)
            self.token = gui.add_text("Control token", initial_value="", order=1.05)
        self.take = gui.add_button("Take control", order=1.1)
        self.release = gui.add_button("Release control", order=1.2, visible=False)
        tabs = gui.add_tab_group(order=5.0)
        with tabs.add_tab("Views"):
            self.view_name = gui.add_text("View name", initial_value="view-1")
            self.save = gui.add_button("Save view")
            self.views = gui.add_dropdown("Saved views", (NO_VIEWS,), initial_value=NO_VIEWS)
            self.goto = gui.add_button("Go to view", color="green")
            self.thumb_note = gui.add_markdown("*No thumbnail.*", visible=False)
            self.thumb = gui.add_image(
                np.zeros((8, 8, 3), np.uint8), label="Thumbnail", format="jpeg", visible=False
            )
            self.delete = gui.add_button("Delete view", color="gray")
            self.export = None
            self.export_note = None
            if console.export_dir is not None:  # reliability: part 4 (security)
                self.export = gui.add_button("Export DICOM", hint="Into the export directory")
                self.export_note = gui.add_markdown("")
            self.view_list = gui.add_markdown("*No saved views yet.*")
        with tabs.add_tab("Jog"):
            self.jog_buttons = []
            labels = JOG_AXES[Mode.KNOB]
            for axis in range(4):
                for sign in (-1, 1):
                    b = gui.add_button(f"{labels[axis]} {'-' if sign < 0 else '+'}")
                    b.on_hold(c._jog_callback(self, axis, sign), callback_hz=c.jog_hz)
                    self.jog_buttons.append((b, axis, sign))
        with tabs.add_tab("Drive"):
            self.mode = gui.add_dropdown("Mode", tuple(MODE_CHOICES), initial_value="Idle")
            self.compensation = gui.add_checkbox("Compensation", initial_value=False)
            self.reset = gui.add_button("Reset fault", color="yellow")
            self.spin = gui.add_button("Spin 360")
            self.calib_kind = gui.add_dropdown(
                "Calibration", tuple(CALIBRATIONS), initial_value="5-point"
            )
            self.calibrate = gui.add_button("Calibrate")
        self.motion_controls = [
            self.mode,
            self.compensation,
            self.reset,
            self.spin,
            self.calib_kind,
            self.calibrate,
            self.save,
            self.goto,
            self.delete,
            *([self.export] if self.export is not None else []),
            *(b for b, _, _ in self.jog_buttons),
        ]


class Console(ConsoleCommands):
    """The browser console of one controller.

    Parameters
    ----------
    controller : ControllerCommands
        The controller to show and drive.
    host, port : str, int
        Where to serve (127.0.0.1 unless told otherwise; ``port=0`` picks a free port).
    anatomy_mesh : sequence of AnatomyMesh or (name, vertices, faces, rgb, opacity), optional
        Anatomy surfaces in the base frame (mm), drawn translucently; None shows none.
    refresh_hz : float
        Scene / panel refresh rate (states in between are coalesced); also the highest
        rate at which ICE images are sent.
    geometry : CatheterGeometry
        Catheter geometry (tube radius; model pose of views loaded with a session).
    mapping : JoystickMapping, optional
        Jog speeds of the on-screen buttons (the gamepad's full-stick rates).
    max_roadmap_points : int
        The roadmap drawn as at most this many points.
    jog_hz : float
        Rate at which a held jog button repeats its jog request.
    status_hz : float
        Rate of the status table and the joint plot (at most refresh_hz; also redrawn on
        each mode change).
    control_token : str, optional
        When set, a browser must enter it before it may take control (viewing, Stop and
        E-STOP need no token).
    export_dir : str, Path or ExportDirectory, optional
        Where the views panel's **Export DICOM** button writes a saved view's image (file
        names made by the program, never by the browser); None: no export button.
    """

    def __init__(
        self,
        controller: ControllerCommands,
        host: str = "127.0.0.1",
        port: int = 8080,
        anatomy_mesh: Sequence[AnatomyMesh | tuple[str, Any, Any, Any, float]] | None = None,
        *,
        refresh_hz: float = 25.0,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
        mapping: JoystickMapping | None = None,
        max_roadmap_points: int = 5000,
        jog_hz: float = 20.0,
        status_hz: float = 10.0,
        control_token: str | None = None,
        export_dir: str | Path | ExportDirectory | None = None,
    ):
        if not (0 < refresh_hz <= 120):
            raise ConfigurationError(f"refresh_hz must be in (0, 120] Hz, got {refresh_hz}")
        if not (0 < status_hz <= 120):
            raise ConfigurationError(f"status_hz must be in (0, 120] Hz, got {status_hz}")
        if not (0 < jog_hz <= 100):
            raise ConfigurationError(f"jog_hz must be in (0, 100] Hz, got {jog_hz}")
        if max_roadmap_points < 2:
            raise ConfigurationError(
                f"max_roadmap_points must be >= 2 points, got {max_roadmap_points}"
            )
        if not 0 <= port <= 65535:
            raise ConfigurationError(f"port must be in [0, 65535], got {port}")
        if control_token is not None and (
            not control_token or control_token != control_token.strip()
        ):
            raise ConfigurationError(
                "control_token must be non-empty, without surrounding spaces (a browser's "
                f"entry is stripped), got {len(control_token)} characters"
            )
        self.controller = controller
        self.control_token = control_token
        """When set, a browser controls (moves, saves, ...) only after entering it; viewing,
        Stop and E-STOP need no token."""
        self._token_gate = (
            None if control_token is None else TokenGate(control_token, on_alarm=self._token_alarm)
        )
        if export_dir is not None and not isinstance(export_dir, ExportDirectory):
            export_dir = ExportDirectory(Path(export_dir))
        self.export_dir: ExportDirectory | None = export_dir
        """Where the Export DICOM button writes (None: no button)."""
        self.host = host
        self.requested_port = port
        self.refresh_hz = refresh_hz
        self._status_every = max(1, round(refresh_hz / status_hz))
        self.jog_hz = jog_hz
        self.geometry = geometry
        self.mapping = mapping or JoystickMapping()
        self.max_roadmap_points = max_roadmap_points
        self.anatomy = as_anatomy_meshes(anatomy_mesh)
        self._slot = LatestSlot()
        self._reset_view_state()
        self._panels: dict[int, _ClientPanel] = {}
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: Any = None
        self._listening = False
        self._running = False
        self._refreshes = 0
        self._images_sent = 0
        self.last_error = ""
        """The latest exception text of a refresh ("" after a good one); shown in the page."""

    def _reset_view_state(self) -> None:
        """What the console has drawn (a fresh start on each start())."""
        self._history = JointHistory(10.0)
        self._last_state: ControllerState | None = None
        self._status_mode: Mode | None = None
        self._last_image_t: float | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def url(self) -> str:
        """http://host:port of the running console."""
        if self._server is None:
            raise ConfigurationError("the console is not started; call start() first")
        return f"http://{self.host}:{self._server.get_port()}"

    @property
    def port(self) -> int:
        """The port actually bound (differs from the requested one for port=0)."""
        if self._server is None:
            raise ConfigurationError("the console is not started; call start() first")
        return int(self._server.get_port())

    def stats(self) -> ConsoleStats:
        """Counters since the console was made."""
        return ConsoleStats(
            states_offered=self._slot.offered,
            refreshes=self._refreshes,
            images_sent=self._images_sent,
            clients=len(self._panels),
        )

    def start(self) -> None:
        """Serve the console and follow the controller (returns at once)."""
        if self._running:
            return
        import viser  # imported here: the pure parts of the console need no server

        self._server = viser.ViserServer(
            host=self.host, port=self.requested_port, label="icenav", verbose=False
        )
        bound = int(self._server.get_port())
        if self.requested_port != 0 and bound != self.requested_port:
            # viser moves to the next free port on its own; a console that is not where
            # the operator was told to look is an error, not a surprise
            self._server.stop()
            self._server = None
            raise ConfigurationError(
                f"console port {self.requested_port} on {self.host} is in use: choose "
                "another --port, or --port 0 for a free one"
            )
        self._stop.clear()
        self._reset_view_state()
        self._build_shared()
        self._server.on_client_connect(self._on_connect)
        self._server.on_client_disconnect(self._on_disconnect)
        self._running = True
        if not self._listening:  # the protocol has no remove_listener: register once
            self.controller.add_listener(self._on_state)
            self._listening = True
        self._slot.offer(self.controller.snapshot())
        self._thread = threading.Thread(target=self._run, name="icenav-console", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop refreshing, release control held by browsers and close the server."""
        if not self._running:
            return
        self._running = False
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            panels = list(self._panels.values())
            self._panels.clear()
        for p in panels:  # the browsers are gone: what they started stops and holds
            with contextlib.suppress(Exception):
                self.controller.disconnect(p.name)
        if self._server is not None:
            self._server.stop()
            self._server = None

    def __enter__(self) -> Console:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _token_alarm(self, text: str) -> None:
        """A token alarm (TokenGate logs it): also into the session's event log."""
        self.controller.note(f"security alarm: {text}")

    def _on_state(self, state: ControllerState) -> None:
        if self._running:
            self._slot.offer(state)

    def _run(self) -> None:
        period = 1.0 / self.refresh_hz
        while not self._stop.wait(period):
            try:
                self.refresh_once()
                error = ""
            except UserWarning as exc:  # raised only where warnings are errors (the tests)
                # a browser closed between taking the panel list and updating its panel: viser
                # warns that the update will not be delivered; benign, the panel goes next cycle
                error = "" if "closed connection" in str(exc) else f"UserWarning: {exc}"
            except Exception as exc:  # keep the console alive; show what went wrong
                error = f"{type(exc).__name__}: {exc}"
            if error != self.last_error:
                self.last_error = error
                with contextlib.suppress(Exception):
                    self._error_md.content = f"**Console error:** `{error}`" if error else ""

    # ------------------------------------------------------------------ building
    def _build_shared(self) -> None:
        s = self._server
        s.gui.configure_theme(control_width="large", show_share_button=False)
        self._estop = s.gui.add_button(
            "E-STOP", color="red", icon=None, order=0.0, hint="Emergency stop (anyone, any mode)"
        )
        self._estop.on_click(lambda ev: self.controller.estop(client=self._client_of(ev)))
        self._stop_btn = s.gui.add_button("Stop", color="orange", order=0.1)
        self._stop_btn.on_click(lambda ev: self.controller.stop(client=self._client_of(ev)))
        self._error_md = s.gui.add_markdown("", order=0.2)
        self._summary = s.gui.add_markdown("*Waiting for the controller...*", order=1.5)
        self._image_placeholder = s.gui.add_markdown("*No ICE image yet.*", order=2.0)
        self._image = s.gui.add_image(
            np.zeros((8, 8, 3), np.uint8),
            label="ICE image",
            format="jpeg",
            jpeg_quality=80,
            order=2.1,
            visible=False,
        )
        self._progress_label = s.gui.add_markdown("", order=3.0, visible=False)
        self._progress = s.gui.add_progress_bar(0.0, order=3.1, visible=False, animated=True)
        with s.gui.add_folder("Status", order=20.0):
            self._status = s.gui.add_markdown("*Waiting for the controller...*")
            import viser.uplot as uplot

            empty = tuple(np.zeros(0) for _ in range(5))
            self._plot = s.gui.add_uplot(
                empty,
                (
                    uplot.Series(label="t (s)"),
                    uplot.Series(label="phi1 (deg)", stroke="#d9480f", width=2),
                    uplot.Series(label="phi2 (deg)", stroke="#1971c2", width=2),
                    uplot.Series(label="phi3 (deg)", stroke="#2f9e44", width=2),
                    uplot.Series(label="d4 (mm)", stroke="#7048e8", width=2, scale="mm"),
                ),
                title="Joint states, last 10 s",
                scales={"x": uplot.Scale(time=False), "mm": uplot.Scale(auto=True)},
                axes=(
                    uplot.Axis(),
                    uplot.Axis(label="deg"),
                    uplot.Axis(label="mm", scale="mm", side=1),
                ),
                aspect=1.6,
            )

        self.scene = SceneView(s, self.anatomy, self.geometry, self.max_roadmap_points)

    def _on_connect(self, client: Any) -> None:
        panel = _ClientPanel(self, client)
        ctl = self.controller
        name = panel.name
        if not panel.authorised:  # the controller refuses everything but Stop / E-STOP
            ctl.set_view_only(name, True)

        def ok(ev: Any) -> bool:
            return ev.client is not None

        @panel.take.on_click
        def _(ev: Any) -> None:
            if not panel.authorised and panel.token is not None and self._token_gate:
                verdict = self._token_gate.check(name, str(panel.token.value).strip())
                if not verdict.ok:
                    panel.note.content = f"**{verdict.reason}**"
                    return
                panel.authorised = True
                ctl.set_view_only(name, False)
            if not ctl.acquire_control(name):
                panel.feedback_text = "**Take control refused**: another client holds control."

        @panel.release.on_click
        def _(ev: Any) -> None:
            ctl.release_control(name)

        @panel.mode.on_update
        def _(ev: Any) -> None:
            if ok(ev):
                self.send(panel, SetMode(mode_from_choice(panel.mode.value), source=panel.source))

        @panel.compensation.on_update
        def _(ev: Any) -> None:
            if ok(ev):
                enabled = bool(panel.compensation.value)
                self.send(panel, SetCompensation(enabled, source=panel.source))

        panel.reset.on_click(lambda ev: self.send(panel, Reset(source=panel.source)))
        panel.spin.on_click(lambda ev: self.send(panel, Spin(source=panel.source)))

        @panel.calibrate.on_click
        def _(ev: Any) -> None:
            self._confirm_calibration(panel, CALIBRATIONS[panel.calib_kind.value])

        @panel.save.on_click
        def _(ev: Any) -> None:
            view = panel.view_name.value.strip()
            if not view:
                return

            def saved(result: CommandResult) -> None:  # a refused save keeps the name
                if result.outcome is Outcome.ACCEPTED and panel.view_name.value == view:
                    panel.view_name.value = next_name(view)

            self.send(panel, SaveView(view, source=panel.source), on_decided=saved)

        @panel.goto.on_click
        def _(ev: Any) -> None:
            if panel.views.value != NO_VIEWS:
                self.send(panel, GoToView(panel.views.value, source=panel.source))

        @panel.delete.on_click
        def _(ev: Any) -> None:
            if panel.views.value != NO_VIEWS:
                self._confirm_delete(panel, str(panel.views.value))

        @panel.views.on_update
        def _(ev: Any) -> None:
            self._show_thumbnail(panel)

        if panel.export is not None:

            @panel.export.on_click
            def _(ev: Any) -> None:
                self._export_clicked(panel)

        with self._lock:
            self._panels[client.client_id] = panel
            state = self._last_state
            if state is not None:
                self._update_panel(panel, state)
        if panel.authorised and (state is None or state.control_owner is None):
            ctl.acquire_control(name)

    def _on_disconnect(self, client: Any) -> None:
        with self._lock:
            panel = self._panels.pop(client.client_id, None)
        if panel is not None:  # its control is released; what it started stops and holds
            self.controller.disconnect(panel.name)

    def _client_of(self, ev: Any) -> str:
        return "browser" if ev.client_id is None else client_name(ev.client_id)

    def _jog_callback(self, panel: _ClientPanel, axis: int, sign: int) -> Any:
        def cb(ev: Any) -> None:
            state = self._last_state
            if state is None or not panel.can_control:
                return
            # Outside tip mode a jog drives the knobs: the controller wakes from IDLE into
            # knob mode on it, and it aborts an automatic motion (as gamepad input does).
            mode = Mode.TIP if state.mode == Mode.TIP else Mode.KNOB
            vel, frame = jog_command(mode, axis, sign, self.mapping)
            self.send(panel, Jog(vel, frame, source=panel.source))

        return cb

    # ------------------------------------------------------------------ refreshing
    def refresh_once(self) -> bool:
        """Draw the newest state (if a new one came) and the newest image; True if drawn."""
        drew = False
        state = self._slot.take()
        if state is not None:
            self._draw_state(state)
            self._refreshes += 1
            drew = True
        frame = self.controller.latest_image()
        if frame is not None and frame.timestamp != self._last_image_t:
            self._draw_image(frame, state or self._last_state)
            self._last_image_t = frame.timestamp
            self._images_sent += 1
        self._serve_panels()
        return drew

    def _draw_state(self, state: ControllerState) -> None:
        with self._lock:
            self._last_state = state
        self._summary.content = summary_markdown(state)
        self._history.append(state.time, state.q_motor)
        # the status table and the plot are costly to re-render in the browser: status_hz
        if self._refreshes % self._status_every == 0 or state.mode != self._status_mode:
            self._status.content = status_markdown(state)
            self._plot.data = self._history.uplot_data()
            self._status_mode = state.mode
        pct = progress_percent(state.progress)
        self._progress.visible = pct is not None
        self._progress_label.visible = pct is not None
        if pct is not None:
            self._progress.value = pct
            self._progress_label.content = f"{state.progress_label or 'Progress'}: {pct:.0f} %"
        self.scene.draw_state(state)
        with self._lock:  # a browser connecting or leaving waits for this
            for p in self._panels.values():
                self._update_panel(p, state)

    def _draw_image(self, frame: ImageFrame, state: ControllerState | None) -> None:
        self._image.image = gray_to_rgb(frame.pixels, IMAGE_MAX_WIDTH, IMAGE_MIN_WIDTH)
        self._image.visible = True
        self._image_placeholder.visible = False
        self.scene.draw_image(frame, state)

    def _update_panel(self, p: _ClientPanel, state: ControllerState) -> None:
        cv = control_view(state.control_owner, p.name)
        if cv.text != p.note_text:
            p.note.content = cv.text
            p.note_text = cv.text
        if cv.can_control != p.can_control:
            for h in p.motion_controls:
                h.disabled = not cv.can_control
            p.can_control = cv.can_control
        p.take.visible = not cv.can_control
        p.take.disabled = not cv.can_take
        p.release.visible = cv.can_control
        for choice, mode in MODE_CHOICES.items():
            if state.mode == mode and p.mode.value != choice:
                p.mode.value = choice
        if p.compensation.value != state.compensation_enabled:
            p.compensation.value = state.compensation_enabled
        jog_mode = state.mode if state.mode == Mode.TIP else Mode.KNOB
        if jog_mode != p.jog_mode:
            labels = JOG_AXES[jog_mode]
            for b, axis, sign in p.jog_buttons:
                b.label = f"{labels[axis]} {'-' if sign < 0 else '+'}"
            p.jog_mode = jog_mode
        names = tuple(v.name for v in state.views)
        if names != p.view_options:
            new = [n for n in names if n not in p.view_options]
            p.view_options = names
            p.views.options = names or (NO_VIEWS,)
            if new:  # select the view just saved
                p.views.value = new[-1]
            elif p.views.value not in names:
                p.views.value = names[0] if names else NO_VIEWS
            p.view_list.content = views_markdown(state.views)
            self._show_thumbnail(p)

    def _show_thumbnail(self, p: _ClientPanel) -> None:
        name = p.views.value
        frame = None if name == NO_VIEWS else self.controller.view_image(name)
        if frame is None:
            p.thumb.visible = False
            p.thumb_note.content = "*No thumbnail.*" if name != NO_VIEWS else ""
            p.thumb_note.visible = name != NO_VIEWS
            return
        p.thumb.image = gray_to_rgb(frame.pixels, max_width=200)
        p.thumb.visible = True
        p.thumb_note.visible = False

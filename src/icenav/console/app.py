"""The operator console: a viser server showing the controller's state and sending its requests.

Layout (for the bedside, docs/console.md)
-----------------------------------------
- Left, the main panel: the live ICE image, as large as the window allows with its aspect
  kept, with a depth scale in cm, the sector's orientation marker, an ECG strip (when the
  console has a cardiac phase source) and the display's gain and depth.
- Middle, the 3-D scene (enlarge it by dragging the panel edges or minimizing the image).
- Right, the control panel: a safety bar that never scrolls (E-STOP, Stop, the mode, robot,
  tracker, who holds control and the gamepad in words; in ESTOP / FAULT a banner with the
  cause and its Reset button), then this browser's controls and the status.
- Keyboard shortcuts (:data:`icenav.console.labels.SHORTCUTS`): Space = Stop, Esc = E-STOP,
  G = go to the selected view, V = save a view, T = take control.

Threads
-------
- The control thread calls the console's listener with each published state; the listener
  only drops the state into a :class:`~icenav.console.panels.LatestSlot` (never blocks).
- One refresh thread wakes at ``refresh_hz``, takes the newest state (older ones are
  coalesced away; the controller's snapshot when a draw did not finish), draws the safety
  bar from that state alone, updates the scene and panels, and sends a new ICE image.
- viser's thread pool runs the GUI callbacks, which only submit commands to the controller
  (:mod:`icenav.console.commands`); what the controller decided is shown in the panel of the
  browser that asked. Export DICOM writes its file on the refresh thread once accepted.

Several browsers may connect. The safety bar, the image, the plot and the 3-D scene are
shared; each browser has its own driving controls (:mod:`icenav.console.client_panel`), enabled
only while it holds control and the robot is not halted. Who may do what is the
controller's decision (:mod:`icenav.control.authorization`), not the console's. Delete view
and Calibrate ask for confirmation. With a control token (``Console(..., control_token=...)``,
as ``icenav demo`` sets when exposed) a browser is view only until it entered the token
(constant-time comparison, rate-limited guesses with a logged alarm: ``TokenGate``).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icenav.console.client_panel import CALIBRATIONS, ClientPanel
from icenav.console.commands import NO_VIEWS, ConsoleCommands, next_name
from icenav.console.display import (
    DisplaySettings,
    ecg_samples,
    heart_rate_bpm,
    imaged_depth_cm,
    render_display,
)
from icenav.console.freshness import (
    ConsoleConfig,
    StateFreshness,
    check_publish_period,
    stale_banner_html,
)
from icenav.console.jog import JogRepeater, check_deadman
from icenav.console.jog_controls import JogControls
from icenav.console.labels import (
    SHORTCUTS,
    GamepadState,
    alarm_html,
    halt_banner,
    jog_rate_words,
    md,
    safety_markdown,
)
from icenav.console.layout import (
    CONTROL_PANEL_PX,
    IMAGE_DISPLAY_PX,
    IMAGE_PANEL_PX,
    PAGE_CSS,
    STATUS_SLOT,
)
from icenav.console.panels import (
    JointHistory,
    LatestSlot,
    client_name,
    mode_from_choice,
    progress_percent,
    status_markdown,
    summary_markdown,
)
from icenav.console.scene import AnatomyMesh, as_anatomy_meshes
from icenav.console.scene_view import SceneLabel, SceneView, as_scene_labels
from icenav.control.authorization import TokenGate
from icenav.control.commands import (
    CommandResult,
    GoToView,
    Outcome,
    RefineView,
    Reset,
    SaveView,
    SetCompensation,
    SetMode,
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

MESSAGE_S = 15.0
"""A controller message (not a fault's cause) is shown this long after it last changed (s)."""


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


class Console(JogControls, ConsoleCommands):
    """The browser console of one controller.

    Parameters
    ----------
    controller : ControllerCommands
        The controller to show and drive.
    host, port : str, int
        Where to serve (127.0.0.1 unless told otherwise; ``port=0`` picks a free port).
    anatomy_mesh : sequence of AnatomyMesh or (name, vertices, faces, rgb, opacity), optional
        Anatomy surfaces in the base frame (mm), drawn translucently; None shows none.
    anatomy_labels : sequence of landmarks, optional
        Labels of the anatomy (objects with ``key``, ``label``, ``name`` and ``point`` in the
        base frame, mm, as ``icenav.apps.wiring.anatomy_labels()`` gives, or such tuples);
        keys ``dir-<letter>`` are the patient directions (unit vectors) of the orientation
        marker. None: no labels.
    cardiac_phase : callable, optional
        Cardiac phase (fraction of the beat, 0 = R wave) at a controller time (s): the ECG
        strip under the image is drawn from it. None: no ECG strip.
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
    config : ConsoleConfig, optional
        The safety bar's settings (``stale_after_s``: when it says the controller's state is
        unknown; :mod:`icenav.console.freshness`).
    clock : callable
        The console's clock (s, monotonic): the age of the shown state, the message's
        15 s.
    """

    def __init__(
        self,
        controller: ControllerCommands,
        host: str = "127.0.0.1",
        port: int = 8080,
        anatomy_mesh: Sequence[AnatomyMesh | tuple[str, Any, Any, Any, float]] | None = None,
        *,
        anatomy_labels: Sequence[Any] | None = None,
        cardiac_phase: Callable[[float], float] | None = None,
        refresh_hz: float = 25.0,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
        mapping: JoystickMapping | None = None,
        max_roadmap_points: int = 1500,
        jog_hz: float = 20.0,
        status_hz: float = 10.0,
        control_token: str | None = None,
        export_dir: str | Path | ExportDirectory | None = None,
        config: ConsoleConfig | None = None,
        clock: Callable[[], float] = time.monotonic,
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
        self.config = config or ConsoleConfig()
        check_publish_period(controller, self.config.stale_after_s)
        check_deadman(self.config.jog_deadman_s, jog_hz)
        self._clock = clock
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
        self.jog = JogRepeater(jog_hz, self.config.jog_deadman_s, on_trip=self._jog_tripped)
        """Keeps a held on-screen jog going between the browser's hold messages; its
        dead-man stops it (:mod:`icenav.console.jog`)."""
        self.geometry = geometry
        self.mapping = mapping or JoystickMapping()
        self._jog_rates = jog_rate_words(self.mapping)
        self.max_roadmap_points = max_roadmap_points
        self.anatomy = as_anatomy_meshes(anatomy_mesh)
        self.labels: tuple[SceneLabel, ...] = as_scene_labels(anatomy_labels)
        self.cardiac_phase = cardiac_phase
        self.display = DisplaySettings()
        """The image display's gain and depth (set from the image panel)."""
        self._slot = LatestSlot()
        self._reset_view_state()
        self._panels: dict[int, ClientPanel] = {}
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
        self._last_frame: ImageFrame | None = None
        self._message = ("", 0.0)
        self._drawn: ControllerState | None = None
        """The state the latest draw finished (None until one did)."""
        self._halt_html: str | None = None
        self._stale_html: str | None = None
        """The alarm area's halt and stale-state banners (HTML; None: not shown)."""
        self.freshness = StateFreshness(self.config.stale_after_s, self._clock)
        """When the refresh last saw a new state (the stale-state banner)."""

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
        self.jog.start()

    def stop(self) -> None:
        """Stop refreshing, release control held by browsers and close the server."""
        if not self._running:
            return
        self._running = False
        self._stop.set()
        self.jog.stop()
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
        gui = s.gui
        gui.configure_theme(control_width="large", show_share_button=False)
        safety = gui.add_tab_group(order=0.0)  # the safety bar: a box (sticky: PAGE_CSS)
        with safety.add_tab("Safety"):
            gui.add_html(PAGE_CSS)
            self._estop = gui.add_button(
                "E-STOP", color="red", hint="Emergency stop: all axes, any mode, anyone (Esc)"
            )
            self._stop_btn = gui.add_button(
                "Stop", color="orange", hint="End the automatic motion and hold (Space)"
            )
            self._safety = gui.add_markdown("*Waiting for the controller...*")
            # the alarm area and Reset keep their place whether shown or not: nothing
            # below them moves under a pointer when a banner comes or goes
            self._alarm = gui.add_html(alarm_html(None, None))
            self._reset = gui.add_button(
                "Reset fault",
                color="yellow",
                disabled=True,
                hint="Clears the E-STOP or fault (the controller accepts it from the holder)",
            )
            self._error_md = gui.add_markdown("")
        self._estop.on_click(lambda ev: self.controller.estop(client=self._client_of(ev)))
        self._stop_btn.on_click(lambda ev: self.controller.stop(client=self._client_of(ev)))
        self._reset.on_click(lambda ev: self._for_panel(ev, self._reset_for))
        self._build_image_panel(gui)
        with gui.add_folder("3-D scene", order=15.0, expand_by_default=False):
            gui.add_markdown(
                "Drag the image panel's edge (or minimize it) to enlarge the scene. Orange: "
                "the catheter; blue: the model's ghost; small axes: the EM sensor; green: "
                "saved views (click one to select it)."
            )
            self._show_roadmap = gui.add_checkbox("Show the roadmap", initial_value=True)
            self._show_labels = gui.add_checkbox("Show anatomy labels", initial_value=True)
            self._show_fan = gui.add_checkbox("Show the image in 3-D", initial_value=True)
        with gui.add_folder("Status", order=20.0, expand_by_default=False):
            self._status = gui.add_markdown("*Waiting for the controller...*")
            self._plot = self._joint_plot(gui)
        with gui.add_folder("Keyboard shortcuts", order=30.0, expand_by_default=False):
            rows = "\n".join(f"| **{k}** | {what} |" for k, what in SHORTCUTS)
            gui.add_markdown(f"| key | does |\n|---|---|\n{rows}\n\nNot while typing in a field.")
        self._build_shortcuts(gui)
        self.scene = SceneView(
            s, self.anatomy, self.geometry, self.max_roadmap_points, labels=self.labels
        )
        self.scene.on_view_click = self._view_marker_clicked
        self._show_roadmap.on_update(lambda ev: self.scene.show_roadmap(self._show_roadmap.value))
        self._show_labels.on_update(lambda ev: self.scene.show_labels(self._show_labels.value))
        self._show_fan.on_update(lambda ev: self.scene.show_image(self._show_fan.value))
        gui.main_panel.dock_right()
        gui.main_panel.set_width(CONTROL_PANEL_PX)

    def _build_image_panel(self, gui: Any) -> None:
        panel = gui.add_panel()
        with panel.add_tab("ICE image"):
            self._summary = gui.add_markdown("*Waiting for the controller...*")
            self._image_placeholder = gui.add_markdown("*No ICE image yet.*")
            self._image = gui.add_image(
                np.zeros((8, 8, 3), np.uint8),
                label=None,
                format="jpeg",
                jpeg_quality=85,
                visible=False,
            )
            self._progress_label = gui.add_markdown("", visible=False)
            self._progress = gui.add_progress_bar(0.0, visible=False, animated=True)
            self._gain = gui.add_slider(
                "Gain (dB)", min=-20.0, max=20.0, step=1.0, initial_value=0.0,
                hint="Display gain: brightens or darkens the picture (not the acquisition)",
            )  # fmt: skip
            self._depth = gui.add_slider(
                "Depth (cm)", min=2.0, max=20.0, step=0.5, initial_value=20.0,
                hint="Displayed depth (the image is cut below it)",
            )  # fmt: skip
        panel.dock_left()
        panel.set_width(IMAGE_PANEL_PX)
        self._image_panel = panel

        def changed(ev: Any) -> None:
            self.display = DisplaySettings(float(self._gain.value), float(self._depth.value))
            self._redraw_image()

        self._gain.on_update(changed)
        self._depth.on_update(changed)

    def _joint_plot(self, gui: Any) -> Any:
        import viser.uplot as uplot

        empty = tuple(np.zeros(0) for _ in range(5))
        return gui.add_uplot(
            empty,
            (
                uplot.Series(label="t (s)"),
                uplot.Series(label="AP knob (°)", stroke="#d9480f", width=2),
                uplot.Series(label="RL knob (°)", stroke="#1971c2", width=2),
                uplot.Series(label="roll (°)", stroke="#2f9e44", width=2),
                uplot.Series(label="translation (mm)", stroke="#7048e8", width=2, scale="mm"),
            ),
            title="Joint states, last 10 s",
            scales={"x": uplot.Scale(time=False), "mm": uplot.Scale(auto=True)},
            axes=(
                uplot.Axis(),
                uplot.Axis(label="°"),
                uplot.Axis(label="mm", scale="mm", side=1),
            ),
            aspect=1.6,
        )

    def _build_shortcuts(self, gui: Any) -> None:
        """Keyboard shortcuts (viser commands with hotkeys; not while typing in a field)."""
        ctl = self.controller

        def on(key: str, label: str, fn: Callable[[Any], object]) -> None:
            cmd = gui.add_command(label, hotkey=key)
            cmd.on_trigger(fn)

        on("escape", "E-STOP", lambda ev: ctl.estop(client=self._client_of(ev)))
        on("space", "Stop", lambda ev: ctl.stop(client=self._client_of(ev)))
        on("G", "Go to the selected view", lambda ev: self._for_panel(ev, self._goto))
        on("V", "Save a view", lambda ev: self._for_panel(ev, self._save))
        on("T", "Take control", lambda ev: self._for_panel(ev, self._take))

    def _for_panel(self, ev: Any, fn: Callable[[ClientPanel], None]) -> None:
        with self._lock:
            panel = self._panels.get(ev.client_id)
        if panel is not None:
            fn(panel)

    # ------------------------------------------------------------------ browsers
    def _on_connect(self, client: Any) -> None:
        panel = ClientPanel(client, self.control_token is not None, self.export_dir is not None)
        ctl = self.controller
        name = panel.name
        if not panel.authorised:  # the controller refuses everything but Stop / E-STOP
            ctl.set_view_only(name, True)

        def ok(ev: Any) -> bool:
            return ev.client is not None

        panel.take.on_click(lambda ev: self._take(panel))
        panel.release.on_click(lambda ev: ctl.release_control(name))

        @panel.mode.on_update
        def _(ev: Any) -> None:
            if ok(ev) and panel.mode.value in panel.mode.options[:3]:
                self.send(panel, SetMode(mode_from_choice(panel.mode.value), source=panel.source))

        @panel.compensation.on_update
        def _(ev: Any) -> None:
            if ok(ev):
                enabled = bool(panel.compensation.value)
                self.send(panel, SetCompensation(enabled, source=panel.source))

        panel.spin.on_click(lambda ev: self.send(panel, Spin(source=panel.source)))

        @panel.calibrate.on_click
        def _(ev: Any) -> None:
            kind: CalibrationKind = CALIBRATIONS[panel.calib_kind.value]  # type: ignore[assignment]
            self._confirm_calibration(panel, kind)

        panel.save.on_click(lambda ev: self._save(panel))
        panel.goto.on_click(lambda ev: self._goto(panel))
        panel.refine.on_click(lambda ev: self._refine(panel))

        @panel.delete.on_click
        def _(ev: Any) -> None:
            if panel.views.value != NO_VIEWS:
                self._confirm_delete(panel, str(panel.views.value))

        self._wire_jog(panel)

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
            self.jog.release(panel.name)
            self.controller.disconnect(panel.name)

    def _client_of(self, ev: Any) -> str:
        return "browser" if ev.client_id is None else client_name(ev.client_id)

    def _take(self, panel: ClientPanel) -> None:
        ctl = self.controller
        if not panel.authorised and panel.token is not None and self._token_gate:
            verdict = self._token_gate.check(panel.name, str(panel.token.value).strip())
            if not verdict.ok:
                panel.note.content = f"**{verdict.reason}**"
                return
            panel.authorised = True
            ctl.set_view_only(panel.name, False)
        if not ctl.acquire_control(panel.name):
            panel.tell("**Take control refused**: another client holds control.")

    def _save(self, panel: ClientPanel) -> None:
        """Save view: an empty or duplicate name is refused here, with a message."""
        view = str(panel.view_name.value).strip()
        if not view:
            panel.tell("**Not saved**: type a name for the view first.", "save_view")
            return
        if view in panel.view_options:
            panel.tell(
                f"**Not saved**: a view named **{md(view)}** exists; choose another name "
                "(or delete that view first).",
                "save_view",
            )
            return

        def saved(result: CommandResult) -> None:  # a refused save keeps the name
            if result.outcome is Outcome.ACCEPTED and panel.view_name.value == view:
                panel.view_name.value = next_name(view)

        self.send(panel, SaveView(view, source=panel.source), on_decided=saved)

    def _goto(self, panel: ClientPanel, view: str | None = None) -> None:
        name = panel.views.value if view is None else view
        if name != NO_VIEWS:
            self.send(panel, GoToView(str(name), source=panel.source))

    def _refine(self, panel: ClientPanel) -> None:
        name = panel.views.value
        if name != NO_VIEWS:
            self.send(panel, RefineView(str(name), source=panel.source))

    def _reset_for(self, panel: ClientPanel) -> None:
        self.send(panel, Reset(source=panel.source))

    def _view_marker_clicked(self, view: str, client_id: int | None) -> None:
        """A click on a saved view's marker in the scene selects it in that browser."""
        with self._lock:
            panel = self._panels.get(client_id) if client_id is not None else None
        if panel is not None and view in panel.view_options:
            panel.views.value = view

    # ------------------------------------------------------------------ refreshing
    def refresh_once(self) -> bool:
        """Draw the newest state and image; True if a state was drawn.

        The newest state the listener got, else the controller's ``snapshot()`` when the
        latest draw did not finish with it: a draw that failed halfway is done again at
        the next refresh (not left half drawn until the controller publishes again), and
        a state told to no listener (``publish_minimal`` after a failed publish: the
        FAULT) still reaches the page. The stale-state banner follows the age of the newest
        state seen (:mod:`icenav.console.freshness`), drawn before the state."""
        drew = False
        state = self._slot.take()
        current = self.controller.snapshot()
        self.freshness.saw(state)
        self.freshness.saw(current)
        self._draw_staleness()
        if state is None and current is not self._drawn:
            state = current
        if state is not None and state is not self._drawn:
            self._draw_state(state)
            self._drawn = state
            self._refreshes += 1
            drew = True
        frame = self.controller.latest_image()
        if frame is not None and frame.timestamp != self._last_image_t:
            self._draw_image(frame, state or self._last_state)
            self._last_image_t = frame.timestamp
            self._images_sent += 1
        self._serve_panels()
        return drew

    def gamepad_state(self) -> GamepadState:
        """The controller's gamepad (``controller.publisher.gamepad()`` when it has one)."""
        get = getattr(getattr(self.controller, "publisher", None), "gamepad", None)
        return get() if callable(get) else "none"

    def _fresh_message(self, state: ControllerState) -> str:
        """The controller's message, dropped :data:`MESSAGE_S` after it last changed."""
        now = self._clock()
        if state.message != self._message[0]:
            self._message = (state.message, now)
        return state.message if now - self._message[1] <= MESSAGE_S else ""

    def _draw_state(self, state: ControllerState) -> None:
        with self._lock:
            self._last_state = state
        self._draw_safety(state)
        self._summary.content = summary_markdown(state, self._fresh_message(state))
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
            label = md(state.progress_label or "Progress")
            self._progress_label.content = f"{label}: {pct:.0f} %"
        self.scene.draw_state(state)
        with self._lock:  # a browser connecting or leaving waits for this
            for p in self._panels.values():
                self._update_panel(p, state)

    def _draw_safety(self, state: ControllerState) -> None:
        """The safety bar from ``state`` alone: the status line; in ESTOP or FAULT the
        banner with its cause and the Reset button, hidden otherwise.

        Every draw assigns all of them (viser sends a property only when it differs from
        the handle's: an unchanged bar costs nothing), so the handles are the one record
        of what the page was sent; no flag kept beside them decides what to redraw."""
        self._safety.content = STATUS_SLOT + safety_markdown(state, self.gamepad_state())
        banner = halt_banner(state)
        self._halt_html = None if banner is None else banner.html()
        self._alarm.content = alarm_html(self._stale_html, self._halt_html)
        self._reset.disabled = banner is None

    def _draw_staleness(self) -> None:
        """The stale-state banner, above the halt banner (which keeps the cause of the last
        state drawn): shown while the newest state is older than ``stale_after_s``."""
        age = self.freshness.stale_age_s()
        self._stale_html = None if age is None else stale_banner_html(age)
        self._alarm.content = alarm_html(self._stale_html, self._halt_html)

    def _draw_image(self, frame: ImageFrame, state: ControllerState | None) -> None:
        self._last_frame = frame
        depth = imaged_depth_cm(frame.pixels, frame.ijk2tip)
        if depth is not None and abs(self._depth.max - depth) > 0.25:
            self._depth.max = round(depth * 2.0) / 2.0
            if self._depth.value > self._depth.max:
                self._depth.value = self._depth.max
        self._redraw_image()
        self.scene.draw_image(frame, state)

    def _redraw_image(self) -> None:
        frame = self._last_frame
        if frame is None or frame.pixels.ndim != 2:
            return
        ecg = None
        note = ""
        if self.cardiac_phase is not None:
            ecg = ecg_samples(self.cardiac_phase, frame.timestamp)
            phase = self.cardiac_phase(frame.timestamp)
            note = (
                f"ECG · HR {heart_rate_bpm(self.cardiac_phase, frame.timestamp):.0f}/min · "
                f"{100 * phase:.0f} % of the beat"
            )
        settings = self.display
        if settings.depth_cm is not None and settings.depth_cm >= self._depth.max:
            settings = DisplaySettings(settings.gain_db, None)
        self._image.image = render_display(
            frame.pixels, frame.ijk2tip, IMAGE_DISPLAY_PX, settings, ecg, note
        )
        self._image.visible = True
        self._image_placeholder.visible = False

    def _update_panel(self, p: ClientPanel, state: ControllerState) -> None:
        if p.update(state, self._jog_rates):
            p.draw_view_list(state.views, self.controller.view_image, self._goto_button(p))
        self._jog_follow(p)

    def _goto_button(self, p: ClientPanel) -> Callable[[str], Callable[[Any], None]]:
        def make(view: str) -> Callable[[Any], None]:
            return lambda ev: self._goto(p, view)

        return make

"""Pure logic of the console's panels: status text, control ownership, jog commands, the
joint-state plot buffer, image conversion and the newest-state slot.

Nothing here imports viser, so all of it is tested without a browser. Degrees and the
``_deg`` names appear only here, where a person reads them.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav.console.labels import MODE_LABELS, client_label, duration_text, md, tracker_label
from icenav.control.state import ControllerState, Mode, ViewSummary
from icenav.control.teleop import JoystickMapping
from icenav.errors import ConfigurationError, ShapeError

__all__ = [
    "ControlView",
    "JOG_AXES",
    "JointHistory",
    "LatestSlot",
    "MODE_CHOICES",
    "client_name",
    "control_view",
    "display_factors",
    "display_pixel_map",
    "gray_to_rgb",
    "jog_command",
    "joint_table_markdown",
    "mode_from_choice",
    "mode_options",
    "progress_percent",
    "status_markdown",
    "summary_markdown",
    "views_markdown",
]

MODE_CHOICES: dict[str, Mode] = {
    "Hold still (idle)": Mode.IDLE,
    "Jog the knobs": Mode.KNOB,
    "Jog the tip": Mode.TIP,
}
"""Mode dropdown label -> mode (the automatic modes start through their own buttons; while
one runs the dropdown shows its name, :func:`mode_options`)."""


def mode_options(mode: Mode) -> tuple[tuple[str, ...], str]:
    """(options, value) of the mode dropdown in ``mode``: the three operator modes, and the
    running automatic or halted mode's name while there is one (so it never says "idle"
    during a spin)."""
    base = tuple(MODE_CHOICES)
    for label, m in MODE_CHOICES.items():
        if m is mode:
            return base, label
    label = MODE_LABELS.get(mode, mode.value)
    return (*base, label), label


JOG_AXES: dict[Mode, tuple[str, str, str, str]] = {
    Mode.KNOB: ("AP knob (phi1)", "RL knob (phi2)", "Roll (phi3)", "Translate (d4)"),
    Mode.TIP: ("Tip x (image dir.)", "Tip y", "Tip z (axis)", "Roll about z"),
}
"""Labels of the four jog axes in each teleoperation mode."""


def client_name(client_id: int) -> str:
    """The controller-facing id of a browser session."""
    return f"browser-{client_id}"


def mode_from_choice(choice: str) -> Mode:
    """The mode a dropdown label names."""
    try:
        return MODE_CHOICES[choice]
    except KeyError:
        raise ConfigurationError(
            f"mode choice must be one of {sorted(MODE_CHOICES)}, got {choice!r}"
        ) from None


def jog_command(
    mode: Mode, axis: int, sign: int, mapping: JoystickMapping | None = None
) -> tuple[Array, Literal["knob", "tip"]]:
    """The jog request an on-screen button sends while held, at the gamepad's full-stick rates.

    Parameters
    ----------
    mode : Mode
        KNOB: ``axis`` 0..3 is phi1, phi2, phi3 (rad/s), d4 (mm/s); returns a (4,) joint
        velocity in the "knob" frame. TIP: ``axis`` 0..2 is tip x, y, z (mm/s), 3 is the
        roll about tip z (rad/s); returns a (6,) tip twist (vx, vy, vz, wx, wy, wz) in the
        "tip" frame.
    axis : int
        0..3.
    sign : int
        +1 or -1.
    """
    m = mapping or JoystickMapping()
    if axis not in (0, 1, 2, 3):
        raise ConfigurationError(f"jog axis must be 0, 1, 2 or 3, got {axis}")
    if sign not in (-1, 1):
        raise ConfigurationError(f"jog sign must be +1 or -1, got {sign}")
    if mode == Mode.KNOB:
        rates = (m.knob_rate, m.knob_rate, m.roll_rate, m.translation_rate)
        vel = np.zeros(4)
        vel[axis] = sign * rates[axis]
        return vel, "knob"
    if mode == Mode.TIP:
        twist = np.zeros(6)
        if axis < 3:
            twist[axis] = sign * m.tip_speed
        else:
            twist[5] = sign * m.roll_rate
        return twist, "tip"
    raise ConfigurationError(f"jogging needs mode KNOB or TIP, not {mode.name}")


@dataclass(frozen=True)
class ControlView:
    """What one browser may do, given who holds control."""

    can_control: bool
    """True when this browser holds control (its motion controls are enabled)."""
    can_take: bool
    """True when control is free, so "Take control" would succeed."""
    text: str
    """Markdown note for this browser."""


def control_view(owner: str | None, me: str) -> ControlView:
    """Control note and permissions of browser ``me`` when ``owner`` holds control."""
    if owner == me:
        return ControlView(True, False, f"**You have control** ({md(client_label(me))}).")
    if owner is None:
        return ControlView(False, True, "**View only**: nobody has control; take it to drive.")
    return ControlView(False, False, f"**View only**: {md(client_label(owner))} has control.")


def joint_table_markdown(q_motor: ArrayLike, q_model: ArrayLike) -> str:
    """Markdown table of the motor and model joint states (deg for angles, mm for d4)."""
    qm = _q4(q_motor, "q_motor")
    qd = _q4(q_model, "q_model")
    rows = ["| joint | motor | model |", "|---|---:|---:|"]
    names = ("phi1 (deg)", "phi2 (deg)", "phi3 (deg)", "d4 (mm)")
    for i, name in enumerate(names):
        a, b = (qm[i], qd[i]) if i == 3 else (math.degrees(qm[i]), math.degrees(qd[i]))
        rows.append(f"| {name} | {a:.1f} | {b:.1f} |")
    return "\n".join(rows)


def _q4(q: ArrayLike, name: str) -> Array:
    a = np.asarray(q, dtype=np.float64)
    if a.shape != (4,):
        raise ShapeError(f"{name} must have shape (4,), got {a.shape}")
    return a


def status_markdown(state: ControllerState) -> str:
    """The status panel: mode, robot, tracker, roadmap, control owner, message, joints."""
    mode = MODE_LABELS.get(state.mode, state.mode.value)
    lines = [
        f"**Mode:** {mode} &nbsp; **Robot:** {state.robot_status.value}",
        f"**Tracker:** {tracker_label(state.tracker_status)} ({state.tracker_status}) &nbsp; "
        f"**Roadmap:** {state.n_vertices} vertices, {state.n_edges} edges",
        f"**Control:** {md(client_label(state.control_owner))} &nbsp; **Compensation:** "
        f"{'on' if state.compensation_enabled else 'off'} &nbsp; **Running for** "
        f"{duration_text(state.time)}",
        f"**Force check of returns:** {md(state.force_check)}",
    ]
    if state.mode in (Mode.FAULT, Mode.ESTOP):
        lines.append(f"**{mode}:** {md(state.message) or '(no message)'}")
    elif state.message:
        lines.append(f"*{md(state.message)}*")
    return "\n\n".join(lines) + "\n\n" + joint_table_markdown(state.q_motor, state.q_model)


def summary_markdown(state: ControllerState, message: str | None = None) -> str:
    """One line above the image: the mode in words and the latest message (``message``
    when given: the console drops a stale one); the cause in FAULT / ESTOP; an open
    question (``state.question``) in front of the message while it can be answered."""
    mode = MODE_LABELS.get(state.mode, state.mode.value)
    text = md(state.message if message is None else message)
    if state.mode in (Mode.FAULT, Mode.ESTOP):
        return f"**{mode}**: {md(state.message) or '(no message)'}"
    if state.question:  # kept in front for as long as it can be answered
        return f"**{mode}**: **Waiting for you:** {md(state.question)}"
    return f"**{mode}**: {text}" if text else f"**{mode}**"


def views_markdown(views: tuple[ViewSummary, ...]) -> str:
    """The view library as a list (name and joint state)."""
    if not views:
        return "*No saved views yet.*"
    rows = []
    for v in views:
        q = v.q_motor
        rows.append(
            f"- **{v.name}**: {math.degrees(q[0]):.0f} / {math.degrees(q[1]):.0f} / "
            f"{math.degrees(q[2]):.0f} deg, {q[3]:.1f} mm"
        )
    return "\n".join(rows)


def progress_percent(progress: float | None) -> float | None:
    """Progress in [0, 1] as a percentage for the bar (clipped), None when there is none."""
    if progress is None or not math.isfinite(progress):
        return None
    return 100.0 * min(1.0, max(0.0, progress))


def display_factors(width: int, max_width: int = 640, min_width: int = 0) -> tuple[int, int]:
    """(down, up): how :func:`gray_to_rgb` resamples an image ``width`` pixels wide.

    ``down`` > 1 keeps every down-th pixel so that the width is <= max_width; otherwise
    ``up`` >= 1 repeats each pixel up times (nearest), the factor that brings the width
    nearest to ``min_width`` without passing ``max_width`` (the browser shows an image at
    its pixel size, never larger).
    """
    if max_width < 1:
        raise ConfigurationError(f"max_width must be >= 1 pixel, got {max_width}")
    if width < 1:
        raise ConfigurationError(f"image width must be >= 1 pixel, got {width}")
    down = max(1, math.ceil(width / max_width))
    if down > 1 or width >= min_width:
        return down, 1
    return 1, max(1, min(round(min_width / width), max_width // width))


def display_pixel_map(down: int, up: int) -> Array:
    """(4, 4) map from displayed pixel (i, j, 0, 1) to original pixel coordinates.

    Pixel coordinates are pixel centres: decimation keeps original pixel ``down * i``;
    enlargement by ``up`` puts displayed pixel i's centre at ``(i + 0.5) / up - 0.5``.
    """
    if down > 1:
        s, o = float(down), 0.0
    else:
        s = 1.0 / up
        o = 0.5 * s - 0.5
    return np.array([[s, 0, 0, o], [0, s, 0, o], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def gray_to_rgb(
    pixels: NDArray[np.uint8], max_width: int = 640, min_width: int = 0
) -> NDArray[np.uint8]:
    """(H, W) B-mode image to (h, w, 3) RGB for JPEG, resampled as :func:`display_factors`
    says (decimated to fit max_width, or enlarged towards min_width)."""
    p = np.asarray(pixels)
    if p.ndim == 3 and p.shape[2] == 3:
        rgb = p
    elif p.ndim == 2:
        rgb = np.repeat(p[:, :, None], 3, axis=2)
    else:
        raise ShapeError(f"image must be (H, W) or (H, W, 3), got {p.shape}")
    down, up = display_factors(rgb.shape[1], max_width, min_width)
    out = rgb[::down, ::down]
    if up > 1:
        out = np.repeat(np.repeat(out, up, axis=0), up, axis=1)
    return np.ascontiguousarray(out.astype(np.uint8, copy=False))


class JointHistory:
    """Joint states over the last ``window_s`` seconds, for the plot."""

    def __init__(self, window_s: float = 10.0):
        if not (math.isfinite(window_s) and window_s > 0):
            raise ConfigurationError(f"window_s must be finite and > 0 s, got {window_s}")
        self.window_s = window_s
        self._t: deque[float] = deque()
        self._q: deque[Array] = deque()

    def append(self, t: float, q: ArrayLike) -> None:
        """Add a sample at controller time ``t`` (s); older samples fall out of the window.

        A time going backwards (a new session) clears the history."""
        if self._t and t < self._t[-1]:
            self._t.clear()
            self._q.clear()
        self._t.append(float(t))
        self._q.append(_q4(q, "q").copy())
        while self._t and self._t[-1] - self._t[0] > self.window_s:
            self._t.popleft()
            self._q.popleft()

    def __len__(self) -> int:
        return len(self._t)

    def uplot_data(self) -> tuple[NDArray[np.float64], ...]:
        """(t - t_now s, phi1 deg, phi2 deg, phi3 deg, d4 mm), each (n,); t_now = last t."""
        if not self._t:
            return tuple(np.zeros(0) for _ in range(5))
        t = np.array(self._t)
        q = np.array(self._q)
        deg = np.degrees(q[:, :3])
        return (t - t[-1], deg[:, 0], deg[:, 1], deg[:, 2], q[:, 3].copy())


class LatestSlot:
    """Hands the newest controller state from the control thread to the refresh thread.

    :meth:`offer` (control thread) only swaps a reference under a lock: it never blocks on
    the console's work. :meth:`take` (refresh thread) returns the newest state since the last
    take, or None; states offered in between are coalesced (dropped).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._state: ControllerState | None = None
        self.offered = 0
        """States offered so far."""
        self.taken = 0
        """States taken so far (offered - taken were coalesced away, or are pending)."""

    def offer(self, state: ControllerState) -> None:
        with self._lock:
            self._state = state
            self.offered += 1

    def take(self) -> ControllerState | None:
        with self._lock:
            s, self._state = self._state, None
            if s is not None:
                self.taken += 1
            return s

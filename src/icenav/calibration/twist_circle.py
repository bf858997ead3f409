"""The distal twist's play over the whole knob plane, read the way a spin uses it (beyond the
paper).

The bent roll sweeps (:func:`icenav.calibration.hysteresis.hysteresis_plan`) read the roll's
and the twist's plays with the knobs *held* in one direction each (the AP knob at three bends,
three further directions at one), and the law over the knob plane assumes the play depends on
the bending plane's axis only (period 180 deg, :class:`~icenav.compensation.bend_play.
KnobPlanePlay`). An image spin moves otherwise: the knobs turn the bending plane through every
direction while the roll turns the other way, so the tendons' tensions (and with them the
plays that grow with them) are those of a turning section, in both senses of each axis.

The **spin circle** (:func:`spin_circle_path`) is that motion, coarsely: the knobs at
``knob`` along direction ``theta`` with the roll at ``-theta`` (the base-frame bending plane
stays put, as in a spin), ``theta`` stepped from 0 up by one turn and a lead-in and back, one
tracker reading per stop. At each stop the model inverse kinematics of the tracked pose gives
the image frame's roll ``phi3'`` and the section's direction; with ``x3`` the motor roll and
``s`` the sense the roll turns in, ``x3 - phi3' = s (w + h) + c`` (the image lags the motor by
the roll's play ``w`` and the twist's ``h``; ``c`` the static part, the same in both senses).
Half the difference between the two senses at one direction is the image frame's whole play
``w + h`` there (TC1); less the roll's play that the sweeps identified (its law over the knob
plane) it is the twist's (TC2)::

    w + h (psi) = (y_+(psi) - y_-(psi)) / 2,   y = x3 - phi3'                     (TC1)
    h (psi)     = max(w + h (psi) - w(b, psi), 0)                                  (TC2)

so that the image's total lag, which is what a spin's image rotation meets, is the one read
while turning. The circle is held out from the sweeps' law; where that law predicts the
circle's readings within :data:`AGREEMENT` RMS, it is kept (it has three bends, the circle
one), else the circle's readings replace it (TC3). What it assumes: the plays are those of
a steady turn in each sense (a stop's reading after ``lead`` of turning one way), the twist
depends on the direction of the bending plane over the whole plane (period 360 deg) and on
the bend through the AP knob's shape, and the roll's play law is right (its error passes
into the twist's, so the image's total is kept). Nothing in it is a friction law.
"""

from __future__ import annotations

import math

import numpy as np

from icenav._typing import Array
from icenav.compensation.bend_play import PlayLaw
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry
from icenav.geometry.kinematics import inverse as kin_inverse

__all__ = [
    "AGREEMENT",
    "CIRCLE_DIRECTIONS",
    "CIRCLE_KNOB",
    "CIRCLE_LEAD",
    "CIRCLE_STEP",
    "SPIN_CIRCLE",
    "circle_twist_readings",
    "spin_circle_path",
]

SPIN_CIRCLE = "spin circle"
"""Phase name of the spin circle's stops in a plan."""

CIRCLE_KNOB = math.radians(50.0)
"""Knob angle of the spin circle (rad; the bent roll sweeps' ``roll_bend``)."""

CIRCLE_STEP = math.radians(30.0)
"""Step of the circle's direction (rad): coarse, the robot-time budget's (docs/calibration.md
section 7); the readings are interpolated between stops."""

CIRCLE_LEAD = math.radians(60.0)
"""Turning before a stop is read in a sense (rad of motor roll): the roll's and the twist's
plays together are up to about 30 deg at the circle's bend on the development catheters."""

CIRCLE_DIRECTIONS = 12
"""Directions (evenly over 360 deg) at which the twist's play is read off the circle."""

AGREEMENT = math.radians(1.0)
"""RMS (rad) over the circle's directions within which the sweeps' twist law, which the circle
did not fit, predicts the circle's readings well enough to be kept (TC3): about the readings'
own error (1.1 deg RMS against the plant's own play on two families of other forms, tested)."""


def spin_circle_path(
    knob: float = CIRCLE_KNOB, step: float = CIRCLE_STEP, lead: float = CIRCLE_LEAD
) -> Array:
    """(m, 4) motor states of the spin circle: ``(knob cos t, knob sin t, -t, 0)`` for ``t``
    from ``step`` up to ``2 pi + lead`` and back down to 0, in ``step`` (rad)."""
    for name, v, hi in (("knob", knob, math.pi / 2), ("step", step, math.pi / 2)):
        if not (0.0 < v <= hi):
            raise ConfigurationError(
                f"spin circle {name} must be in (0, {math.degrees(hi):.0f}] deg, got "
                f"{math.degrees(v):.1f} deg"
            )
    if not (0.0 <= lead <= math.pi):
        raise ConfigurationError(
            f"spin circle lead must be in [0, 180] deg, got {math.degrees(lead):.1f} deg"
        )
    n_up = math.ceil((2.0 * math.pi + lead) / step - 1e-9)
    up = step * np.arange(1, n_up + 1)
    down = up[-1] - step * np.arange(1, n_up + 1)
    t = np.concatenate([up, down])
    return np.column_stack([knob * np.cos(t), knob * np.sin(t), -t, np.zeros_like(t)])


def _periodic_interp(at: Array, x: Array, y: Array) -> Array:
    """``y(x)`` interpolated linearly and periodically (2 pi) at ``at`` (rad)."""
    order = np.argsort(np.mod(x, 2.0 * math.pi))
    xs = np.mod(x, 2.0 * math.pi)[order]
    return np.interp(np.mod(at, 2.0 * math.pi), xs, y[order], period=2.0 * math.pi)


def circle_twist_readings(
    q_motor: Array,
    poses: Array,
    roll_width: PlayLaw | None,
    roll_base: float,
    *,
    lead: float = CIRCLE_LEAD,
    n_directions: int = CIRCLE_DIRECTIONS,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> tuple[Array, Array, Array]:
    """The twist's play read off a recorded spin circle, (TC1)-(TC2).

    Parameters
    ----------
    q_motor : (m, 4) motor states of the circle (rad, rad, rad, mm), in the order driven
        (the stop before the first is taken at roll 0).
    poses : (m, 4, 4) tracked tip2base (NaN where missing).
    roll_width : the roll's extra play over the straight one, ``e(b, psi)`` (rad; None: 0).
    roll_base : the roll's straight play half-width (rad).
    lead, n_directions : turning before a stop counts (rad) and directions read.

    Returns
    -------
    directions (n,) rad in [0, 2 pi), tracked bends (n,) rad and the twist's half-width
    (n,) rad (NaN where a sense does not cover the whole plane).
    """
    q = np.asarray(q_motor, dtype=np.float64)
    t = np.asarray(poses, dtype=np.float64)
    dirs = 2.0 * math.pi * np.arange(n_directions) / n_directions
    nan = np.full(n_directions, np.nan)
    x3 = q[:, 2]
    dx = np.diff(np.concatenate([[0.0], x3]))
    sense = np.sign(dx)
    run = np.zeros(x3.size)  # turning in the present sense up to each stop (rad)
    for k in range(x3.size):
        same = k > 0 and sense[k] == sense[k - 1]
        run[k] = (run[k - 1] if same else 0.0) + abs(dx[k])
    ok = np.all(np.isfinite(t.reshape(len(t), -1)), axis=1) & (run >= lead - 1e-9) & (sense != 0)
    if not np.any(ok):
        return dirs, nan, nan.copy()
    qm = kin_inverse(t[ok], geometry, check=False)
    x = x3[ok]
    s = sense[ok]
    phi3 = qm[:, 2] + 2.0 * math.pi * np.round((x - qm[:, 2]) / (2.0 * math.pi))
    bend = np.arccos(np.clip(t[ok][:, 2, 2], -1.0, 1.0))
    # the section's direction: the model knobs' turned back by the twist t = phi3' - p3,
    # p3 = x3 - s w (the roll's play from its law, at the knobs' direction first)
    psi0 = np.arctan2(qm[:, 1], qm[:, 0])
    w = roll_base + (0.0 if roll_width is None else np.asarray(roll_width(bend, psi0)))
    psi = psi0 + (phi3 - (x - s * w))
    w = roll_base + (0.0 if roll_width is None else np.asarray(roll_width(bend, psi)))
    y = x - phi3
    half = []
    bends = []
    for sgn in (1.0, -1.0):
        m = s == sgn
        cover = np.sort(np.mod(psi[m], 2.0 * math.pi))
        if cover.size < 3 or np.max(np.diff(np.append(cover, cover[0] + 2 * math.pi))) > 2.0 * (
            CIRCLE_STEP + math.radians(10.0)
        ):
            return dirs, nan, nan.copy()
        half.append(_periodic_interp(dirs, psi[m], y[m]))
        bends.append(_periodic_interp(dirs, psi[m], bend[m]))
    total = 0.5 * (half[0] - half[1])  # (TC1)
    b = 0.5 * (bends[0] + bends[1])
    wd = roll_base + (0.0 if roll_width is None else np.asarray(roll_width(b, dirs)))
    return dirs, b, np.maximum(total - wd, 0.0)  # (TC2)

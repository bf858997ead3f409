"""The bending plane's lag read while turning, from the spin circle (beyond the paper).

In an image spin the knobs turn the bending plane through the knob plane while the roll turns
the other way, so that the plane stays put in the base frame. Where the plane lands is the
*sum* of two lags: the knobs' effective direction behind their command (the per-tendon
transmission, :mod:`icenav.compensation.transmission`) and the section's roll behind the
motor (the roll's play, :mod:`icenav.calibration.hysteresis`). Each is identified from its
own motions (the knob circles; the roll sweeps with the knobs held), and an error in either
moves the plane sideways: the tip's tangential error.

The spin circle (:mod:`icenav.calibration.twist_circle`) is the spin's own motion, so it reads
what the spin meets. At each of its stops the fitted map (:class:`~icenav.compensation.
tendon_map.TendonKnobMap`, driven through the circle's commands from rest) predicts the tip;
the tracked tip (tracker bias removed) says where it is. With ``r`` the tracked azimuth of the
tip about the base axis less the predicted one and ``s`` the sense the roll turns in::

    e(psi) = (r_+(psi) - r_-(psi)) / 2                                            (PL1)

is the part of the plane's error that flips with the sense of turning: a lag the two models
together get wrong (the part the same in both senses is static: F's, not a lag). A roll play
wider by ``delta`` moves the prediction by ``-s delta``, so the constant ::

    delta = -mean_psi e(psi)                                                       (PL2)

removes it. It is given to the roll's play and taken from the twist's, in every direction at
the circle's bend (each law over the bend keeps its shape, scaled through the new value:
B6): the image frame's whole lag (the roll's and the twist's plays together, which the
circle's TC1 reads and the image rotation meets) is unchanged, and the motor roll a spin
commands with it; only the split moves, and with it the knobs' lead: the plane lands where
the circle says. Kept only where the circle's own data say it predicts (PL3): ``delta``
from the even directions predicts the odd ones' ``e`` and the other way round, and their
held-out RMS must fall to :data:`KEEP_RATIO` of the RMS without it.

What it assumes: the plane's lag in a spin is the circle's (one bend, about 55-75 deg of
tracked bend; at other bends the roll's and the twist's laws carry ``delta`` with their
shapes), the same in every direction (one number: the readings' scatter does not carry a
law over the direction), and it belongs to the spin's coupled motion (a roll turned alone
with the knobs held meets the roll's play as the sweeps read it, so the correction there is
off by ``delta``). No friction law, rate or relaxation term is in it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icenav._typing import Array
from icenav.calibration.hysteresis import HysteresisIdentification, direction_law
from icenav.calibration.twist_circle import (
    CIRCLE_DIRECTIONS,
    CIRCLE_LEAD,
    CIRCLE_STEP,
    periodic_interp,
    turning_runs,
)
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay, PlayLaw
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.compensation.transmission import TendonCompensator, TransmissionCalibration
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = [
    "KEEP_RATIO",
    "PlaneLag",
    "apply_plane_lag",
    "circle_plane_lag",
    "predicted_circle",
    "shift_plays",
]

KEEP_RATIO = 0.8
"""(PL3): the held-out RMS of the plane's reversing error with ``delta`` must be at most this
fraction of the RMS without it for ``delta`` to be kept."""


@dataclass(frozen=True)
class PlaneLag:
    """The spin circle's reading of the bending plane's lag (PL1)-(PL3)."""

    directions: Array
    """(n,) directions of the knob plane read (rad, [0, 2 pi))."""
    bends: Array
    """(n,) tracked bend there (rad)."""
    reversing: Array
    """(n,) ``e(psi)`` (PL1): the plane's error that flips with the sense (rad; NaN where a
    sense does not cover the plane)."""
    delta: float
    """(PL2) (rad): the roll's play to add and the twist's to take (0 where not kept)."""
    held_out_rms: tuple[float, float]
    """Two-fold held-out RMS of ``e`` without and with ``delta`` (rad) (PL3)."""
    kept: bool
    """Whether ``delta`` passed (PL3)."""


def _wrap(a: Array) -> Array:
    return np.asarray((a + math.pi) % (2.0 * math.pi) - math.pi)


def predicted_circle(
    transmission: TransmissionCalibration,
    q_motor: Array,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> Array:
    """(m, 4, 4) tips the map of ``transmission`` predicts at the circle's motor states
    ``q_motor`` (m, 4), driven through them in order from rest at zeros."""
    q = np.asarray(q_motor, dtype=np.float64)
    km = TendonKnobMap(transmission, np.zeros(4), geometry=geometry)
    predicted = np.empty((q.shape[0], 4))
    for k, row in enumerate(q):
        predicted[k] = km.motor_to_model(row, check=False)
        km.observe(row)
    predicted[:, 3] = q[:, 3]
    return np.asarray(forward(predicted, geometry, check=False))


def circle_plane_lag(
    q_motor: Array,
    tracked: Array,
    predicted: Array,
    *,
    lead: float = CIRCLE_LEAD,
    n_directions: int = CIRCLE_DIRECTIONS,
) -> PlaneLag:
    """(PL1)-(PL3) from a spin circle: its motor states ``q_motor`` (m, 4) in the order
    driven, the tracked tips ``tracked`` (m, 4, 4; tracker bias removed, NaN where missing)
    and the tips a model predicts there ``predicted`` (m, 4, 4, :func:`predicted_circle`);
    the stops after ``lead`` (rad) of turning in a sense, read in ``n_directions``
    directions of the predicted bend."""
    q = np.asarray(q_motor, dtype=np.float64)
    t = np.asarray(tracked, dtype=np.float64)
    p = np.asarray(predicted, dtype=np.float64)
    dirs = 2.0 * math.pi * np.arange(n_directions) / n_directions
    nan = np.full(n_directions, np.nan)
    none = PlaneLag(dirs, nan, nan.copy(), 0.0, (math.nan, math.nan), False)
    sense, run = turning_runs(q[:, 2])
    ok = np.all(np.isfinite(t.reshape(len(t), -1)), axis=1) & (run >= lead - 1e-9) & (sense != 0)
    if not np.any(ok):
        return none
    tip = p[ok, :3, 3]
    r = _wrap(np.arctan2(t[ok, 1, 3], t[ok, 0, 3]) - np.arctan2(tip[:, 1], tip[:, 0]))
    # the bend's direction in the knob plane: the predicted tip's, turned by the motor roll
    psi = _wrap(np.arctan2(tip[:, 1], tip[:, 0]) - q[ok, 2])
    bend = np.arccos(np.clip(t[ok][:, 2, 2], -1.0, 1.0))
    s = sense[ok]
    per_sense, bends = [], []
    for sgn in (1.0, -1.0):
        m = s == sgn
        cover = np.sort(np.mod(psi[m], 2.0 * math.pi))
        if cover.size < 3 or np.max(np.diff(np.append(cover, cover[0] + 2 * math.pi))) > (
            2.0 * (CIRCLE_STEP + math.radians(10.0))
        ):
            return none
        per_sense.append(periodic_interp(dirs, psi[m], r[m]))
        bends.append(periodic_interp(dirs, psi[m], bend[m]))
    e = 0.5 * (per_sense[0] - per_sense[1])  # (PL1)
    b = 0.5 * (bends[0] + bends[1])
    delta = -float(np.mean(e))  # (PL2)
    even, odd = e[0::2], e[1::2]
    without = math.sqrt(float(np.mean(e**2)))
    with_ = math.sqrt(
        float(np.mean(np.concatenate([even - np.mean(odd), odd - np.mean(even)]) ** 2))
    )
    kept = with_ <= KEEP_RATIO * without  # (PL3)
    return PlaneLag(dirs, b, e, delta if kept else 0.0, (without, with_), kept)


def _shifted(law: PlayLaw | None, lag: PlaneLag, sign: float) -> PlayLaw | None:
    """``law`` with ``sign * delta`` added at the circle's bend in each of its directions
    (clipped at 0), each direction's law the AP knob's scaled through it (B6), period 2 pi."""
    if law is None:
        ap: BendPlay = BendPlay.linear(0.0)
    else:
        first = law.laws[0] if isinstance(law, KnobPlanePlay) else law
        assert isinstance(first, BendPlay)
        ap = first
    laws = []
    for b, d in zip(lag.bends, lag.directions, strict=True):
        now = 0.0 if law is None else float(law(float(b), float(d)))
        value = max(now + sign * lag.delta, 0.0)
        laws.append(direction_law(ap, (float(b), value, value), 1))
    return KnobPlanePlay(tuple(float(d) for d in lag.directions), tuple(laws), period=2.0 * math.pi)


def shift_plays(comp: HysteresisCompensator, lag: PlaneLag) -> HysteresisCompensator:
    """A fresh ``comp`` whose roll's play is ``lag.delta`` wider and whose twist's is as much
    narrower (clipped at 0) at the circle's bend in each direction read (:func:`_shifted`)."""
    return comp.with_plays(_shifted(comp.roll_play, lag, 1.0), _shifted(comp.twist_play, lag, -1.0))


def apply_plane_lag(
    transmission: TransmissionCalibration,
    hysteresis: HysteresisIdentification,
    lag: PlaneLag,
) -> tuple[TransmissionCalibration, HysteresisIdentification]:
    """The transmission's and the identification's compensators with ``lag.delta`` moved
    from the twist's play to the roll's (unchanged when ``lag.kept`` is False)."""
    if not lag.kept or lag.delta == 0.0:
        return transmission, hysteresis
    comp = shift_plays(hysteresis.compensator, lag)
    tc = transmission.compensator
    new_tc = TendonCompensator(
        tc.model, comp, knob_limit=tc.knob_limit, dead_zone_ramp=tc.dead_zone_ramp
    )
    return (
        TransmissionCalibration(
            fit=transmission.fit,
            effective_map=transmission.effective_map,
            compensator=new_tc,
            n_moves=transmission.n_moves,
            section=transmission.section,
        ),
        HysteresisIdentification(
            compensator=comp, fits=hysteresis.fits, n_moves=hysteresis.n_moves
        ),
    )

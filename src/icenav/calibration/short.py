"""A short calibration along the knob rings a spin follows (beyond the paper; a development
condition, ``eval spin --conditions short+rings``).

The issue's short calibration is the paper's 5-point search plus at most 100 moves. The
``short`` condition spends its moves on two roll sweeps and keeps the 5-point F, which
carries neither the knobs' play nor the elastic map between the five points: 2-6x the full
calibration's error. This one spends them where a spin goes: after coarse roll sweeps
(straight and at one bend, 10 deg steps: the roll's and the twist's play as lines,
:func:`icenav.calibration.hysteresis.fit_hysteresis`), the knobs visit ``n_stops`` stops on
each of a few *rings* (circles of constant knob radius, the knob paths of a spin at that
bend), all turned in one sense, one tracker sample at each. F is the paper's interpolant
over the five points and the ring stops (:class:`~icenav.compensation.elasticity.ElasticityMap`)::

    F  built on  {(x_i, T_i)} = five points  U  ring stops (x = motor knobs, T = tracked tip)

A ring stop is reached by turning the knobs one way, so its sample holds the knobs' lag in
that sense (the play, the tendons' stick): F built on it inverts the lag *for motions that
turn the same way*; a motion the other way meets the lag twice. So each ring is turned both
ways (``both_ways``, the default): one F per sense, ``F+`` over the five points and the
stops turned counter-clockwise, ``F-`` over the five points and those turned clockwise, and
a path of model knobs ``m_k`` is commanded through their blend by the sense it turns in::

    s_k = (m_k x (m_{k+1} - m_{k-1})) / (|m_k| |m_{k+1} - m_{k-1}|)    in [-1, 1]
    x_k = (1 + s_k) / 2  F+(m_k)  +  (1 - s_k) / 2  F-(m_k)              (S1)

(a counter-clockwise circle ``s = 1``, a clockwise one ``s = -1``, a radial move ``s = 0``:
the mean of the two). What it assumes: the knobs' lag on a knob path depends on the sense
the path turns about the knob origin (true of a circle, a spin; a radial move gets the mean
of the two senses' lag, which is no lag at all); between the rings' radii F interpolates.
It identifies no knob play model and no tracker bias. With ``both_ways=False`` (the first
development version) the rings turn one way only and F is ``F+``.

*Spin rings* (``spin=True``; an option measured on development catheters, not the default):
each ring stop is reached with the roll turned against the knobs' angle ``a`` turned so far,
so a ring is a spin of the image at the ring's bend, the tip standing still in the base
frame as in the evaluation's spins::

    q_k = (r cos a_k, r sin a_k, -a_k, 0),   a_k continued over the turn and back     (S2)

and the tracker's field bias at that point enters F as a spin meets it (rings at roll 0
teach F the bias as if it turned with the knobs, and a spin through them makes the tracked
tip orbit the intended one). F's samples are taken into the knob frame of the roll
*reached* (the sweeps' play model along the commanded path) and the five points, read at
roll 0, are left out beyond the smallest ring::

    p_i = R_z(-phi3_eff,i) (tip_i - d4 e_z),   phi3_eff = play model (phi3 commanded)  (S3)

*The short roll circle* (``bias_circle=True``; ``eval spin``'s ``short+rings+prior``): F built
on samples read at roll 0 learns the tracker's field bias at each stop as if it turned with
the knobs, and a spin turns it (the tip orbits, its axis tilts). After the sweeps the roll is
stopped at a few angles with the AP knob bent (:func:`bias_circle_path`), each approached
rising, and the field's affine bias ``b(x) = b0 + B x`` is fitted by TB1 of
:mod:`icenav.calibration.tracker_bias` (one knob pose) and removed from every tracked pose
before F and the plays are fitted::

    m_i = R_z(r_i) P + b0 + B R_z(r_i) P   (circle stops),   tip <- tip - b(tip)       (B1)

F then aims the true tip, as the full calibration does. The bent sweep goes in coarser steps
to pay for it (100 moves still).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.calibration.hysteresis import HysteresisPlan, fit_hysteresis, hysteresis_plan
from icenav.calibration.map_prior import MapPrior
from icenav.calibration.plans import MotionPlan, Recording
from icenav.calibration.play_prior import PlayPrior
from icenav.calibration.tracker_bias import fit_tracker_bias
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.compensation.section_length import SectionLength, fit_section_length
from icenav.compensation.tracker_bias import TrackerBias
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = [
    "BIAS_BENT_STEP",
    "BIAS_CIRCLE_SAMPLES",
    "BIAS_CIRCLE_STOPS",
    "BOTH_WAYS_STOPS",
    "KNOB_RINGS",
    "MIN_BIAS_STOPS",
    "RING_RADII",
    "ROLL_CIRCLE",
    "SWEEP_STEP",
    "ShortRingCalibration",
    "ShortRingPlan",
    "bias_circle_path",
    "fit_short_bias",
    "fit_short_plays",
    "fit_short_rings",
    "ring_path",
    "short_ring_plan",
    "short_twist_reading",
    "turn_sense",
]

KNOB_RINGS = "knob rings"
"""Segment name of the ring stops in the plan."""
RING_RADII = tuple(math.radians(a) for a in (25.0, 50.0, 75.0))
"""Knob radii of the rings (rad): those of the full calibration's knob circles, spanning the
spins' 20-60 deg."""
BOTH_WAYS_STOPS = 10
"""Stops per turn and sense of the rings turned both ways: 3 rings x (1 + 2 x 10) = 63 moves,
which with the roll sweeps (36 at :data:`SWEEP_STEP`) and the return to rest keeps the plan
within 100 moves (7 stops and 10 deg sweeps until session 8: the stops identify more than
the sweeps' resolution, docs/calibration.md section 7)."""

SWEEP_STEP = math.radians(20.0)
"""Roll step of the short calibration's sweeps (rad): a play's width is read from the offset
between the up and the down branch, which a coarse step samples too."""

STRAIGHT_SWEEP = (math.radians(30.0), SWEEP_STEP)
"""Amplitude and step (rad) of the short calibration's straight roll sweep."""
BENT_AMPLITUDE = math.radians(50.0)
"""Amplitude (rad) of its bent roll sweep, the AP knob at :data:`BENT_KNOB`."""
BENT_KNOB = math.radians(50.0)
"""The AP knob's angle (rad) of the bent roll sweep (the sweeps' ``roll_bend``)."""

SPIN_RINGS = False
"""The short calibration's rings keep the roll at 0 by default; spin rings (the roll turned
against the knobs, ``spin=True``) are a measured option, not adopted: docs/calibration.md
section 7, session 10."""
RING_SAMPLES = 1
"""Tracker samples averaged at each ring stop by default (10 ms each, no move)."""

ROLL_CIRCLE = "short roll circle"
"""Segment name of the short roll circle's stops (:func:`bias_circle_path`)."""
BIAS_CIRCLE_STOPS = 5
"""Stops of the short roll circle (72 deg apart): its 5 moves and the roll's turn back are
paid by the bent sweep's coarser step (:data:`BIAS_BENT_STEP`: 13 moves instead of 19), the
rings kept as the map prior stores them (100 moves in all)."""
BIAS_BENT_STEP = math.radians(25.0)
"""Roll step (rad) of the bent sweep (+-50 deg) when the short roll circle is in the plan."""
BIAS_CIRCLE_SAMPLES = 4
"""Tracker samples averaged at each stop of the short roll circle (10 ms each, no move)."""
MIN_BIAS_STOPS = 4
"""Tracked stops of the short roll circle below which no bias is fitted."""


def ring_path(
    radii: Sequence[float] = RING_RADII,
    n_stops: int = 12,
    direction: int = 1,
    both_ways: bool = False,
    spin: bool = False,
) -> Array:
    """Ring stops, motor joint states (m, 4) (rad): for each radius r, a move to (r, 0), then
    ``n_stops`` stops one turn around at equal angles, counter-clockwise in (phi1, phi2)
    (``direction`` +1; -1 clockwise); the last stop is (r, 0) again. With ``both_ways`` the
    same stops follow turned the other way (``1 + 2 n_stops`` rows a ring). Translation 0;
    the roll 0, or with ``spin`` turned against the knobs' angle (phi3 = -angle, continued
    over the turn: the ring is a spin of the image at the ring's bend, the tip standing
    still in the base frame, as the evaluation's spins, Eq. S2)."""
    rr = [float(r) for r in radii]
    if not rr or any(not (0.0 < r <= DEFAULT_GEOMETRY.knob_limit) for r in rr):
        raise ConfigurationError(
            f"ring radii must be in (0, {DEFAULT_GEOMETRY.knob_limit:.4f}] rad, got {radii!r}"
        )
    if not (4 <= int(n_stops) <= 72) or direction not in (-1, 1):
        raise ConfigurationError(
            f"need 4 <= n_stops <= 72 and direction +-1, got {n_stops}, {direction}"
        )
    rows: list[tuple[float, float, float]] = []
    senses = (direction, -direction) if both_ways else (direction,)
    for r in rr:
        rows.append((r, 0.0, 0.0))
        for sense in senses:
            for k in range(1, int(n_stops) + 1):
                a = sense * 2.0 * math.pi * k / int(n_stops)
                # the second sense starts where the first ended (a full turn away)
                turned = a if sense == senses[0] else senses[0] * 2.0 * math.pi + a
                rows.append((r * math.cos(a), r * math.sin(a), -turned if spin else 0.0))
    out = np.zeros((len(rows), 4))
    out[:, :3] = rows
    return out


@dataclass(frozen=True, eq=False)
class ShortRingPlan:
    """The short calibration's moves after the 5-point search."""

    plan: MotionPlan
    """The roll sweeps' plan, then the rings (segment :data:`KNOB_RINGS`), back to rest."""
    sweeps: HysteresisPlan
    """The roll sweeps (the first part of ``plan``)."""
    rings: Array
    """(m, 4) the ring stops (:func:`ring_path`)."""
    n_stops: int
    """Stops per turn and sense."""
    both_ways: bool
    """Each ring turned both ways."""
    spin: bool = False
    """The rings turn the roll against the knobs (:func:`ring_path`'s ``spin``)."""
    n_average: int = 1
    """Tracker samples averaged at each ring stop."""
    bias_circle: bool = False
    """The roll circle of :func:`bias_circle_path` follows the sweeps (the field bias, B1)."""


def short_ring_plan(
    radii: Sequence[float] = RING_RADII,
    n_stops: int | None = None,
    direction: int = 1,
    both_ways: bool = True,
    roll_step: float | None = None,
    play_directions: Sequence[float] = (),
    direction_step: float | None = None,
    spin: bool = SPIN_RINGS,
    n_average: int = RING_SAMPLES,
    straight: tuple[float, float] = STRAIGHT_SWEEP,
    bias_circle: bool = False,
) -> ShortRingPlan:
    """Roll sweeps straight (+-30 deg) and with the AP knob at 50 deg (+-50 deg) in
    ``roll_step``, then :func:`ring_path`: 100 moves with the defaults (both ways,
    :data:`BOTH_WAYS_STOPS` stops; one way: 12 stops, 76 moves), the 5-point search's 11
    before them. ``play_directions`` (rad in (0, pi), ascending) add one bent roll sweep
    each, the knobs at 50 deg along that direction, in ``direction_step`` (default
    ``roll_step``): the plays over the knob plane
    (:func:`~icenav.calibration.hysteresis.hysteresis_plan`); fewer stops keep the budget.
    ``roll_step`` defaults to :data:`SWEEP_STEP`. With ``bias_circle`` the short roll circle
    (:func:`bias_circle_path` and the roll's turn back, 6 moves) follows the sweeps and the
    bent sweep goes in :data:`BIAS_BENT_STEP` (100 moves with the defaults)."""
    stops = (BOTH_WAYS_STOPS if both_ways else 12) if n_stops is None else int(n_stops)
    if roll_step is None:
        roll_step = BIAS_BENT_STEP if bias_circle else SWEEP_STEP
    amplitude, step = (float(x) for x in straight)
    sweeps = hysteresis_plan(
        joints=(2,),
        roll_amplitude=amplitude,
        roll_step=step,
        bent_step=roll_step,
        roll_widening=(BENT_AMPLITUDE - amplitude) / BENT_KNOB,
        more_roll_bends=(),
        play_directions=tuple(float(p) for p in play_directions),
        direction_step=roll_step if direction_step is None else float(direction_step),
    )
    path = ring_path(radii, stops, direction, both_ways, spin=spin)
    rings = MotionPlan.make(path, KNOB_RINGS, int(n_average), retries=0)
    rest = MotionPlan.make(np.zeros((1, 4)), "to zero", n_average=0, retries=0)
    parts = [sweeps.plan]
    if bias_circle:
        circle = bias_circle_path()
        back = np.zeros((1, 4))  # the roll turned back down as the knobs straighten
        parts += [
            MotionPlan.make(circle, ROLL_CIRCLE, BIAS_CIRCLE_SAMPLES, retries=0),
            MotionPlan.make(back, "roll back", n_average=0, retries=0),
        ]
    return ShortRingPlan(
        plan=MotionPlan.concat([*parts, rings, rest]),
        sweeps=sweeps,
        rings=path,
        n_stops=stops,
        both_ways=bool(both_ways),
        spin=bool(spin),
        n_average=int(n_average),
        bias_circle=bool(bias_circle),
    )


def bias_circle_path(knob: float = BENT_KNOB, n_stops: int = BIAS_CIRCLE_STOPS) -> Array:
    """(n_stops, 4) motor states of the short roll circle's stops (B1): the AP knob at
    ``knob`` (rad), the roll at ``n_stops`` equal steps from one step up to a full turn, each
    stop approached increasing. Driven from rest at roll 0 after the bent sweep's last
    (falling) move, the first stop is one step (72 deg with the default) of rising roll away,
    more than the roll's whole play (twice its half-width, up to about 20 deg at 50 deg of
    knob on the development catheters): the play's lag is then the same knob-frame offset at
    every stop, absorbed in TB1's ``P``. The plan then turns the roll back down to 0 as the
    knobs straighten, so the rings start from the roll's state after the sweeps (lagging
    the straight play behind a falling roll), as without the circle."""
    if not (0.0 < knob <= DEFAULT_GEOMETRY.knob_limit) or not (3 <= int(n_stops) <= 36):
        raise ConfigurationError(
            f"need 0 < knob <= {DEFAULT_GEOMETRY.knob_limit:.4f} rad and 3 <= n_stops <= 36, "
            f"got {knob!r}, {n_stops!r}"
        )
    out = np.zeros((int(n_stops), 4))
    out[:, 0] = knob
    out[:, 2] = 2.0 * math.pi * np.arange(1, int(n_stops) + 1) / int(n_stops)
    return out


def turn_sense(knobs: ArrayLike) -> Array:
    """(S1)'s ``s_k`` (n,) of a path of knob pairs (n, 2) (rad): the sine of the angle
    between the position about the knob origin and the path's direction (central
    differences; one-sided at the ends), +1 counter-clockwise, -1 clockwise, 0 radial or
    still (a step under 1e-9 rad, or a position within 1e-6 rad of the origin)."""
    m = np.asarray(knobs, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 2:
        raise ConfigurationError(f"knobs must have shape (n, 2), got {m.shape}")
    if m.shape[0] < 2:
        return np.zeros(m.shape[0])
    d = np.gradient(m, axis=0)
    cross = m[:, 0] * d[:, 1] - m[:, 1] * d[:, 0]
    norm = np.linalg.norm(m, axis=1) * np.linalg.norm(d, axis=1)
    ok = (np.linalg.norm(m, axis=1) > 1e-6) & (np.linalg.norm(d, axis=1) > 1e-9)
    out = np.zeros(m.shape[0])
    out[ok] = np.clip(cross[ok] / norm[ok], -1.0, 1.0)
    return out


@dataclass(frozen=True, eq=False)
class ShortRingCalibration:
    """What :func:`fit_short_rings` fits."""

    elasticity_map: ElasticityMap
    """F over the five points and the ring stops (``F+``: those turned counter-clockwise,
    when the rings turned both ways)."""
    hysteresis: HysteresisCompensator
    """The roll's and the twist's play (lines against the bend); no knob models."""
    n_moves: int
    """Moves of the plan (the 5-point search's not counted)."""
    reverse_map: ElasticityMap | None = None
    """``F-``: over the five points and the stops turned clockwise (None: one way only)."""
    section: SectionLength = field(default_factory=SectionLength)
    """The section's length, fitted on every tracked pose of the calibration (the five
    points, the sweeps, the ring stops): F is built on tips with its axial excess removed,
    and :meth:`model_to_motor_path` sends it to the translation."""
    prior: PlayPrior | None = None
    """The play prior the roll's and the twist's plays were scaled from (None: lines)."""
    map_prior: MapPrior | None = None
    """The map prior F's interpolant was built around (None: the samples alone)."""
    tracker_bias: TrackerBias = field(default_factory=TrackerBias.none)
    """The tracker's field bias read on the short roll circle and removed from every tracked
    pose before the fit (the zero bias without the circle): F then aims the true tip."""

    def model_to_motor_path(self, q_model: ArrayLike) -> Array:
        """Motor joint states (n, 4) of a path of model joint states (n, 4) in the order
        driven: (S1) with both maps, ``F+`` alone without ``reverse_map``; phi3 unchanged,
        d4 less the section's axial excess at the model bend (the path is not range-checked:
        clip the knobs after)."""
        q = np.asarray(q_model, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 4:
            raise ConfigurationError(f"q_model must have shape (n, 4), got {q.shape}")
        out = np.asarray(self.elasticity_map.model_to_motor(q, check=False), np.float64)
        sense = turn_sense(q[:, :2])
        if self.reverse_map is not None:
            rev = np.asarray(self.reverse_map.model_to_motor(q, check=False), np.float64)
            w = 0.5 * (1.0 + sense)[:, None]  # (S1)
            out = w * out + (1.0 - w) * rev

        bend = DEFAULT_GEOMETRY.knob_ratio * np.hypot(q[:, 0], q[:, 1])
        out[:, 3] = q[:, 3] - self.section.axial_excess(bend)  # (SL1)
        return out


def fit_short_rings(
    splan: ShortRingPlan,
    recording: Recording,
    five_point: CalibrationSet,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    *,
    fit_length: bool = True,
    prior: PlayPrior | None = None,
    map_prior: MapPrior | None = None,
    map_scaled: bool = False,
) -> ShortRingCalibration:
    """F on the five points (``five_point``, the paper's search) and the tracked ring stops,
    and the roll's plays from the sweeps, of a recording of ``splan``; with ``fit_length``
    the section's length (:func:`~icenav.compensation.section_length.fit_section_length`
    over every tracked pose), its axial excess removed from F's samples. With ``prior`` (an
    explicit option: the catheter model's play shapes from full calibrations of other
    catheters, :mod:`icenav.calibration.play_prior`) the roll's and the twist's plays are
    the prior's shapes scaled to the bent sweep's readings (P1) instead of lines. With
    ``map_prior`` (an explicit option, :mod:`icenav.calibration.map_prior`) each F is the
    product line's mean tip plus the interpolated difference of the samples from it (M1;
    ``map_scaled``: the line's deviation from the model scaled to the samples first, M2)."""
    if recording.plan is not splan.plan and recording.plan.segments != splan.plan.segments:
        raise ConfigurationError("the recording is not of this short calibration's plan")
    bias = TrackerBias.none()
    if splan.bias_circle:
        # the field bias from the short roll circle (TB1), removed from every tracked pose
        bias = fit_short_bias(splan, recording)
        recording = _unbiased(recording, bias)
        five_point = bias.correct_calibration(five_point)
    roll = fit_short_plays(splan, recording, prior, geometry)
    section = _fit_section(recording, five_point, geometry) if fit_length else SectionLength()
    q, poses = recording.part(KNOB_RINGS)
    if splan.spin:
        # F's samples in the knob frame of the roll reached, not the roll commanded (S3)
        q = np.array(q)
        q[:, 2] = roll.effective_path(q, q_start=np.zeros(4))[:, 2]
    tracked = np.all(np.isfinite(poses.reshape(len(q), -1)), axis=1)
    if np.any(tracked):
        poses = np.array(poses)
        poses[tracked] = section.correct_poses(poses[tracked])
    five_point = section.correct(five_point)
    keep_five = np.ones(five_point.n_samples, dtype=bool)
    if splan.spin:
        # the five points were read at roll 0: beyond the rings' smallest radius their field
        # bias is not the one a spin meets there (S3); F keeps those inside it (the origin)
        radius = np.hypot(five_point.q_motor[:, 0], five_point.q_motor[:, 1])
        keep_five = radius < float(np.min(np.hypot(splan.rings[:, 0], splan.rings[:, 1])))
    # the sense each stop was reached in: the first pass of a ring, then (both ways) the
    # second; the move onto the ring (a radial one) joins neither
    per_ring = 1 + (2 if splan.both_ways else 1) * splan.n_stops
    k = np.arange(len(q)) % per_ring
    first = (k >= 1) & (k <= splan.n_stops)
    second = k > splan.n_stops
    ccw_first = turn_sense(splan.rings[:, :2])[1] > 0.0

    def f_over(stops: Any, sense: int = 1) -> ElasticityMap:
        keep = stops & tracked
        samples = CalibrationSet(
            q_motor=np.vstack([five_point.q_motor[keep_five], q[keep]]),
            tip2base=np.concatenate([five_point.tip2base[keep_five], poses[keep]]),
            catheter_id=five_point.catheter_id,
            vessel=five_point.vessel,
            method="five-point+rings",
        )
        if map_prior is not None:
            return map_prior.build_map(samples, sense=sense, scaled=map_scaled, geometry=geometry)
        return ElasticityMap.build(samples, geometry)

    if not splan.both_ways:
        fwd, rev = f_over(first | (k == 0), sense=1 if ccw_first else -1), None
    else:
        fwd = f_over(first if ccw_first else second)
        rev = f_over(second if ccw_first else first, sense=-1)
    return ShortRingCalibration(
        elasticity_map=fwd,
        hysteresis=roll,
        n_moves=splan.plan.n,
        reverse_map=rev,
        section=section,
        prior=prior,
        map_prior=map_prior,
        tracker_bias=bias,
    )


def fit_short_bias(splan: ShortRingPlan, recording: Recording) -> TrackerBias:
    """The tracker's field bias (TB1 of :mod:`icenav.calibration.tracker_bias`, one knob
    pose) from the short roll circle's tracked stops (:data:`ROLL_CIRCLE`) of a recording
    of ``splan``; the zero bias when ``splan`` has no circle, or fewer than
    :data:`MIN_BIAS_STOPS` of its stops were tracked (F then learns the bias as before)."""
    if not splan.bias_circle:
        return TrackerBias.none()
    q, poses = recording.part(ROLL_CIRCLE)
    ok = np.all(np.isfinite(poses.reshape(len(q), -1)), axis=1)
    if int(np.sum(ok)) < MIN_BIAS_STOPS:
        return TrackerBias.none()
    return fit_tracker_bias(q[ok], poses[ok], np.zeros(int(np.sum(ok)), dtype=np.int64))


def _unbiased(recording: Recording, bias: TrackerBias) -> Recording:
    """``recording`` with ``bias`` removed from its tracked poses."""
    t = np.array(recording.tip2base)
    ok = recording.measured
    t[ok] = bias.correct_poses(t[ok])
    return Recording(plan=recording.plan, tip2base=t, attempts=recording.attempts)


def fit_short_plays(
    splan: ShortRingPlan,
    recording: Recording,
    prior: PlayPrior | None = None,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> HysteresisCompensator:
    """The roll's and the twist's plays of the short calibration's sweeps (the first
    ``splan.sweeps.plan.n`` visits of ``recording``; the rings may follow or not): lines
    through the bent sweep's reading (:func:`~icenav.calibration.hysteresis.fit_hysteresis`;
    laws over the knob plane when the plan sweeps further directions), or with ``prior``
    the prior's shapes scaled to that reading (P1; the twist by T1 where the prior stores
    the circle's twist, :mod:`icenav.calibration.play_prior`)."""
    n = splan.sweeps.plan.n
    if recording.plan.n < n or recording.plan.segments[: len(splan.sweeps.plan.segments)] != (
        splan.sweeps.plan.segments
    ):
        raise ConfigurationError("the recording does not start with the short plan's sweeps")
    sweeps = Recording(
        plan=splan.sweeps.plan, tip2base=recording.tip2base[:n], attempts=recording.attempts[:n]
    )
    roll = fit_hysteresis(splan.sweeps, sweeps, geometry).compensator
    if prior is not None:
        roll = _with_prior(roll, prior, _bent_check(sweeps, splan.sweeps.bend))
    return roll


def short_twist_reading(splan: ShortRingPlan, recording: Recording) -> float:
    """The twist's play (rad) the short calibration's bent sweep reads at its tracked bend,
    the field bias of its roll circle removed first (as :func:`fit_short_rings` does): the
    ``s`` of (T0) and (T1) of :mod:`icenav.calibration.play_prior`."""
    recording = _unbiased(recording, fit_short_bias(splan, recording))
    comp = fit_short_plays(splan, recording)
    n = splan.sweeps.plan.n
    sweeps = Recording(splan.sweeps.plan, recording.tip2base[:n], recording.attempts[:n])
    return comp.twist_play_per_bend * _bent_check(sweeps, splan.sweeps.bend)


def _bent_check(recording: Recording, knob: float) -> float:
    """The tracked bend (rad) of the sweeps' 5-sample ``bend check`` (the AP knob's angle
    ``knob`` when it was not tracked), as the sweeps' fit reads it."""
    _, check = recording.part("bend check")
    pose = check[0]
    if not np.all(np.isfinite(pose)):
        return max(knob, math.radians(1.0))
    return max(math.acos(max(-1.0, min(1.0, float(pose[2, 2])))), math.radians(1.0))


def _with_prior(
    comp: HysteresisCompensator, prior: PlayPrior, bend: float
) -> HysteresisCompensator:
    """The sweeps' compensator with the roll's and the twist's plays of (P1): the readings
    at the bent sweep (``*_per_bend`` x the tracked ``bend``) set the prior's levels; a play
    the prior cannot scale keeps its line."""
    roll = prior.law("roll", bend, comp.roll_play_per_bend * bend)
    reading = comp.twist_play_per_bend * bend
    circle = prior.circle_twist(reading)  # (T1) where the prior stores the circle's twist
    twist = circle if circle is not None else prior.law("twist", bend, reading)
    return comp.with_plays(roll, twist)


def _fit_section(
    recording: Recording, five_point: CalibrationSet, geometry: CatheterGeometry
) -> SectionLength:
    """:func:`fit_section_length` over the five points and every tracked pose of the
    recording (its heights and radii do not depend on the roll the sweeps turn)."""
    ok = recording.measured
    everything = CalibrationSet(
        q_motor=np.vstack([five_point.q_motor, recording.plan.q_motor[ok]]),
        tip2base=np.concatenate([five_point.tip2base, recording.tip2base[ok]]),
        catheter_id=five_point.catheter_id,
        vessel=five_point.vessel,
        method="five-point+short",
    )
    return fit_section_length(everything, geometry)

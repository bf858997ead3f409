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
turn the same way*, e.g. the spins of :func:`icenav.geometry.trajectories.spin_trajectory`
with ``direction = -1`` (the paper's), whose knobs turn counter-clockwise. What it assumes:
the procedure turns the knobs the way the rings did, between the rings' radii; a motion the
other way meets the lag twice (measured in docs/calibration.md, section 7). It identifies
no play model and no tracker bias.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from icenav._typing import Array
from icenav.calibration.hysteresis import HysteresisPlan, fit_hysteresis, hysteresis_plan
from icenav.calibration.plans import MotionPlan, Recording
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = [
    "KNOB_RINGS",
    "RING_RADII",
    "ShortRingCalibration",
    "ShortRingPlan",
    "fit_short_rings",
    "ring_path",
    "short_ring_plan",
]

KNOB_RINGS = "knob rings"
"""Segment name of the ring stops in the plan."""
RING_RADII = tuple(math.radians(a) for a in (25.0, 50.0, 75.0))
"""Knob radii of the rings (rad): those of the full calibration's knob circles, spanning the
spins' 20-60 deg."""


def ring_path(radii: Sequence[float] = RING_RADII, n_stops: int = 12, direction: int = 1) -> Array:
    """Ring stops, motor joint states (m, 4) (rad): for each radius r, a move to (r, 0), then
    ``n_stops`` stops one turn around at equal angles, counter-clockwise in (phi1, phi2)
    (``direction`` +1; -1 clockwise); the last stop is (r, 0) again. Roll and translation 0."""
    rr = [float(r) for r in radii]
    if not rr or any(not (0.0 < r <= DEFAULT_GEOMETRY.knob_limit) for r in rr):
        raise ConfigurationError(
            f"ring radii must be in (0, {DEFAULT_GEOMETRY.knob_limit:.4f}] rad, got {radii!r}"
        )
    if not (4 <= int(n_stops) <= 72) or direction not in (-1, 1):
        raise ConfigurationError(
            f"need 4 <= n_stops <= 72 and direction +-1, got {n_stops}, {direction}"
        )
    rows: list[tuple[float, float]] = []
    for r in rr:
        rows.append((r, 0.0))
        for k in range(1, int(n_stops) + 1):
            a = direction * 2.0 * math.pi * k / int(n_stops)
            rows.append((r * math.cos(a), r * math.sin(a)))
    out = np.zeros((len(rows), 4))
    out[:, :2] = rows
    return out


@dataclass(frozen=True, eq=False)
class ShortRingPlan:
    """The short calibration's moves after the 5-point search."""

    plan: MotionPlan
    """The roll sweeps' plan, then the rings (segment :data:`KNOB_RINGS`), back to rest."""
    sweeps: HysteresisPlan
    """The roll sweeps (the first part of ``plan``)."""


def short_ring_plan(
    radii: Sequence[float] = RING_RADII, n_stops: int = 12, direction: int = 1
) -> ShortRingPlan:
    """Roll sweeps straight (+-30 deg) and with the AP knob at 50 deg (+-50 deg), 10 deg
    steps, then :func:`ring_path`: 94 moves with the defaults (the 5-point search's 11
    before them)."""
    sweeps = hysteresis_plan(
        joints=(2,),
        roll_amplitude=math.radians(30.0),
        roll_step=math.radians(10.0),
        roll_widening=0.4,
        more_roll_bends=(),
    )
    rings = MotionPlan.make(ring_path(radii, n_stops, direction), KNOB_RINGS, 1, retries=0)
    rest = MotionPlan.make(np.zeros((1, 4)), "to zero", n_average=0, retries=0)
    return ShortRingPlan(plan=MotionPlan.concat([sweeps.plan, rings, rest]), sweeps=sweeps)


@dataclass(frozen=True, eq=False)
class ShortRingCalibration:
    """What :func:`fit_short_rings` fits."""

    elasticity_map: ElasticityMap
    """F over the five points and the ring stops."""
    hysteresis: HysteresisCompensator
    """The roll's and the twist's play (lines against the bend); no knob models."""
    n_moves: int
    """Moves of the plan (the 5-point search's not counted)."""


def fit_short_rings(
    splan: ShortRingPlan,
    recording: Recording,
    five_point: CalibrationSet,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> ShortRingCalibration:
    """F on the five points (``five_point``, the paper's search) and the tracked ring stops,
    and the roll's plays from the sweeps, of a recording of ``splan``."""
    if recording.plan is not splan.plan and recording.plan.segments != splan.plan.segments:
        raise ConfigurationError("the recording is not of this short calibration's plan")
    n = splan.sweeps.plan.n
    sweeps = Recording(
        plan=splan.sweeps.plan, tip2base=recording.tip2base[:n], attempts=recording.attempts[:n]
    )
    roll = fit_hysteresis(splan.sweeps, sweeps, geometry).compensator
    q, poses = recording.part(KNOB_RINGS)
    tracked = np.all(np.isfinite(poses.reshape(len(q), -1)), axis=1)
    samples = CalibrationSet(
        q_motor=np.vstack([five_point.q_motor, q[tracked]]),
        tip2base=np.concatenate([five_point.tip2base, poses[tracked]]),
        catheter_id=five_point.catheter_id,
        vessel=five_point.vessel,
        method="five-point+rings",
    )
    return ShortRingCalibration(
        elasticity_map=ElasticityMap.build(samples, geometry),
        hysteresis=roll,
        n_moves=splan.plan.n,
    )

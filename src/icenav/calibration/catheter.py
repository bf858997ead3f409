"""The whole calibration our ``dense+hysteresis`` compensation needs, as one motion plan and
one fit (beyond the paper).

:func:`catheter_plan` strings together, from rest at zeros: the paper's dense raster, the
roll sweeps straight, at three bends and along three further bend directions
(:func:`icenav.calibration.hysteresis.hysteresis_plan`, with the spin circle of
:mod:`icenav.calibration.twist_circle`),
the roll circles that separate the tracker's field bias
(:func:`icenav.calibration.tracker_bias.roll_circle_plan`) and the knob circles of the
per-tendon model (:func:`icenav.calibration.transmission.circle_plan`): 1,199 states.
:func:`fit_catheter` turns its :class:`~icenav.calibration.plans.Recording` into
:class:`CatheterCalibration` -- F, the roll's and the twist's plays, the tracker bias and the
per-tendon transmission. :meth:`CatheterCalibration.knob_map` is the controller's compensation
(:class:`icenav.compensation.tendon_map.TendonKnobMap`).

It is the ``dense+hysteresis`` procedure of :func:`icenav.calibration.procedures.make_procedure`:
the console's calibration runner, ``icenav eval spin`` and a bench script all drive that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.calibration.hysteresis import (
    DIRECTION_AMPLITUDE,
    HysteresisIdentification,
    HysteresisPlan,
    fit_hysteresis,
    hysteresis_plan,
)
from icenav.calibration.plans import MotionPlan, Recording, calibration_set_from, raster_grid
from icenav.calibration.spin_path import scorable
from icenav.calibration.tracker_bias import fit_tracker_bias_from, roll_circle_plan
from icenav.calibration.transmission import (
    KNOB_CIRCLES,
    build_transmission,
    circle_plan,
    motion_from,
)
from icenav.calibration.twist_circle import SPIN_CIRCLE
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.section_length import fit_section_length
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.compensation.tracker_bias import TrackerBias
from icenav.compensation.transmission import TransmissionCalibration
from icenav.errors import ConfigurationError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = [
    "CatheterCalibration",
    "CatheterPlan",
    "DENSE_RASTER",
    "KNOB_CIRCLE_STEP",
    "catheter_plan",
    "fit_catheter",
]

DENSE_RASTER = "dense raster"
"""Segment name of the raster in the plan."""


@dataclass(frozen=True, eq=False)
class CatheterPlan:
    """The combined motion and what its fit needs."""

    plan: MotionPlan
    """Every state, in order (segments: dense raster, the sweeps, roll circles, knob
    circles, and unread moves between them)."""
    raster: Array
    """(361, 4) the raster's commanded states (the per-tendon model simulates along them)."""
    hysteresis: HysteresisPlan
    """The sweeps' own plan (a part of ``plan``)."""
    hysteresis_start: int
    """Index in ``plan`` where the sweeps' plan starts."""


KNOB_CIRCLE_STEP = math.radians(6.0)
"""Largest knob change per sample of the knob circles (rad): 6 deg (3 before), the circles
half as long; re-checked on the development catheters (docs/calibration.md, section 7)."""


def catheter_plan(
    *,
    raster_n_average: int = 4,
    raster_step: float = math.radians(10.0),
    circle_step: float = KNOB_CIRCLE_STEP,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CatheterPlan:
    """The raster (``raster_n_average`` tracker samples averaged per knob pair), the roll
    sweeps (straight and at three bends), the roll circles and the knob circles (in
    ``circle_step``), from rest at zeros back to rest. The knobs' own sweeps are not in it:
    the per-tendon model identifies the knobs' plays from the raster and the circles (the
    per-knob model of :func:`icenav.calibration.hysteresis.hysteresis_plan` with joints 0, 1
    is an ablation's)."""
    raster = raster_grid(raster_step, geometry.knob_limit)
    hplan = hysteresis_plan(joints=(2,), spin_circle=True, direction_amplitude=DIRECTION_AMPLITUDE)
    plan = MotionPlan.concat(
        [
            MotionPlan.make(raster, DENSE_RASTER, n_average=raster_n_average, retries=10),
            hplan.plan,
            roll_circle_plan(),
            circle_plan(step=circle_step),
        ]
    )
    return CatheterPlan(plan=plan, raster=raster, hysteresis=hplan, hysteresis_start=len(raster))


@dataclass(frozen=True, eq=False)
class CatheterCalibration:
    """Everything fitted from one :func:`catheter_plan` recording."""

    dense: CalibrationSet
    """The raster's tracked samples (as recorded: the tracker's bias in them)."""
    elasticity_map: ElasticityMap
    """The paper's F from them."""
    hysteresis: HysteresisIdentification
    """The roll's play and the twist's, against the bend (no knob models: the knobs'
    plays are the per-tendon model's)."""
    tracker_bias: TrackerBias
    """The tracker's base-frame field bias, from the roll circles."""
    transmission: TransmissionCalibration
    """The per-tendon model and F on its effective knobs (built bias-free)."""

    def knob_map(
        self,
        q_motor: ArrayLike = (0.0, 0.0, 0.0, 0.0),
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    ) -> TendonKnobMap:
        """The controller's compensation, relaxed at motor state ``q_motor`` (4,)."""
        return TendonKnobMap(self.transmission, q_motor, geometry=geometry)


def fit_catheter(
    cplan: CatheterPlan,
    recording: Recording,
    *,
    catheter_id: str = "",
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> CatheterCalibration:
    """Fit everything from the recording of ``cplan`` (about 10-20 s, mostly the per-tendon
    identification)."""
    if recording.plan is not cplan.plan and recording.plan.segments != cplan.plan.segments:
        raise ConfigurationError("the recording is not of this catheter plan")
    dense = calibration_set_from(recording, DENSE_RASTER, catheter_id=catheter_id).calibration
    # the sweeps' own recording (their plan is a part of the whole)
    start = cplan.hysteresis_start
    stop = start + cplan.hysteresis.plan.n
    sweeps = Recording(
        plan=cplan.hysteresis.plan,
        tip2base=recording.tip2base[start:stop],
        attempts=recording.attempts[start:stop],
    )
    hyst = fit_hysteresis(cplan.hysteresis, sweeps, geometry)
    bias = fit_tracker_bias_from(recording)
    unbiased = bias.correct_calibration(dense)
    section = fit_section_length(unbiased, geometry)
    spin = None
    if SPIN_CIRCLE in {name for _, _, name in cplan.plan.segments}:
        # the spin circle: a second held-out path of the transmission's form (relaxed at the
        # state before it)
        spin = motion_from(
            recording, SPIN_CIRCLE, tracker_bias=bias, geometry=geometry, section=section
        )
        before = cplan.plan.q_motor[max(cplan.plan.segment(SPIN_CIRCLE).start - 1, 0)]
        spin = replace(spin, q_start=before)
        if not scorable(spin.q_motor, spin.observed, spin.q_start):
            spin = None  # too short or too little tracked: the knob circle alone chooses
    transmission = build_transmission(
        unbiased,
        cplan.raster,
        motion_from(recording, KNOB_CIRCLES, tracker_bias=bias, geometry=geometry, section=section),
        hyst.compensator,
        section=section,
        spin=spin,
    )
    return CatheterCalibration(
        dense=dense,
        elasticity_map=ElasticityMap.build(dense, geometry),
        hysteresis=hyst,
        tracker_bias=bias,
        transmission=transmission,
    )

"""Conditions of the twin: which disturbances act and how strongly, and the twin built for
one catheter and one patient.

Three conditions (magnitudes, sources and which seeds set them in ``docs/digital-twin.md``,
section 9):

* ``none``: today's twin, nothing disturbs a return (the default everywhere);
* ``phantom``: the paper's bench study, a beating heart phantom: contact with its walls,
  its pump's flow and regular beat (small stroke-to-stroke variation), the catheter held
  at the phantom's access (the shaft through the access and the phantom's vessel, dragged
  by the beating junction), no breathing;
* ``in-vivo``: the animal study: contact, flow, a beat that varies from beat to beat and
  with breathing, irregular breathing that moves the heart, a long shaft through the
  introducer's seal and the vessel that sticks, slips and is dragged by the breathing
  vessel, slow settling.

Each disturbance is a field of :class:`Condition`; ``condition.without("breathing")`` (or
any of :data:`DISTURBANCES`) switches one off. A patient (anatomy, rhythm, breathing) is
drawn from the patient seed when ``patient_variation`` is on; the shaft's friction draws
use the catheter and the patient seed together.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.errors import ConfigurationError
from icenav.sim.anatomy import EXAMPLE_VIEWS, HeartPhantom
from icenav.sim.contact import ContactModel, ContactParams, FlowParams, Walls
from icenav.sim.disturbed import DisturbedPlant, DisturbedTracker
from icenav.sim.introducer import ShaftFriction, ShaftParams
from icenav.sim.patient import Patient, aim_views
from icenav.sim.physiology import (
    Breathing,
    BreathingParams,
    CardiacRhythm,
    PhysiologicalHeart,
    RhythmParams,
)

__all__ = [
    "CONDITIONS",
    "Condition",
    "DISTURBANCES",
    "Twin",
    "build_twin",
    "condition",
]

DISTURBANCES = ("contact", "flow", "rhythm", "breathing", "shaft", "patient_variation")
"""Names of the switchable disturbances (fields of :class:`Condition`)."""


@dataclass(frozen=True)
class Condition:
    """Which disturbances act and their parameters (None / False: off)."""

    name: str
    """Condition name."""
    contact: ContactParams | None = None
    """Contact of the catheter with the walls (IVC, RA wall, septum, tricuspid annulus)."""
    flow: FlowParams | None = None
    """Drag of the atrial blood flow on the catheter."""
    rhythm: RhythmParams | None = None
    """Beat-to-beat variation of the heart (None: a regular beat)."""
    breathing: BreathingParams | None = None
    """Breathing that moves the heart relative to the base (None: none)."""
    shaft: ShaftParams | None = None
    """Stick-slip and settling of the shaft in the introducer and the vessel (None: the
    robot grips the shaft at the bending section)."""
    patient_variation: bool = False
    """Draw the heart's size, position, orientation, rate and breathing per patient seed."""

    def without(self, *names: str) -> Condition:
        """This condition with the named disturbances (:data:`DISTURBANCES`) switched off."""
        bad = [n for n in names if n not in DISTURBANCES]
        if bad:
            raise ConfigurationError(f"unknown disturbance(s) {bad}; known: {list(DISTURBANCES)}")
        off: dict[str, Any] = {n: (False if n == "patient_variation" else None) for n in names}
        return replace(self, **off)

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the disturbances that act."""
        return tuple(
            f.name for f in fields(self) if f.name in DISTURBANCES and getattr(self, f.name)
        )


NONE = Condition("none")

PHANTOM = Condition(
    "phantom",
    contact=ContactParams(),
    flow=FlowParams(),
    rhythm=RhythmParams(amplitude_sd=0.02),
    breathing=None,
    shaft=ShaftParams(
        axial_stiffness_n_per_mm=0.30,
        torsional_stiffness_nmm_per_rad=35.0,
        static_friction_n=0.3,
        kinetic_friction_n=0.1,
        static_friction_sd=0.5,
        ageing=0.05,
        ageing_time_s=1.0,
        entrainment=0.5,
        settling_time_s=0.15,
    ),
    patient_variation=True,
)

IN_VIVO = Condition(
    "in-vivo",
    contact=ContactParams(),
    flow=FlowParams(),
    rhythm=RhythmParams(
        rr_sd=0.03,
        rr_correlation=0.5,
        rsa=0.03,
        amplitude_sd=0.05,
        stroke_variation=0.10,
        shape_sd_mm=0.5,
    ),
    breathing=BreathingParams(period_sd=0.05, amplitude_sd=0.10, baseline_sd=0.05),
    shaft=ShaftParams(
        axial_stiffness_n_per_mm=0.10,
        torsional_stiffness_nmm_per_rad=15.0,
        static_friction_n=1.0,
        kinetic_friction_n=0.6,
        static_friction_sd=0.2,
        ageing=0.05,
        ageing_time_s=1.0,
        entrainment=0.8,
        settling_time_s=0.3,
    ),
    patient_variation=True,
)

CONDITIONS: dict[str, Condition] = {c.name: c for c in (NONE, PHANTOM, IN_VIVO)}
"""The named conditions."""


def condition(name: str) -> Condition:
    """The condition called ``name`` (``none``, ``phantom``, ``in-vivo``)."""
    if name not in CONDITIONS:
        raise ConfigurationError(f"condition must be one of {sorted(CONDITIONS)}, got {name!r}")
    return CONDITIONS[name]


class _NoBreathing:
    """The respiratory signal of a patient who does not breathe (a phantom): zero."""

    def signal(self, t: Any) -> Array:
        out: Array = np.zeros(np.shape(t))
        return out


@dataclass
class Twin:
    """One catheter in one patient under one condition."""

    condition: Condition
    """The condition."""
    patient: Patient
    """The patient (anatomy and physiology parameters)."""
    plant: DisturbedPlant
    """The catheter (plug-in protocol, plus time-dependent states)."""
    tracker: DisturbedTracker
    """The EM tracker at the tip."""
    phantom: HeartPhantom
    """The moving heart (rendering and walls)."""
    base2anatomy: Array
    """(4, 4) registration of the robot base in the anatomy frame."""
    monitor: Any
    """Respiratory signal (``signal(t)``): what a bellows records."""
    rhythm: CardiacRhythm
    """The heart's beat."""
    breathing: Breathing | None
    """The breathing, None when there is none."""
    views: dict[str, tuple[float, float, float, float]]
    """Model joint states of the views an operator finds in this heart."""

    def shift_patient(self, translation_mm: Any) -> None:
        """The patient (the whole anatomy) moves by ``translation_mm`` (3,) in the robot's
        base frame (mm), as when the patient is repositioned on the table: the walls, the
        images and the flow follow; the catheter's motors stay."""
        v = np.asarray(translation_mm, np.float64).reshape(3)
        if not np.all(np.isfinite(v)):
            raise ConfigurationError(f"translation_mm must be finite (mm), got {v}")
        b2a = np.array(self.base2anatomy, np.float64)
        b2a[:3, 3] -= b2a[:3, :3] @ v  # a base point now sits at anatomy x - R v
        self.base2anatomy = b2a
        if self.plant.contact is not None:
            self.plant.contact.set_registration(b2a)
        self.plant.anatomy_moved()


def build_twin(
    cond: Condition | str,
    catheter_seed: int,
    patient_seed: int,
    clock: Callable[[], float],
    *,
    vessel: str = "moderate",
    plant: Any | None = None,
    tracker: Any | None = None,
) -> Twin:
    """The twin of one catheter in one patient under condition ``cond``.

    Parameters
    ----------
    cond : Condition or name
    catheter_seed, patient_seed : int
        Seeds of the catheter (plant, tracker) and of the patient (anatomy, rhythm,
        breathing); the shaft's friction uses both.
    clock : callable returning s
        Simulation time.
    vessel : str
        Vessel of the default plant.
    plant, tracker : optional
        A plant of the plug-in protocol and its tracker (default: ``CatheterPlant`` and
        ``EMTracker`` of ``catheter_seed``).
    """
    from icenav.sim.plant import CatheterPlant
    from icenav.sim.tracker import EMTracker

    c = condition(cond) if isinstance(cond, str) else cond
    patient = Patient.sample(patient_seed) if c.patient_variation else Patient.nominal()
    breathing = None
    if c.breathing is not None:
        bp = c.breathing
        bp = replace(
            bp,
            period_s=patient.breathing_period_s if c.patient_variation else bp.period_s,
            translation_mm=tuple(  # type: ignore[arg-type]
                float(x) * patient.breathing_scale for x in bp.translation_mm
            ),
            rotation_rad=bp.rotation_rad * patient.breathing_scale,
        )
        breathing = Breathing(bp, patient_seed)
    rp = c.rhythm if c.rhythm is not None else RhythmParams()
    rp = replace(rp, heart_rate_bpm=patient.heart_rate_bpm)
    rhythm = CardiacRhythm(rp, patient_seed, breathing)
    base2anatomy = patient.base2anatomy()
    anatomy = patient.phantom()
    heart = PhysiologicalHeart(anatomy, rhythm, breathing)
    views = dict(EXAMPLE_VIEWS) if not c.patient_variation else aim_views(anatomy, base2anatomy)
    inner = plant if plant is not None else CatheterPlant(seed=catheter_seed, vessel=vessel)
    inner_tracker = (
        tracker if tracker is not None else EMTracker(inner, seed=catheter_seed, clock=clock)
    )
    shaft = None
    if c.shaft is not None:
        wall = _junction_motion(anatomy, rhythm, breathing, base2anatomy[:3, 2])

        shaft = ShaftFriction(c.shaft, (int(catheter_seed), int(patient_seed)), wall)
    contact = None
    if c.contact is not None or c.flow is not None:
        walls = Walls(heart, base2anatomy) if c.contact is not None else None
        contact = ContactModel(
            walls,
            c.contact,
            c.flow,
            phantom=heart,
            base2anatomy=base2anatomy,
            geometry=getattr(inner, "geometry", None) or _default_geometry(),
        )
    dplant = DisturbedPlant(inner, clock, shaft=shaft, contact=contact)
    monitor: Any = breathing if breathing is not None else _NoBreathing()
    return Twin(
        c,
        patient,
        dplant,
        DisturbedTracker(inner_tracker, dplant),
        heart,
        base2anatomy,
        monitor,
        rhythm,
        breathing,
        views,
    )


def _junction_motion(
    anatomy: HeartPhantom, rhythm: CardiacRhythm, breathing: Breathing | None, axis: Array
) -> Callable[[float], float]:
    """Eq. (S5): the displacement (mm) of the IVC-RA junction (the anatomy frame's origin)
    along the base axis, a function of time: the beat's displacement (tabulated over the
    phase once, scaled by the beat's amplitude, P3) and breathing (P5)."""
    still = HeartPhantom(
        anatomy.chambers,
        anatomy.vessels,
        anatomy.valves,
        septum_centre=tuple(float(x) for x in anatomy.septum_centre),  # type: ignore[arg-type]
        septum_normal=tuple(float(x) for x in anatomy.septum_normal),  # type: ignore[arg-type]
        septum_radius_mm=anatomy.septum_radius_mm,
        septum_mm=anatomy.septum_mm,
        motion=replace(anatomy.motion, respiratory_amplitude_mm=(0.0, 0.0, 0.0)),
    )
    period = still.motion.period_s
    phases = np.linspace(0.0, 1.0, 257)
    junction = np.zeros((1, 3))
    table = np.array(
        [float(still.displacement(junction, min(p, 1.0 - 1e-9) * period)[0] @ axis) for p in phases]
    )

    def wall(t: float) -> float:
        u = rhythm.amplitude(t) * float(np.interp(rhythm.phase(t), phases, table))
        if breathing is not None:
            u += float(breathing.displacement(junction, t)[0] @ axis)
        return u

    return wall


def _default_geometry() -> Any:
    from icenav.geometry.kinematics import DEFAULT_GEOMETRY

    return DEFAULT_GEOMETRY

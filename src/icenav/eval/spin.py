"""``icenav eval spin``: the paper's image-spinning experiment (Table I, Fig. 5, Fig. 7).

On the digital twin: each catheter (``--seed N``, or ``--seeds 110-119`` for many, in
``--jobs`` processes) is calibrated in the straight vessel -- the dense 19 x 19 raster, the
simplified 5-point search and (beyond the paper) the hysteresis sweeps, knob circles and roll
circles -- then tested in the chosen vessels (``--vessel straight,moderate,steep``: the
paper's curvature figure, calibrate straight, test curved). For each initial AP bend
(20, 40, 60 deg) and each condition the image plane is spun 360 deg about the tip axis
(phi1 = a cos t, phi2 = a sin t, phi3 = -t, 360 samples, t from 0 to 2 pi inclusive), the tip
is measured by the EM tracker after every step, and the RMSE against the intended pose is
reported (the paper's protocol), together with the RMSE against the twin's true pose.

Conditions:

- ``none``: motor knobs = model knobs.
- ``dense``: F from the dense raster (smoothing spline), commands smoothed with a quadratic
  Savitzky-Golay filter, as the paper.
- ``simplified``: F from the 5-point calibration (thin-plate RBF), smoothed likewise.
- ``dense+hysteresis`` (ours, open loop): the dead-zone and hysteresis of each tendon
  (:mod:`icenav.compensation.transmission`, identified from the raster and knob circles) composed
  with F
  built on its effective knob angles; the roll's and the image's twist play per joint
  (:mod:`icenav.compensation.hysteresis`); the tracker's base-frame field bias separated by roll
  circles
  (:mod:`icenav.compensation.tracker_bias`). Calibrated in the straight vessel like every condition;
  with ``--in-situ`` its plays are re-identified in a curved test vessel before the spin
  (knob circles and roll sweeps, about 1,700 moves, no raster; F kept), as a robot with a tip
  sensor can before a procedure.
- ``dense+knob-hysteresis`` (ours, the simpler model): one backlash / dead-zone per knob
  (:mod:`icenav.compensation.hysteresis`, from single-knob sweeps), F on its effective knob angles,
  the
  same roll/twist play and tracker-bias separation.
- ``dense+hysteresis+em`` (ours, closed loop): the ``dense+knob-hysteresis`` feed-forward
  corrected at every sample by an integral servo on the EM-tracked tip
  (:mod:`icenav.control.servo`).

Errors: position RMSE = RMS distance between the measured tip and the intended tip (the
model tip at the start; the model keeps it fixed); rotation RMSE = RMS angle of the rotation
between the intended orientation ``forward(q_model(t))`` (which includes the intended roll of
the image plane) and the measured one. Missing tracker samples are left out of the EM
errors (their count is reported). The tables and plots are :mod:`icenav.eval.spin_report`,
the command line (options, many catheters, printing) :mod:`icenav.eval.spin_cli`.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.calibration.catheter import CatheterCalibration
from icenav.calibration.hysteresis import (
    fit_hysteresis,
    hysteresis_plan,
    short_hysteresis_plan,
)
from icenav.calibration.plans import raster_grid
from icenav.calibration.play_prior import PlayPrior, load_play_prior
from icenav.calibration.procedure import CalibrationOutcome, run_procedure, run_visits
from icenav.calibration.procedures import make_procedure, plan_visits
from icenav.calibration.short import ShortRingCalibration, fit_short_rings, short_ring_plan
from icenav.calibration.transmission import (
    KNOB_CIRCLES,
    circle_plan,
    motion_from,
    reidentify_in_situ,
)
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.compensation.tracker_bias import TrackerBias
from icenav.control.servo import TipPoseServo
from icenav.devices.sim_robot import SimulatedRobot
from icenav.errors import InvalidValueError
from icenav.eval.spin_report import BENDS_DEG
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, forward
from icenav.geometry.se3 import rotation_angle
from icenav.geometry.trajectories import savgol_smooth, spin_trajectory

__all__ = [
    "ALL_CONDITIONS",
    "CONDITIONS",
    "Calibrations",
    "CatheterRun",
    "FILE",
    "PlantSpec",
    "Rig",
    "SpinRecord",
    "calibrate",
    "evaluate_catheter",
    "family_play_prior",
    "identify_in_situ",
    "knob_map_commands",
    "make_rig",
    "plant_name",
    "run_calibration",
    "run_spin",
    "run_spin_closed_loop",
    "run_vessel",
    "short_ring_commands",
]

OURS = "dense+hysteresis"
"""Our open-loop condition: dense F with the per-tendon dead-zone / hysteresis model."""
KNOB_HYSTERESIS = "dense+knob-hysteresis"
"""Our simpler open-loop condition: dense F with one backlash / dead-zone model per knob."""
CLOSED_LOOP = "dense+hysteresis+em"
"""The closed-loop condition's name."""
CONDITIONS = ("none", "dense", "simplified", OURS, KNOB_HYSTERESIS, CLOSED_LOOP)
"""The conditions, in the order of the table (the paper's three, then ours)."""
SHORT = "short"
"""The paper's 5-point F and the roll's and twist's plays from two short roll sweeps
(:func:`short_hysteresis_plan`; 89 moves; no knob play, no tracker bias; not default)."""
SHORT_RINGS = "short+rings"
"""The 5-point search, coarse roll sweeps and ring stops turned both ways, F over the points
and the stops (:mod:`icenav.calibration.short`; 111 moves; not in the default set)."""
SHORT_PRIOR = "short+rings+prior"
"""The short calibration with the product line's priors of the plays and the map (``eval/data/
play_prior_<family>.json``) on its plan with the short roll circle (``bias_circle``; 111 moves)."""
ALL_CONDITIONS = (*CONDITIONS, SHORT, SHORT_RINGS, SHORT_PRIOR)
"""Every condition ``--conditions`` accepts."""
FILE = "file"
"""The compensation of a calibration file (``--calibration CAL.json``: a file ``icenav
calibrate`` or the console wrote), the map the console installs from it: the stored model of
a version 3 file (the knob map of ``dense+hysteresis``, F of ``dense`` / ``five_point``), the
paper's F built on the samples of an older one."""
SETTLE_UPDATES = 10
"""Closed loop: tracker updates at the start pose before the spin starts (1/8 s at 80 Hz)."""
SAVGOL_WINDOW = 15
"""Savitzky-Golay window (samples = deg of spin) of the ablation ``dense+knob-hysteresis``
(the console's knob maps send each command as it is computed, unfiltered)."""
APPROACH_STEPS = 20
"""Steps of the approach from the relaxed state to the start of the spin."""


@dataclass(frozen=True)
class SpinRecord:
    """One row of the machine-readable output: one bend, one condition."""

    bend_deg: int
    """Initial AP bend (deg)."""
    condition: str
    """``none``, ``dense``, ``simplified``, ``dense+hysteresis``, ``dense+knob-hysteresis`` or
    ``dense+hysteresis+em``
    (closed loop on the EM tracker)."""
    position_rmse_mm: float
    """Tip position RMSE measured by the EM tracker (mm), the paper's protocol."""
    rotation_rmse_deg: float
    """Tip orientation RMSE measured by the EM tracker (deg)."""
    true_position_rmse_mm: float
    """Tip position RMSE of the twin's true pose (mm)."""
    true_rotation_rmse_deg: float
    """Tip orientation RMSE of the twin's true pose (deg)."""
    seed: int
    """Catheter seed."""
    vessel: str
    """Test vessel (calibration is always in the straight vessel)."""
    n_samples: int
    """Samples of the spin."""
    em_missing: int
    """Samples the tracker reported MISSING (left out of the EM errors)."""
    in_situ: bool = False
    """True: this condition's plays were re-identified in the (curved) test vessel before
    the spin (``--in-situ``, ``dense+hysteresis`` only); False: as calibrated straight."""
    plant: str = "default"
    """The plant the catheter is (:func:`plant_name`: ``default``, a family, a plug-in)."""


@dataclass(frozen=True, eq=False)
class Calibrations:
    """Everything calibrated on one catheter in the straight vessel, by the console's
    procedures (:func:`icenav.calibration.procedures.make_procedure`) and their fits."""

    dense: CalibrationOutcome
    """``dense``: the paper's raster and F (the outcome's ``knob_map``)."""
    simplified: CalibrationOutcome
    """``five_point``: the paper's 5-point search and F."""
    ours: CalibrationOutcome
    """``dense+hysteresis``: raster, sweeps, roll and knob circles; ``details`` is the
    :class:`icenav.calibration.catheter.CatheterCalibration`, ``knob_map`` the controller's
    :class:`icenav.compensation.tendon_map.TendonKnobMap`."""
    dense_effective: ElasticityMap
    """The ablation ``dense+knob-hysteresis``: F from the same raster (tracker bias removed)
    in the per-joint model's effective knob angles."""
    knob_hysteresis: HysteresisCompensator
    """The ablation's per-joint compensator: the knobs' plays from their own sweeps (run
    after ours, not a part of it), the roll's and the twist's from ours."""
    seconds: float
    """Wall time of the calibration (s)."""
    short: HysteresisCompensator | None = None
    """The short calibration's roll and twist plays (with ``simplified``'s F), if run."""
    short_rings: ShortRingCalibration | None = None
    """The ``short+rings`` calibration, if run."""
    short_prior: ShortRingCalibration | None = None
    """The ``short+rings+prior`` calibration (the same recording), if run."""

    @property
    def catheter(self) -> CatheterCalibration:
        """The ``dense+hysteresis`` fit."""
        cal: CatheterCalibration = self.ours.details
        return cal

    @property
    def compensator(self) -> HysteresisCompensator:
        """The per-joint (knob, roll, twist) hysteresis compensator of the ablation."""
        return self.knob_hysteresis

    @property
    def tracker_bias(self) -> TrackerBias:
        """The tracker's base-frame field bias from the roll circles."""
        return self.catheter.tracker_bias

    @property
    def dense_set(self) -> CalibrationSet:
        """The dense procedure's tracked samples."""
        cs: CalibrationSet = self.dense.calibration_set
        return cs

    @property
    def five_set(self) -> CalibrationSet:
        """The 5-point procedure's tracked samples."""
        cs: CalibrationSet = self.simplified.calibration_set
        return cs


PlantSpec = str | Callable[..., tuple[Any, Any]] | None
"""Which plant the evaluation runs on: None (the default twin), a family name
(:func:`icenav.sim.families.family`, e.g. ``"rate-dependent"``), a plug-in spec
``MODULE:FACTORY`` (:func:`icenav.sim.plugins.load_factory`) or a factory itself
(picklable, for ``--jobs``)."""


def plant_name(plant: PlantSpec) -> str:
    """The name a plant spec is reported under: ``default``, the family name, the plug-in
    spec, or the factory's ``name`` / qualified name."""
    if plant is None:
        return "default"
    if isinstance(plant, str):
        return plant
    return str(getattr(plant, "name", None) or getattr(plant, "__qualname__", repr(plant)))


class Rig:
    """A catheter on the simulated robot backend, and its tracker: what the evaluation drives.

    The plant (any plant of the plug-in protocol, :mod:`icenav.sim.plugins`) is wrapped in
    :class:`icenav.devices.sim_robot.SimulatedRobot`, so the calibrations and spins command
    it as the product commands a robot (``command_position``, joint limits checked;
    ``home`` relaxes it at zero) and read only the robot's reported tip pose and the
    tracker; nothing reads the plant's parameters.
    """

    def __init__(self, plant: Any, tracker: Any) -> None:
        self.robot = SimulatedRobot(plant)
        self.robot.record_commands = False
        self.robot.enable()
        self.tracker = tracker

    def move(self, q_motor: ArrayLike) -> Array:
        """Command the motor joint state (4,) (rad, rad, rad, mm); the true tip2base (4, 4)
        the catheter settles at (mm)."""
        self.robot.command_position(q_motor)
        return self.robot.tip2base

    def reset(self) -> None:
        """Home the robot: the catheter relaxed at q = 0."""
        self.robot.home()


def make_rig(seed: int, vessel: str, plant: PlantSpec = None) -> tuple[Rig, Any]:
    """Catheter ``seed`` of ``plant`` (:data:`PlantSpec`) in ``vessel`` on the simulated robot,
    and its tracker; the plant and tracker are checked against the plug-in protocol
    (:func:`icenav.sim.plugins.make_plant`; PluginError naming what is missing)."""
    from icenav.sim.plugins import make_plant

    made, tracker = make_plant("default" if plant is None else plant, seed, vessel)
    return Rig(made, tracker), tracker


def run_calibration(kind: str, plant: Any, tracker: Any) -> CalibrationOutcome:
    """The console's calibration ``kind`` on the twin: :func:`make_procedure`, driven by
    :func:`run_procedure` from rest, then its fit (exactly what the controller's calibration
    runner drives and fits)."""
    plant.reset()
    procedure = make_procedure(kind)
    return procedure.fit(run_procedure(procedure, plant.move, tracker))


def family_play_prior(plant: PlantSpec) -> PlayPrior:
    """The play prior of ``plant``'s product line (``eval/data/play_prior_<name>.json``,
    made by ``docs/figures/make_play_priors.py``); raises InvalidValueError when there is
    none (a plug-in plant has none)."""
    name = plant_name(plant)
    res = resources.files("icenav.eval") / "data" / f"play_prior_{name}.json"
    if not res.is_file():
        raise InvalidValueError(
            f"condition {SHORT_PRIOR!r}: no play prior for plant {name!r} "
            "(docs/figures/make_play_priors.py makes the families')"
        )
    with resources.as_file(res) as path:
        return load_play_prior(path)


def calibrate(
    seed: int,
    plant: PlantSpec = None,
    *,
    short: bool = False,
    short_rings: bool = False,
    short_prior: bool = False,
) -> Calibrations:
    """Calibrate catheter ``seed`` of ``plant`` in the straight vessel with the console's
    procedures: ``dense``, ``five_point`` and ``dense+hysteresis``, one after the other on one
    robot and tracker (each from rest); with ``short`` also the short calibration's roll
    sweeps (:func:`short_hysteresis_plan`), with ``short_rings`` the ``short+rings`` one
    (:func:`icenav.calibration.short.short_ring_plan` after the 5-point search's), with
    ``short_prior`` the family's priors on its own plan (with the short roll circle)."""
    t0 = time.perf_counter()
    rig, tracker = make_rig(seed, "straight", plant)
    dense = run_calibration("dense", rig, tracker)
    five = run_calibration("five_point", rig, tracker)
    ours = run_calibration("dense+hysteresis", rig, tracker)
    short_comp = None
    if short:
        rig.reset()
        splan = short_hysteresis_plan()
        rec = run_visits(plan_visits(splan.plan), rig.move, tracker)
        short_comp = fit_hysteresis(splan, rec).compensator
    rings = with_prior = None
    fp = five.calibration_set
    for wanted, circle in ((short_rings, False), (short_prior, True)):
        if wanted:  # each its own recording: short+rings+prior's plan has the roll circle
            rig.reset()
            rplan = short_ring_plan(bias_circle=circle)
            rec = run_visits(plan_visits(rplan.plan), rig.move, tracker)
            if not circle:
                rings = fit_short_rings(rplan, rec, fp)
                continue
            prior = family_play_prior(plant)
            with_prior = fit_short_rings(rplan, rec, fp, prior=prior, map_prior=prior.map)
    cat: CatheterCalibration = ours.details
    # the ablation: the knobs' own sweeps (not in our calibration), the roll's plays of ours
    rig.reset()
    kplan = hysteresis_plan(joints=(0, 1))
    knobs = fit_hysteresis(kplan, run_visits(plan_visits(kplan.plan), rig.move, tracker))
    k, r = knobs.compensator, cat.hysteresis.compensator
    comp = HysteresisCompensator(
        [k.joints[0], k.joints[1], r.joints[2], None],
        roll_play_per_bend=r.roll_play_per_bend,
        knob_play_per_bend=k.knob_play_per_bend,
        twist_play_per_bend=r.twist_play_per_bend,
        roll_play=r.roll_play,
        twist_play=r.twist_play,
    )
    # F on the per-joint model's effective knobs along the raster (from rest)
    raster = raster_grid()
    eff = comp.effective_path(np.vstack([np.zeros(4), raster]))[1:]
    # a play's centre offset can put an effective knob past the limit F is defined on
    # (out-of-tolerance catheters): clip it there, as the raster's own limit samples are
    lim = DEFAULT_GEOMETRY.knob_limit
    eff[:, :2] = np.clip(eff[:, :2], -lim, lim)
    keep = [int(np.argmin(np.max(np.abs(raster - q), axis=1))) for q in cat.dense.q_motor]
    unbiased = cat.tracker_bias.correct_calibration(cat.dense)
    dense_eff = unbiased.with_motor_knobs(eff[keep, :2], method="dense-raster-effective")
    return Calibrations(
        dense=dense,
        simplified=five,
        ours=ours,
        dense_effective=ElasticityMap.build(dense_eff),
        knob_hysteresis=comp,
        seconds=time.perf_counter() - t0,
        short=short_comp,
        short_rings=rings,
        short_prior=with_prior,
    )


def identify_in_situ(
    seed: int, vessel: str, cal: Calibrations, plant: PlantSpec = None
) -> TendonKnobMap:
    """Our compensation with its plays re-identified on catheter ``seed`` in the test
    ``vessel`` (opt-in ``--in-situ``): the hysteresis sweeps and the knob circles there
    (about 1,700 small moves, no raster; a robot with a tip sensor can run them before a
    procedure), fitted with F and G kept from the straight vessel (the section's elasticity
    does not change with the vessel, the shaft's friction does)."""
    rig, tracker = make_rig(seed, vessel, plant)
    rig.reset()
    hplan = hysteresis_plan()
    roll = fit_hysteresis(hplan, run_visits(plan_visits(hplan.plan), rig.move, tracker))
    rig.reset()
    rec = run_visits(plan_visits(circle_plan()), rig.move, tracker)
    circles = motion_from(rec, KNOB_CIRCLES, tracker_bias=cal.tracker_bias)
    transmission = reidentify_in_situ(cal.catheter.transmission, circles, roll.compensator)
    return TendonKnobMap(transmission)


def _rmse(measured: Array, intended: Array) -> tuple[float, float]:
    pos = np.linalg.norm(measured[:, :3, 3] - intended[0, :3, 3], axis=-1)
    rot = rotation_angle(intended[:, :3, :3], measured[:, :3, :3])
    return float(np.sqrt(np.mean(pos**2))), math.degrees(float(np.sqrt(np.mean(rot**2))))


def _approach_path(q_model: Array) -> Array:
    """The approach from rest to the spin's start, then the spin: (APPROACH_STEPS + n, 4)."""
    approach = np.linspace(np.zeros(4), q_model[0], APPROACH_STEPS + 1)[1:]
    return np.vstack([approach, q_model])


def knob_map_commands(knob_map: Any, q_model_path: Array) -> Array:
    """Motor commands (n, 4) of a model path (n, 4) through a knob map, as the controller
    sends them: ``model_to_motor`` of each state from the present state, clipped to the
    knob limits, then ``observe`` of the command sent (a map with state, e.g.
    :class:`~icenav.compensation.tendon_map.TendonKnobMap`, follows every command)."""
    lim = DEFAULT_GEOMETRY.knob_limit
    observe = getattr(knob_map, "observe", None)
    out = np.empty_like(q_model_path)
    for i, q in enumerate(q_model_path):
        cmd = np.asarray(knob_map.model_to_motor(q, check=False), dtype=np.float64).copy()
        cmd[:2] = np.clip(cmd[:2], -lim, lim)
        if observe is not None:
            observe(cmd)
        out[i] = cmd
    return out


def _effective_path(q_model: Array, cal: Calibrations) -> tuple[Array, Array]:
    """The ablation dense + knob hysteresis before the play inverse: the wanted effective
    joint states (APPROACH_STEPS + n, 4) (tracker-bias shift, twist pre-shaped, F,
    Savitzky-Golay) and the intended bend of each (rad), for
    :meth:`HysteresisCompensator.command`."""
    path = cal.tracker_bias.shift_model_path(_approach_path(q_model))
    lim = DEFAULT_GEOMETRY.knob_limit
    model = cal.compensator.preshape_model(path)
    model[:, :2] = np.clip(model[:, :2], -lim, lim)
    eff = cal.dense_effective.model_to_motor(model, check=False)
    eff[APPROACH_STEPS:] = savgol_smooth(eff[APPROACH_STEPS:], SAVGOL_WINDOW)
    eff[:APPROACH_STEPS] = np.linspace(np.zeros(4), eff[APPROACH_STEPS], APPROACH_STEPS + 1)[1:]
    bends = DEFAULT_GEOMETRY.knob_ratio * np.hypot(path[:, 0], path[:, 1])
    return eff, bends


def _short_commands(
    q_model: Array, cal: Calibrations, rings: bool = False, prior: bool = False
) -> Array:
    """The short calibration's commands (APPROACH_STEPS + n, 4): the twist pre-shaped, the
    5-point F (``rings``: with the ring stops, F+ / F- by the sense turned, S1 of
    icenav.calibration.short), the roll's play inverse at the intended bend."""
    if rings:
        sr = cal.short_prior if prior else cal.short_rings
        if sr is None:
            name = SHORT_PRIOR if prior else SHORT_RINGS
            raise InvalidValueError(f"condition {name!r} needs its calibration")
        return short_ring_commands(sr, q_model)  # F+ / F- by the sense turned
    if cal.short is None:
        raise InvalidValueError(f"condition {SHORT!r} needs the short calibration")
    to_motor = functools.partial(cal.simplified.knob_map.model_to_motor, check=False)
    return _compensated_commands(q_model, cal.short, to_motor)


def short_ring_commands(sr: ShortRingCalibration, q_model: Array) -> Array:
    """``short+rings``' commands (APPROACH_STEPS + n, 4) for ``q_model`` (n, 4), for scripts."""
    return _compensated_commands(q_model, sr.hysteresis, sr.model_to_motor_path)


def _compensated_commands(q_model: Array, comp: Any, to_motor: Callable[..., Array]) -> Array:
    """The path pre-shaped by ``comp``, mapped by ``to_motor``, then its play inverse."""
    path = _approach_path(q_model)
    lim = DEFAULT_GEOMETRY.knob_limit
    model = comp.preshape_model(path)
    model[:, :2] = np.clip(model[:, :2], -lim, lim)
    eff = to_motor(model)
    bends = DEFAULT_GEOMETRY.knob_ratio * np.hypot(path[:, 0], path[:, 1])
    comp.reset(np.zeros(4))
    cmd = comp.command_path(eff, bends=bends)
    cmd[:, :2] = np.clip(cmd[:, :2], -lim, lim)
    return cmd


def _fresh_map(cal: Calibrations, condition: str, knob_map: Any = None) -> Any:
    """The knob map of a condition as the controller installs it after the calibration:
    a stateful map relaxed at rest (a new one per spin), F as it is."""
    if condition == "dense":
        return cal.dense.knob_map
    if condition == "simplified":
        return cal.simplified.knob_map
    if knob_map is not None:  # in situ: re-identified plays
        return TendonKnobMap(knob_map.calibration)
    return cal.catheter.knob_map()


def _commands(
    condition: str, q_model: Array, cal: Calibrations | None, knob_map: Any = None
) -> Array:
    """Motor commands (APPROACH_STEPS + n, 4): the approach from rest, then the spin
    (open-loop conditions; the closed loop builds its own, :func:`run_spin_closed_loop`)."""
    path = _approach_path(q_model)
    if condition == "none":
        return path
    if condition == FILE:
        if knob_map is None:
            raise InvalidValueError("condition 'file' needs the calibration file's map")
        reset = getattr(knob_map, "reset", None)
        if callable(reset):  # a map with state (dense+hysteresis): relaxed at rest per spin
            reset(np.zeros(4))
        return knob_map_commands(knob_map, path)
    if cal is None:
        raise InvalidValueError(f"condition {condition!r} needs the calibrations")
    if condition == SHORT:
        return _short_commands(q_model, cal)
    if condition == SHORT_RINGS:
        return _short_commands(q_model, cal, rings=True)
    if condition == SHORT_PRIOR:
        return _short_commands(q_model, cal, rings=True, prior=True)
    if condition == KNOB_HYSTERESIS:
        eff, bends = _effective_path(q_model, cal)
        comp = cal.compensator
        comp.reset(np.zeros(4))
        cmd = comp.command_path(eff, bends=bends)
        lim = DEFAULT_GEOMETRY.knob_limit
        cmd[:, :2] = np.clip(cmd[:, :2], -lim, lim)
        return cmd
    return knob_map_commands(_fresh_map(cal, condition, knob_map), path)


def run_spin(
    plant: Any,
    tracker: Any,
    q_motor: Array,
    n_skip: int = APPROACH_STEPS,
) -> tuple[Array, Array]:
    """Drive ``q_motor`` (m, 4) from a relaxed start; return the true and the EM-tracked
    poses (m - n_skip, 4, 4) of the samples after the approach (NaN where MISSING)."""
    plant.reset()
    true = []
    em = []
    for i, q in enumerate(q_motor):
        pose = plant.move(q)
        if i < n_skip:
            continue
        true.append(pose)
        m = tracker.measure_tip2base()
        em.append(np.full((4, 4), np.nan) if m is None else m)
    return np.array(true), np.array(em)


def run_spin_closed_loop(
    plant: Any,
    tracker: Any,
    q_model: Array,
    cal: Calibrations,
    servo: TipPoseServo | None = None,
    knob_map: Any = None,
) -> tuple[Array, Array, Array]:
    """The spin of ``q_model`` (n, 4) with our compensation (``dense+hysteresis``'s knob map)
    corrected online from the EM tracker by the controller's servo
    (:class:`icenav.control.servo.TipPoseServo`), as the controller's spin task does it:
    the feed-forward is the knob map's commands of the whole spin from the state at its
    start, the servo's correction is added to each motor command, every command sent is
    observed by the map.

    From a relaxed start, the approach runs open loop; at the start pose the servo takes
    ``SETTLE_UPDATES`` tracker updates; then at each sample the tip is measured once and the
    servo updates toward the intended pose of that sample. Returns the true and the
    EM-tracked poses (n, 4, 4) (NaN where MISSING) and the motor commands (n, 4)."""
    servo = TipPoseServo() if servo is None else servo
    servo.reset()
    intended = forward(q_model, check=False)
    kmap = _fresh_map(cal, OURS, knob_map)
    lim = DEFAULT_GEOMETRY.knob_limit
    plant.reset()
    approach = knob_map_commands(kmap, _approach_path(q_model)[:APPROACH_STEPS])
    for q in approach:
        plant.move(q)
    feed_forward = np.asarray(kmap.model_to_motor(q_model, check=False), dtype=np.float64)

    def drive(k: int) -> tuple[Array, Array]:
        q = feed_forward[k] + servo.correction
        q[:2] = np.clip(q[:2], -lim, lim)
        kmap.observe(q)
        return plant.move(q), q

    for _ in range(SETTLE_UPDATES):
        drive(0)
        servo.update(q_model[0], intended[0], tracker.measure_tip2base())
    true, em, cmds = [], [], []
    for k in range(q_model.shape[0]):
        pose, q = drive(k)
        m = tracker.measure_tip2base()
        servo.update(q_model[k], intended[k], m)
        true.append(pose)
        em.append(np.full((4, 4), np.nan) if m is None else m)
        cmds.append(q)
    return np.array(true), np.array(em), np.array(cmds)


def run_vessel(
    seed: int,
    vessel: str,
    cal: Calibrations | None,
    *,
    bends_deg: Sequence[int] = BENDS_DEG,
    n_samples: int = 360,
    conditions: Sequence[str] = CONDITIONS,
    keep_commands: dict[tuple[int, str], Array] | None = None,
    keep_tips: dict[tuple[int, str], Array] | None = None,
    in_situ: bool = False,
    plant: PlantSpec = None,
    file_map: Any = None,
) -> list[SpinRecord]:
    """The spins of one catheter in one vessel: a record per bend and condition.

    Every condition is calibrated in the straight vessel (``cal``; the paper's protocol;
    None only with condition ``none``, which needs no calibration). With ``in_situ`` and a
    vessel other than the straight one, the plays of ``dense+hysteresis`` (tendons, roll,
    twist) are re-identified in the test vessel first (:func:`identify_in_situ`).
    ``keep_commands`` / ``keep_tips`` receive, per (bend, condition), the motor commands
    (n, 4) and the true tip positions (n, 3) (mm, base frame) of the spin."""
    if cal is None and any(c not in ("none", FILE) for c in conditions):
        raise InvalidValueError(f"conditions {list(conditions)} need the calibrations")
    in_situ = in_situ and vessel != "straight" and OURS in conditions
    situ_map = None
    if in_situ:
        assert cal is not None
        situ_map = identify_in_situ(seed, vessel, cal, plant)
    rig, tracker = make_rig(seed, vessel, plant)
    records = []
    for bend in bends_deg:
        sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], n_samples, include_end=True)
        intended = forward(sp.q_model, check=False)
        for cond in conditions:
            if cond == CLOSED_LOOP:
                assert cal is not None  # checked above
                true, em, cmd = run_spin_closed_loop(rig, tracker, sp.q_model, cal)
                if keep_commands is not None:
                    keep_commands[(bend, cond)] = cmd
            else:
                knob = situ_map if cond == OURS else file_map if cond == FILE else None
                cmd = _commands(cond, sp.q_model, cal, knob)
                if keep_commands is not None:
                    keep_commands[(bend, cond)] = cmd[APPROACH_STEPS:]
                true, em = run_spin(rig, tracker, cmd)
            if keep_tips is not None:
                keep_tips[(bend, cond)] = true[:, :3, 3]
            ok = np.all(np.isfinite(em.reshape(len(em), -1)), axis=1)
            tp, tr = _rmse(true, intended)
            ep, er = _rmse(em[ok], intended[ok]) if np.any(ok) else (math.nan, math.nan)
            records.append(
                SpinRecord(
                    bend_deg=int(bend),
                    condition=cond,
                    position_rmse_mm=ep,
                    rotation_rmse_deg=er,
                    true_position_rmse_mm=tp,
                    true_rotation_rmse_deg=tr,
                    seed=seed,
                    vessel=vessel,
                    n_samples=n_samples,
                    em_missing=int(np.sum(~ok)),
                    in_situ=in_situ and cond == OURS,
                    plant=plant_name(plant),
                )
            )
    return records


@dataclass(frozen=True)
class CatheterRun:
    """Everything :func:`evaluate_catheter` made for one catheter."""

    seed: int
    """Catheter seed."""
    plant: str
    """The plant's name (:func:`plant_name`)."""
    records: list[SpinRecord]
    """One record per vessel, bend and condition."""
    calibration_text: list[str]
    """What the calibration identified, as printed lines."""
    commands: dict[tuple[str, int, str], Array]
    """(vessel, bend, condition) -> motor commands of the spin (n, 4), if kept."""
    tips: dict[tuple[str, int, str], Array]
    """(vessel, bend, condition) -> true tip positions of the spin (n, 3) (mm), if kept."""
    seconds: float
    """Wall time (s)."""


def _describe_calibration(seed: int, cal: Calibrations | None) -> list[str]:
    if cal is None:
        return [f"catheter {seed}: nothing to calibrate (condition none only)"]
    lines = [
        f"catheter {seed}: calibrated in the straight vessel in {cal.seconds:.1f} s "
        "(the console's dense, five_point and dense+hysteresis procedures)"
    ]
    for name, outcome in (("dense", cal.dense), ("5-point", cal.simplified), (OURS, cal.ours)):
        lines.append(f"  {name}: {outcome.quality.describe()}")
    tb = cal.tracker_bias
    at = [tb.at(forward(np.array([math.radians(a), 0, 0, 0]))[:3, 3]) for a in BENDS_DEG]
    lines.append(
        "  tracker bias at the 20 / 40 / 60 deg spin points (mm, base x y): "
        + ", ".join(f"{b[0]:.2f} {b[1]:.2f}" for b in at)
        + f"; fit residual {tb.rms_residual_mm:.2f} mm over {tb.n_samples} stops"
    )
    for name, m in (("phi1", 0), ("phi2", 1), ("phi3", 2)):
        jm = cal.compensator.joints[m]
        if jm is not None:
            lines.append(
                f"  {name}: backlash {math.degrees(jm.backlash):.2f} deg + "
                f"{jm.backlash_slope:.3f} |x|, dead-zone {math.degrees(jm.dead_zone):.2f} deg, "
                f"centre {math.degrees(jm.centre):.2f} deg"
            )
    c = cal.compensator
    lines.append(
        f"  per rad of bend: roll play {c.roll_play_per_bend:.3f}, twist play "
        f"{c.twist_play_per_bend:.3f}; knob play per rad of the other knob "
        f"{c.knob_play_per_bend:.3f}"
    )
    if c.roll_play is not None and c.twist_play is not None:
        lines.append(
            f"  against the bend: roll play {c.roll_play.describe()}; twist play "
            f"{c.twist_play.describe()}"
        )
    return lines


def evaluate_catheter(
    seed: int,
    vessels: Sequence[str] = ("straight",),
    *,
    bends_deg: Sequence[int] = BENDS_DEG,
    n_samples: int = 360,
    conditions: Sequence[str] = CONDITIONS,
    in_situ: bool = False,
    keep: bool = False,
    plant: PlantSpec = None,
    calibration_file: str | None = None,
) -> CatheterRun:
    """Calibrate catheter ``seed`` in the straight vessel once, then run the spins in each of
    ``vessels`` (:func:`run_vessel`). With ``keep`` the commands and true tips are kept (for
    the plots). ``plant`` (:data:`PlantSpec`) is the catheter's plant (default: the twin).
    With ``calibration_file`` (a path: loaded in the worker) condition ``file`` runs that
    file's compensation (:meth:`icenav.calibration.files.CalibrationFile.compensation`), as
    the console installs it.
    A module-level function, so ``--jobs`` can run catheters in processes."""
    t0 = time.perf_counter()
    file_map = None
    if calibration_file is not None:
        from icenav.calibration.files import CalibrationFile

        file_map = CalibrationFile.load(calibration_file).compensation(DEFAULT_GEOMETRY)
    if FILE in conditions and file_map is None:
        raise InvalidValueError("condition 'file' needs calibration_file")
    needs_calibration = any(c not in ("none", FILE) for c in conditions)
    cal = (
        calibrate(
            seed,
            plant,
            short=SHORT in conditions,
            short_rings=SHORT_RINGS in conditions,
            short_prior=SHORT_PRIOR in conditions,
        )
        if needs_calibration
        else None
    )
    records: list[SpinRecord] = []
    commands: dict[tuple[str, int, str], Array] = {}
    tips: dict[tuple[str, int, str], Array] = {}
    for vessel in vessels:
        kc: dict[tuple[int, str], Array] = {}
        kt: dict[tuple[int, str], Array] = {}
        records += run_vessel(
            seed,
            vessel,
            cal,
            bends_deg=bends_deg,
            n_samples=n_samples,
            conditions=conditions,
            keep_commands=kc if keep else None,
            keep_tips=kt if keep else None,
            in_situ=in_situ,
            plant=plant,
            file_map=file_map,
        )
        commands.update({(vessel, *k): v for k, v in kc.items()})
        tips.update({(vessel, *k): v for k, v in kt.items()})
    return CatheterRun(
        seed=seed,
        plant=plant_name(plant),
        records=records,
        calibration_text=_describe_calibration(seed, cal),
        commands=commands,
        tips=tips,
        seconds=time.perf_counter() - t0,
    )

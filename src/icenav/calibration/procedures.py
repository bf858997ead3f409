"""The calibrations icenav offers, as :class:`~icenav.calibration.procedure.Procedure` values.

:func:`make_procedure` is the one place that says what each kind visits and how it is fitted;
the console (through the controller's calibration runner), ``icenav calibrate`` and the
evaluations all get their calibration from it.

- ``dense``: the paper's raster (19 x 19 knob pairs at 10 deg over +-90 deg, serpentine),
  F built on the tracked tips (paper Sec. III-C).
- ``five_point``: the paper's simplified calibration (Sec. IV, "Model calibration"): for each
  of five target tips (centre, +-90 deg AP with y = 0, +-90 deg RL with x = 0) the knobs are
  searched until the tracked tip reaches the target in (x, y) (the paper's operator did this
  with the joystick; here a damped Gauss-Newton search with finite differences measured on
  the catheter), then F is built on the five pairs found.
- ``dense+hysteresis``: ours: the raster, hysteresis sweeps, roll circles and knob circles
  (:func:`icenav.calibration.catheter.catheter_plan`), fitted by
  :func:`icenav.calibration.catheter.fit_catheter`.
- ``registration``: the tracker to the robot base: the straight catheter translated and rolled
  (:func:`icenav.devices.registration.registration_joint_states`), the sensor read in the
  tracker frame, fitted by :func:`icenav.devices.registration.register_tracker` (the outcome's
  ``details`` is the :class:`~icenav.devices.registration.Registration`; no knob map).

Every procedure starts from rest at zeros of the knobs and ends there; the runner brings the
catheter back to where the operator left it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_transform
from icenav.calibration.plans import (
    MotionPlan,
    Recording,
    calibration_set_from,
    five_point_targets,
    raster_grid,
)
from icenav.calibration.procedure import CalibrationOutcome, FitQuality, Visit, VisitGenerator
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.devices.registration import register_tracker, registration_joint_states
from icenav.errors import ConfigurationError, TrackerError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.geometry.se3 import rotation_angle

__all__ = [
    "CALIBRATION_KINDS",
    "FivePointProcedure",
    "PlanProcedure",
    "RegistrationProcedure",
    "fit_quality",
    "make_procedure",
    "plan_visits",
]

CALIBRATION_KINDS = ("dense", "five_point", "dense+hysteresis", "registration")
"""The kinds :func:`make_procedure` knows."""


def plan_visits(plan: MotionPlan) -> VisitGenerator:
    """A fixed :class:`MotionPlan` as a visit generator; returns its :class:`Recording`."""
    poses = np.full((plan.n, 4, 4), np.nan)
    attempts = np.zeros(plan.n, dtype=np.int64)
    for i in range(plan.n):
        n = int(plan.n_average[i])
        pose = yield Visit(plan.q_motor[i], n, int(plan.retries[i]), plan.phase_at(i))
        if n > 0:
            attempts[i] = 1
            if pose is not None:
                poses[i] = pose
    return Recording(plan=plan, tip2base=poses, attempts=attempts)


def fit_quality(
    knob_map: Any, cal: CalibrationSet, geometry: CatheterGeometry, n_missing: int = 0
) -> FitQuality:
    """Residual of a compensation on its own samples: the model tip of each motor state mapped
    back through the map (``motor_to_model``) against the tracked tip (mm, deg). Samples whose
    model knobs land on the model's limit are left out and counted (the real catheter bends
    beyond what the model reaches there: no model state explains them)."""
    q_model = np.asarray(knob_map.motor_to_model(cal.q_motor, check=False))
    inside = np.all(np.abs(q_model[:, :2]) < geometry.knob_limit - 1e-6, axis=1)
    if not np.any(inside):
        inside[:] = True
    predicted = forward(q_model[inside], geometry, check=False)
    measured = cal.tip2base[inside]
    d = np.linalg.norm(predicted[:, :3, 3] - measured[:, :3, 3], axis=1)
    ang = np.degrees(rotation_angle(predicted[:, :3, :3], measured[:, :3, :3], check=False))
    n_out = int((~inside).sum())
    return FitQuality(
        n_used=int(inside.sum()),
        n_missing=int(n_missing),
        rms_mm=float(np.sqrt(np.mean(d**2))),
        max_mm=float(d.max()),
        rms_deg=float(np.sqrt(np.mean(ang**2))),
        n_left_out=n_out,
        left_out=(
            f"the model's knobs at their +-{math.degrees(geometry.knob_limit):.0f} deg limit: "
            "the catheter bends further than the model reaches"
            if n_out
            else ""
        ),
        max_deg=float(ang.max()),
    )


@dataclass(frozen=True, eq=False)
class PlanProcedure:
    """A procedure whose visits are a fixed plan (``dense``, ``dense+hysteresis``)."""

    kind: str
    label: str
    plan: MotionPlan
    geometry: CatheterGeometry = DEFAULT_GEOMETRY
    catheter_plan: Any = None
    """For ``dense+hysteresis``: the :class:`icenav.calibration.catheter.CatheterPlan`."""

    def visits(self) -> VisitGenerator:
        return plan_visits(self.plan)

    def fit(self, recording: Any) -> CalibrationOutcome:
        rec: Recording = recording
        missing = int(np.sum((rec.plan.n_average > 0) & ~rec.measured))
        if self.kind == "dense+hysteresis":
            from icenav.calibration.catheter import fit_catheter

            cal = fit_catheter(self.catheter_plan, rec, geometry=self.geometry)
            knob_map = cal.knob_map(np.zeros(4), self.geometry)
            quality = fit_quality(cal.elasticity_map, cal.dense, self.geometry, missing)
            return CalibrationOutcome(self.kind, knob_map, cal.dense, quality, details=cal)
        dense = calibration_set_from(rec, "dense raster", catheter_id="").calibration
        emap = ElasticityMap.build(dense, self.geometry)
        quality = fit_quality(emap, dense, self.geometry, missing)
        return CalibrationOutcome(self.kind, emap, dense, quality, details=emap.report)


@dataclass(frozen=True, eq=False)
class FivePointProcedure:
    """The paper's simplified calibration: search the knobs until the tracked tip reaches
    each of the five targets in (x, y), then build F on the five pairs found."""

    kind: str = "five_point"
    label: str = "5-point: centre, +-90 deg AP, +-90 deg RL (searched)"
    geometry: CatheterGeometry = DEFAULT_GEOMETRY
    tol_mm: float = 1.0
    """Stop a target's search once the tip is this close to it in (x, y) (mm)."""
    max_iterations: int = 8
    """Gauss-Newton iterations per target."""
    fd_step: float = math.radians(4.0)
    """Finite-difference step of the knobs (rad)."""
    max_step: float = math.radians(20.0)
    """Largest knob step of one iteration (rad)."""
    n_average: int = 1
    retries: int = 10

    def visits(self) -> VisitGenerator:
        lim = self.geometry.knob_limit
        knobs, xy = five_point_targets(self.geometry)
        visited_q: list[Array] = []
        visited_t: list[Array] = []
        phases: list[str] = []
        kept: list[int] = []  # indices (into visited) of the five samples

        def q_of(k: Array) -> Array:
            return np.array([k[0], k[1], 0.0, 0.0])

        def visit(k: Array, phase: str) -> VisitGenerator:
            pose = yield Visit(q_of(k), self.n_average, self.retries, phase)
            visited_q.append(q_of(k))
            visited_t.append(np.full((4, 4), np.nan) if pose is None else np.asarray(pose))
            phases.append(phase)
            return pose

        for i in range(5):
            phase = f"five-point target {i + 1}"
            target = xy[i]
            k = knobs[i].copy()
            best_k: Array | None = None
            best_err = math.inf
            for _ in range(self.max_iterations):
                pose = yield from visit(k, phase)
                if pose is None:
                    break
                e = pose[:2, 3] - target
                err = float(np.linalg.norm(e))
                if err < best_err:
                    best_k, best_err = k.copy(), err
                if err <= self.tol_mm:
                    break
                jac = np.empty((2, 2))
                ok = True
                for j in range(2):
                    h = self.fd_step if k[j] + self.fd_step <= lim else -self.fd_step
                    kh = k.copy()
                    kh[j] += h
                    ph = yield from visit(kh, phase)
                    if ph is None:
                        ok = False
                        break
                    jac[:, j] = (ph[:2, 3] - pose[:2, 3]) / h
                if not ok:
                    break
                step = -np.linalg.solve(jac.T @ jac + 1e-2 * np.eye(2), jac.T @ e)
                norm = float(np.linalg.norm(step))
                if norm > self.max_step:
                    step *= self.max_step / norm
                k_new = np.clip(k + step, -lim, lim)
                if np.allclose(k_new, k, atol=1e-6):
                    break
                k = k_new
            if best_k is not None:
                # the sample: a fresh reading at the best pair (approached like the others)
                pose = yield from visit(best_k, phase)
                if pose is not None:
                    kept.append(len(visited_q) - 1)
        yield from _rest(visited_q, visited_t, phases)
        q = np.array(visited_q)
        t = np.array(visited_t)
        n_avg = np.zeros(len(q), dtype=np.int64)
        n_avg[kept] = self.n_average
        segments = _segments(phases)
        plan = MotionPlan(
            q_motor=q, n_average=n_avg, retries=np.zeros(len(q), np.int64), segments=segments
        )
        keep_t = np.full_like(t, np.nan)
        keep_t[kept] = t[kept]
        return Recording(plan=plan, tip2base=keep_t, attempts=(n_avg > 0).astype(np.int64))

    def fit(self, recording: Any) -> CalibrationOutcome:
        rec: Recording = recording
        ok = rec.measured
        if int(ok.sum()) < 3:
            raise TrackerError(
                f"only {int(ok.sum())} of 5 calibration points could be measured; check the "
                "tracker (sensor in the field volume, cable)"
            )
        cal = CalibrationSet(
            q_motor=rec.plan.q_motor[ok], tip2base=rec.tip2base[ok], method="five-point"
        )
        emap = ElasticityMap.build(cal, self.geometry)
        quality = fit_quality(emap, cal, self.geometry, 5 - int(ok.sum()))
        return CalibrationOutcome(self.kind, emap, cal, quality, details=emap.report)


@dataclass(frozen=True, eq=False)
class RegistrationProcedure:
    """The tracker's registration to the robot base as a calibration procedure: the straight
    catheter at several translations, rolled up and back down
    (:func:`icenav.devices.registration.registration_joint_states`), the sensor pose averaged
    in the tracker frame at each, fitted by
    :func:`icenav.devices.registration.register_tracker` with the given sensor mount."""

    sensor2tip: Array
    """(4, 4) pose of the sensor in the tip frame (mm): the mount, measured or from its
    drawing."""
    kind: str = "registration"
    label: str = "Registration: straight catheter, 3 translations x 12 rolls"
    geometry: CatheterGeometry = DEFAULT_GEOMETRY
    n_average: int = 8
    """Tracker samples averaged at each state."""
    retries: int = 10

    def visits(self) -> VisitGenerator:
        q = registration_joint_states()
        plan = MotionPlan.make(q, "registration", n_average=self.n_average, retries=self.retries)
        poses = np.full((plan.n, 4, 4), np.nan)
        for i in range(plan.n):
            pose = yield Visit(q[i], self.n_average, self.retries, "registration", "tracker")
            if pose is not None:
                poses[i] = pose
        yield Visit(np.zeros(4), 0, 0, "to zero")
        return Recording(plan=plan, tip2base=poses, attempts=np.ones(plan.n, dtype=np.int64))

    def fit(self, recording: Any) -> CalibrationOutcome:
        """The :class:`~icenav.devices.registration.Registration` (in ``details``); the
        recording's poses are the sensor in the tracker frame. Quality: the registration's
        position residual (mm) over the tracked states."""
        rec: Recording = recording
        ok = rec.measured
        if int(ok.sum()) < 3:
            raise TrackerError(
                f"only {int(ok.sum())} of {rec.plan.n} registration states were tracked; check "
                "the tracker (sensor in the field volume, cable)"
            )
        reg = register_tracker(
            rec.plan.q_motor[ok], rec.tip2base[ok], self.sensor2tip, self.geometry
        )
        quality = FitQuality(
            n_used=reg.n_points,
            n_missing=int((~ok).sum()),
            rms_mm=reg.rms_residual_mm,
            max_mm=reg.max_residual_mm,
            rms_deg=math.nan,
        )
        return CalibrationOutcome(self.kind, None, None, quality, details=reg)


def _rest(q: list[Array], t: list[Array], phases: list[str]) -> VisitGenerator:
    """Back to rest at zeros (not read)."""
    yield Visit(np.zeros(4), 0, 0, "to zero")
    q.append(np.zeros(4))
    t.append(np.full((4, 4), np.nan))
    phases.append("to zero")


def _segments(phases: list[str]) -> tuple[tuple[int, int, str], ...]:
    out: list[tuple[int, int, str]] = []
    start = 0
    for i in range(1, len(phases) + 1):
        if i == len(phases) or phases[i] != phases[start]:
            out.append((start, i, phases[start]))
            start = i
    return tuple(out)


def make_procedure(
    kind: str,
    *,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
    sensor2tip: ArrayLike | None = None,
) -> PlanProcedure | FivePointProcedure | RegistrationProcedure:
    """The calibration of ``kind`` (one of :data:`CALIBRATION_KINDS`); ``sensor2tip`` (4, 4)
    (mm, the sensor mount) is what ``registration`` needs."""
    if kind == "dense":
        raster = raster_grid(math.radians(10.0), geometry.knob_limit)
        plan = MotionPlan.concat(
            [
                MotionPlan.make(np.zeros((1, 4)), "to zero", n_average=0, retries=0),
                MotionPlan.make(raster, "dense raster", n_average=4, retries=10),
                MotionPlan.make(np.zeros((1, 4)), "to zero", n_average=0, retries=0),
            ]
        )
        return PlanProcedure("dense", f"Dense grid: {len(raster)} points at 10 deg", plan, geometry)
    if kind == "five_point":
        return FivePointProcedure(geometry=geometry)
    if kind == "dense+hysteresis":
        from icenav.calibration.catheter import catheter_plan

        cplan = catheter_plan(geometry=geometry)
        return PlanProcedure(
            "dense+hysteresis",
            f"Dense grid + hysteresis: {cplan.plan.n} states",
            cplan.plan,
            geometry,
            catheter_plan=cplan,
        )
    if kind == "registration":
        if sensor2tip is None:
            raise ConfigurationError(
                "the registration needs sensor2tip: the (4, 4) pose of the sensor in the tip "
                "frame (mm), measured or from the mount's drawing"
            )
        mount = check_transform(sensor2tip, "sensor2tip")
        if mount.shape != (4, 4):
            raise ConfigurationError(f"sensor2tip must be one (4, 4) transform, got {mount.shape}")
        return RegistrationProcedure(sensor2tip=mount, geometry=geometry)
    raise ConfigurationError(
        f"unknown calibration kind {kind!r}: use one of {', '.join(CALIBRATION_KINDS)}"
    )

"""The force check of a return under study: false alarms on undisturbed returns and the
patient shifts it catches, for the motor-state reference of Eq. (F1) and the tip-pose
reference of Eq. (F2) (:mod:`icenav.recovery.force`).

Protocol, per catheter / patient pair on a disturbed twin (``phantom`` or ``in-vivo``):

1. the scripted operator drives to the three valve views (``eval recovery``'s targets),
   dwells, then explores (``wander_moves``); every commanded state is recorded in the
   roadmap with the force read there (:class:`ForceMap`), and the EM tip pose is read with
   the force every ``em_every`` cycles (:class:`TipForceMap`);
2. ``rounds`` rounds of returns to the three views, the patient where it was, each after
   ``moves_between`` more exploration moves of the operator (recorded): every force the
   check would stop on is a false alarm;
3. for each shift (``shifts_mm`` along each of the six base-frame axes, the views in turn)
   the operator explores as before, the patient moves, the catheter returns to the view,
   the patient moves back.

A return follows its roadmap path without stopping; at each cycle the study notes the force
read and each reference (the EM pose read every ``em_every`` cycles, the last one held in
between). What a return needed not to stop, for a relative margin ``c``, is
``max_k (F_k - (1 + c) F_ref,k)`` (N): the check stops it when that exceeds the absolute
margin. The summary sweeps the absolute margin and prints, per reference, the false-alarm
rate and the fraction of shifted returns caught.

``python -m icenav.eval.force_study --condition in-vivo --seed 100-104 --patient 0-4``
(``--json PATH`` writes the per-return records). Seeds: ``docs/view-recovery.md``.

Session 7: ``--raw DIR`` records every control cycle of the same protocol
(:func:`record_pair`, what the product can read), and ``--score DIR/*.npz`` checks the
recorded returns offline with the product's code (:func:`check_returns`: Eqs. F1, F2, F4,
F5 at :class:`CheckPoint`, the product's operating point); ``--sweep`` ranks the points of
:data:`SWEEP` by the rule of :func:`choose_point`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.control.controller import ControllerConfig, PathTask
from icenav.errors import ConfigurationError
from icenav.eval.recovery import TARGETS, RecoveryConfig
from icenav.eval.recovery_bench import DT, Bench
from icenav.recovery.drift import (
    DEFAULT_DRIFT_MM,
    RESOLUTION_FRACTION,
    REST_WINDOW_S,
    RestReference,
    cannot_tell,
)
from icenav.recovery.force import (
    CHECK_MARGIN_FRACTION,
    CHECK_MARGIN_N,
    DEFAULT_ANGLE_DEG,
    DEFAULT_HOLD_S,
    DEFAULT_RADIUS_MM,
    ForceMap,
    PathForces,
    TipForceMap,
    TipIndex,
    TipTrace,
    shape_reference,
)

__all__ = [
    "CheckPoint",
    "FRACTIONS",
    "ForceStudyConfig",
    "MARGINS_N",
    "RAW_COLUMNS",
    "ReturnCheck",
    "ReturnForces",
    "SWEEP",
    "check_returns",
    "choose_point",
    "dwell_table",
    "main",
    "operating_point",
    "record_pair",
    "run_force_study",
    "score",
    "summarize",
    "tally",
]

MARGINS_N = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
"""Absolute margins (N) the operating point is chosen among."""

FRACTIONS = (0.0, 0.5, 1.0)
"""Relative margins ``c`` at which each return's needed absolute margin is noted."""


@dataclass(frozen=True)
class ForceStudyConfig:
    """One pair of the study (see the module docstring)."""

    condition: str = "in-vivo"
    """Twin condition: ``phantom`` or ``in-vivo``."""
    seed: int = 100
    """Catheter seed."""
    patient: int = 0
    """Patient seed."""
    rounds: int = 4
    """Undisturbed rounds of returns to the three views."""
    shifts_mm: tuple[float, ...] = (5.0, 10.0, 20.0)
    """Patient shifts (mm), each along the six base-frame axes."""
    wander_moves: int = 12
    """Exploration moves of the operator after the views."""
    moves_between: int = 2
    """Exploration moves of the operator before each return (a return starts where the
    operator left the catheter)."""
    dwell_s: float = 0.0
    """The operator's hands off before each return (s): the operator looks at the image, the
    motors are still; a shift happens at the end of it, just before the return."""
    rest_force_n: float | None = None
    """With a value (N): the operator looks at the force readout before letting go, and
    while the mean force over a second exceeds it backs off halfway towards where the
    exploration started (at most 6 times; a cardiologist does not leave an ICE catheter
    pushing a wall). None: session 8's blind operator (``docs/results.md``)."""
    em_every: int = 4
    """Control cycles per EM reading (the twin's contact is solved at 25 Hz)."""
    tip_keys: tuple[tuple[float, float], ...] = ((2.0, 180.0), (4.0, 180.0), (8.0, 180.0),
                                                 (4.0, 30.0))  # fmt: skip
    """(radius mm, angle deg) of each tip-pose reference, Eq. (F2)."""
    lost_motion_box: tuple[float, float] = (0.3, 4.0)
    """Roll (rad) and translation (mm) of the ``box`` reference: the largest force recorded
    at the vertices within the roadmap's epsilon in the steering joints and within these
    of the current state in roll and translation (the shaft's lost motion, without EM)."""


@dataclass(frozen=True)
class ReturnForces:
    """What one return met: the margin (N) each reference needed not to stop it."""

    condition: str
    seed: int
    patient: int
    target: str
    shift_mm: tuple[float, float, float]
    """Patient shift of this return (mm, base frame; zeros: undisturbed)."""
    peak_force_n: float
    """Largest force read along the return (N)."""
    needed_n: dict[str, dict[str, float]] = field(default_factory=dict)
    """Per reference (``motor``, ``tip1``, ``tip2``...) and relative margin (``"0.5"``),
    ``max_k (F_k - (1 + c) F_ref,k)`` (N)."""
    tip_found: dict[str, float] = field(default_factory=dict)
    """Per tip reference, the fraction of cycles with a reading within its radius."""


def _reference_names(cfg: ForceStudyConfig) -> list[str]:
    return ["motor", "box", "shape"] + [f"tip{r:g}a{a:g}" for r, a in cfg.tip_keys]


def _box_reference(b: Bench, motor: ForceMap, q: Array, box: tuple[float, float]) -> float:
    """Largest recorded force within the lost-motion box of ``q`` (N; NaN: none)."""
    verts = b.roadmap.vertices()
    d = np.abs(verts - q)
    eps = b.roadmap.epsilon
    ok = (d[:, 0] <= np.radians(eps)) & (d[:, 1] <= np.radians(eps))
    ok &= (d[:, 2] <= box[0]) & (d[:, 3] <= box[1])
    vals = motor.at(np.flatnonzero(ok))
    return float(np.nanmax(vals)) if np.isfinite(vals).any() else math.nan


def _save_views(b: Bench, cfg: ForceStudyConfig, drive: Callable[[Array], None]) -> dict[str, Any]:
    """The operator drives to each target, dwells 0.5 s and saves it, then wanders
    (``cfg.wander_moves``): the views by target name."""
    views = {}
    for name in TARGETS:
        drive(b.operator.move_to(b.views[name]))
        drive(b.operator.dwell(0.5))
        views[name] = b.roadmap.make_view(name, created_s=b.clock.now())
    drive(b.operator.explore(cfg.wander_moves))
    return views


def _shift_plan(cfg: ForceStudyConfig) -> list[tuple[float, float, float]]:
    """The patient shift (mm, x / y / z) before each return: ``cfg.rounds`` undisturbed
    rounds of the targets, then each shift of ``cfg.shifts_mm`` along +-x, +-y, +-z."""
    plan: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * (cfg.rounds * len(TARGETS))
    for s in cfg.shifts_mm:
        for axis in range(3):
            for sign in (1.0, -1.0):
                v = [0.0, 0.0, 0.0]
                v[axis] = sign * s
                plan.append((v[0], v[1], v[2]))
    return plan


def run_force_study(cfg: ForceStudyConfig) -> list[ReturnForces]:
    """Run the protocol of the module docstring for one pair."""
    b = Bench(
        RecoveryConfig(
            condition=cfg.condition,
            seed=cfg.seed,
            patient=cfg.patient,
            wander_moves=cfg.wander_moves,
            force_check=True,
        )
    )
    if b.twin is None or b.force_sensor is None:
        raise ConfigurationError(f"condition {cfg.condition!r} has no contact (phantom or in-vivo)")
    motor = ForceMap()
    tips = [TipForceMap(r, a) for r, a in cfg.tip_keys]
    tip_trace = TipTrace()

    def drive(trace: Array) -> None:
        for k, q in enumerate(trace):
            b.robot.command_position(q)
            b.record(q)
            tip = b.tracker.measure_tip2base(1) if k % cfg.em_every == 0 else None
            f = b.force_sensor.contact_force_n()  # type: ignore[union-attr]
            motor.record(b.roadmap.current_vertex, f)
            tip_trace.record(b.roadmap.current_vertex, tip)
            for m in tips:
                m.record(tip, f)
            b.clock.advance(DT)

    views = _save_views(b, cfg, drive)

    out: list[ReturnForces] = []
    plan = _shift_plan(cfg)
    for k, shift in enumerate(plan):
        drive(b.operator.explore(cfg.moves_between))
        moved = any(shift)
        if moved:
            b.twin.shift_patient(shift)
        name = TARGETS[k % len(TARGETS)]
        out.append(_follow(b, cfg, views[name], motor, tips, tip_trace, shift))
        if moved:
            b.twin.shift_patient([-x for x in shift])
    return out


def _follow(
    b: Bench,
    cfg: ForceStudyConfig,
    view: Any,
    motor: ForceMap,
    tips: list[TipForceMap],
    trace: TipTrace,
    shift: tuple[float, float, float],
) -> ReturnForces:
    q0 = np.asarray(b.robot.read_state().q, np.float64)
    path = b.roadmap.plan(q0, view, approach=True)
    profile = motor.profile(b.roadmap, path)
    task = PathTask(path, np.array(ControllerConfig().max_velocity))
    forces: list[float] = []
    refs: list[list[float]] = []
    tip_ref: list[float] = [math.nan] * len(tips)
    held = [math.nan, math.nan]
    k = 0
    while True:
        q = task.next_command(np.asarray(b.robot.read_state().q), DT)
        if q is None:
            break
        b.robot.command_position(q)
        b.record(q)
        b.clock.advance(DT)
        if k % cfg.em_every == 0:
            tip = b.tracker.measure_tip2base(1)
            if tip is not None:
                tip_ref = [math.nan if (r := m.reference(tip)) is None else r for m in tips]
                sh = shape_reference(motor, trace, b.roadmap, q, tip)
                held = [_box_reference(b, motor, q, cfg.lost_motion_box),
                        math.nan if sh is None else sh]  # fmt: skip
        k += 1
        f = float(b.force_sensor.contact_force_n() or 0.0)  # type: ignore[union-attr]
        i = task.path_index
        m_ref = math.nan
        if profile is not None:
            m_ref = max(float(profile[i]), float(profile[min(i + 1, len(profile) - 1)]))
        forces.append(f)
        refs.append([m_ref, *held, *tip_ref])
    b.clock.advance(0.2)
    fa = np.asarray(forces)
    ra = np.asarray(refs).reshape(len(fa), 3 + len(tips))
    needed: dict[str, dict[str, float]] = {}
    found: dict[str, float] = {}
    for j, name in enumerate(_reference_names(cfg)):
        ref = ra[:, j].copy()
        if j > 0:  # the larger of Eq. (F1)'s and this one where it has one
            found[name] = float(np.mean(np.isfinite(ref))) if len(ref) else 0.0
            ref = np.fmax(ref, ra[:, 0])
        ok = np.isfinite(ref)
        needed[name] = {
            f"{c:g}": float(np.max(fa[ok] - (1.0 + c) * ref[ok])) if ok.any() else -math.inf
            for c in FRACTIONS
        }
    return ReturnForces(
        cfg.condition,
        cfg.seed,
        cfg.patient,
        view.name,
        shift,
        float(fa.max()) if len(fa) else 0.0,
        needed,
        found,
    )


RAW_COLUMNS = ("t", "q0", "q1", "q2", "q3", "force", "px", "py", "pz", "zx", "zy", "zz",
               "ecg_phase", "resp", "f1_ref", "path_index")  # fmt: skip
"""Columns of the raw rows of :func:`record_pair`: time (s), motor state, force (N), EM tip
position (mm) and axis (NaN between readings), ECG phase, respiration signal, the motor-state
reference of Eq. (F1) (N; NaN on the operator's rows) and the path index (-1: operator)."""


def record_pair(cfg: ForceStudyConfig) -> dict[str, Any]:
    """The protocol of the module docstring for one pair, kept raw: every control cycle of
    the operator and of the returns as rows of :data:`RAW_COLUMNS`, what a check can read
    (never the twin's hidden state). Returns arrays ``rows`` (n, 16), ``returns`` (k, 3) row
    ranges [start, stop) and the operator's row count before each return, ``shifts``
    (k, 3) mm, ``targets`` (k,) indices into ``TARGETS``."""
    b = Bench(RecoveryConfig(condition=cfg.condition, seed=cfg.seed, patient=cfg.patient,
                             wander_moves=cfg.wander_moves, force_check=True))  # fmt: skip
    if b.twin is None or b.force_sensor is None:
        raise ConfigurationError(f"condition {cfg.condition!r} has no contact (phantom or in-vivo)")
    twin, sensor = b.twin, b.force_sensor
    rows: list[list[float]] = []
    nan3 = [math.nan] * 3
    motor = ForceMap()

    def row(k: int, q: Array, f: float, ref: float, index: int) -> None:
        t = b.clock.now()
        tip = b.tracker.measure_tip2base(1) if k % cfg.em_every == 0 else None
        pose = nan3 * 2 if tip is None else [*tip[:3, 3], *tip[:3, 2]]
        resp = float(np.asarray(twin.monitor.signal(t)).reshape(-1)[0])
        rows.append([t, *q, f, *pose, twin.rhythm.phase(t), resp, ref, float(index)])

    def drive(trace: Array) -> None:
        for k, q in enumerate(trace):
            b.robot.command_position(q)
            b.record(q)
            f = float(sensor.contact_force_n() or 0.0)
            motor.record(b.roadmap.current_vertex, f)
            row(k, q, f, math.nan, -1)
            b.clock.advance(DT)

    def back_off(q_free: Array, limit_n: float) -> None:  # the operator reads the force
        for _ in range(6):
            n0 = len(rows)
            drive(b.operator.dwell(1.0))
            if np.mean([r[5] for r in rows[n0:]]) <= limit_n:
                return
            drive(b.operator.move_to(0.5 * (b.operator.state + q_free)))

    views = _save_views(b, cfg, drive)
    plan = _shift_plan(cfg)
    spans: list[tuple[int, int, int]] = []
    for k, shift in enumerate(plan):
        if cfg.rest_force_n is not None:  # the operator goes on from where the robot is
            b.operator.state = np.asarray(b.robot.read_state().q, np.float64).copy()
        q_free = b.operator.state.copy()
        drive(b.operator.explore(cfg.moves_between))
        if cfg.rest_force_n is not None:
            back_off(q_free, cfg.rest_force_n)
        if cfg.dwell_s > 0:
            drive(b.operator.dwell(cfg.dwell_s))
        n_op = len(rows)
        if any(shift):
            twin.shift_patient(shift)
        q0 = np.asarray(b.robot.read_state().q, np.float64)
        path = b.roadmap.plan(q0, views[TARGETS[k % len(TARGETS)]], approach=True)
        forces = PathForces(motor, b.roadmap, path)
        task = PathTask(path, np.array(ControllerConfig().max_velocity))
        j = 0
        while (q := task.next_command(np.asarray(b.robot.read_state().q), DT)) is not None:
            b.robot.command_position(q)
            b.record(q)
            b.clock.advance(DT)
            f = float(sensor.contact_force_n() or 0.0)
            ref = forces.recorded(task.path_index)
            row(j, q, f, math.nan if ref is None else ref, task.path_index)
            j += 1
        spans.append((n_op, len(rows), n_op))
        b.clock.advance(0.2)
        if any(shift):
            twin.shift_patient([-x for x in shift])
    return {
        "rows": np.asarray(rows, np.float64).reshape(-1, len(RAW_COLUMNS)),
        "returns": np.asarray(spans, np.int64).reshape(-1, 3),
        "shifts": np.asarray(plan, np.float64).reshape(-1, 3),
        "targets": np.arange(len(plan)) % len(TARGETS),
    }


@dataclass(frozen=True)
class CheckPoint:
    """An operating point of the product's check (Eqs. F1, F2, F4, F5 of
    :mod:`icenav.recovery.force`); the defaults are the product's."""

    radius_mm: float = DEFAULT_RADIUS_MM
    """Radius of the tip reference, Eq. (F2) (mm; 0: the motor state's reference alone)."""
    margin_fraction: float = CHECK_MARGIN_FRACTION
    margin_n: float = CHECK_MARGIN_N
    hold_s: float = DEFAULT_HOLD_S
    drift_mm: float = DEFAULT_DRIFT_MM
    """Eq. (F5)'s limit (mm; inf: no such check)."""
    phase_match: bool = True
    """Eq. (F5) phase-matched (the product's), else its instantaneous form."""
    resolution_fraction: float = RESOLUTION_FRACTION
    """Eq. (F6): beyond this fraction of the limit the check asks instead of refusing (inf:
    it always refuses, session 8's check)."""


@dataclass(frozen=True)
class ReturnCheck:
    """What the check of a :class:`CheckPoint` saw on one recorded return."""

    shift_mm: float
    """Largest component of the patient's shift (mm; 0: undisturbed)."""
    needed_n: float
    """The absolute margin the force rule (F4) needed not to stop it (N)."""
    drift_mm: float
    """The tip's motion with the motors still at the start, Eq. (F5) phase-matched (mm;
    NaN: unknown)."""
    drift_instant_mm: float = math.nan
    """The same in Eq. (F5)'s instantaneous form: against the reading at the stop (mm)."""
    resolution_mm: float = 0.0
    """Eq. (F6) over the reference (mm; phase-matched, or instantaneous as ``point``)."""
    resolution_instant_mm: float = 0.0
    rest_force_n: float = math.nan
    """Median force (N) over the operator's still cycles before the return."""

    def _drifted(self, point: CheckPoint) -> tuple[bool, bool]:
        """(beyond the limit, the check cannot tell here) of Eqs. (F5, F6)."""
        drift = self.drift_mm if point.phase_match else self.drift_instant_mm
        res = self.resolution_mm if point.phase_match else self.resolution_instant_mm
        return drift > point.drift_mm, cannot_tell(res, point.drift_mm, point.resolution_fraction)

    def stopped(self, point: CheckPoint) -> bool:
        """Whether the check stops this return at ``point`` (refuses, or asks the operator
        to confirm where Eq. F6 cannot tell)."""
        return self.needed_n > point.margin_n or self._drifted(point)[0]

    def asked(self, point: CheckPoint) -> bool:
        """Whether the return holds for the operator's confirmation: stopped by Eq. (F5)
        alone where Eq. (F6) says the check cannot tell (a second press runs it)."""
        beyond, cannot = self._drifted(point)
        return beyond and cannot and self.needed_n <= point.margin_n


def _pose(row: Array) -> Array:
    """(4, 4) a pose with the row's tip position and axis (only those two are read)."""
    t = np.eye(4)
    t[:3, 3], t[:3, 2] = row[6:9], row[9:12]
    return t


def _stop_row(op: Array) -> int:
    """The first row after the operator's last motion in the operator's rows ``op``."""
    moved = np.flatnonzero(np.any(np.diff(op[:, 1:5], axis=0) != 0, axis=1))
    return int(moved[-1]) + 1 if len(moved) else 0


def _reference(t0: float, rows: Array, phases: bool) -> RestReference:
    """Eq. (F5)'s reference of a stop at ``t0`` (s) from the EM rows of the stillness (the
    first one the stop's), with their respiratory signal and cardiac phase or without (the
    instantaneous form)."""
    r0 = rows[0]
    ref = RestReference(t0, r0[6:9], None, *((r0[13], r0[12]) if phases else (None, None)))
    for r in rows[1:]:
        ref.add(float(r[0]), r[6:9], *((float(r[13]), float(r[12])) if phases else (None, None)))
    return ref


def _rest_drift(
    op: Array, ret: Array, dwell_s: float | None, shifted: bool
) -> tuple[float, float, float, float]:
    """Eq. (F5) at a return's start, as the product computes it: the reference is the EM
    readings from the operator's stop (the last motion of ``op``, the operator's rows) over
    :data:`icenav.recovery.drift.REST_WINDOW_S` (at most ``dwell_s``); the tip now is the
    return's first reading, or, for ``dwell_s`` shorter than the recorded dwell, the reading
    that long after the stop (an undisturbed return started then). Returns (phase-matched,
    instantaneous) ``D`` and ``R`` of Eqs. (F5, F6) (mm; NaN: no reading)."""
    stop = _stop_row(op)
    em = np.flatnonzero(np.isfinite(op[:, 6]))
    before = em[em <= stop]
    first = int(before[-1]) if len(before) else (int(em[0]) if len(em) else -1)
    if first < 0:
        return math.nan, math.nan, math.nan, math.nan
    t0 = op[stop, 0]
    recorded = op[-1, 0] - t0
    d = recorded if dwell_s is None else min(float(dwell_s), recorded)
    window = min(d, REST_WINDOW_S)
    keep = em >= first
    keep &= op[em, 0] <= t0 + window + 1e-9 if math.isfinite(t0) else em == first
    rows = op[em[keep]]
    ref, plain = _reference(t0, rows, phases=True), _reference(t0, rows, phases=False)
    now = ret[0] if len(ret) else None
    if dwell_s is not None and dwell_s < recorded and not shifted:
        later = em[op[em, 0] >= t0 + dwell_s - 1e-9]
        now = op[int(later[0])] if len(later) else now
    if now is None or not np.isfinite(now[6]):
        return math.nan, math.nan, math.nan, math.nan
    t_now = float(now[0]) if math.isfinite(now[0]) else None
    return (ref.drift(now[6:9], float(now[13]), float(now[12]), t_now), ref.drift(now[6:9]),
            ref.resolution_mm(), plain.resolution_mm())  # fmt: skip


def check_returns(
    raw: dict[str, Array], point: CheckPoint, dwell_s: float | None = None
) -> list[ReturnCheck]:
    """The product's check (:class:`icenav.recovery.force.TipIndex` for Eq. F2 over the
    operator's readings before each return, Eq. F5 of :mod:`icenav.recovery.drift`) on the
    returns of one pair recorded by :func:`record_pair`; ``dwell_s`` evaluates Eq. (F5) as if
    each return had started that long after the operator stopped (at most the recorded
    dwell; a shifted return is checked at its start, the shift just before it)."""
    rows, spans, shifts = raw["rows"], raw["returns"], raw["shifts"]
    w = int(round(point.hold_s / DT)) + 1  # Eq. (F4): cycles above the limit in a row
    out: list[ReturnCheck] = []
    for (a, b, n_op), shift in zip(spans, shifts, strict=True):
        op, ret = rows[:n_op], rows[a:b]
        em = op[np.isfinite(op[:, 6])]
        index = None
        if point.radius_mm > 0 and len(em):
            samples = np.column_stack([em[:, 6:12], em[:, 5]])
            index = TipIndex(samples, point.radius_mm, DEFAULT_ANGLE_DEG)
        ref = ret[:, 14].copy()
        tip_ref = math.nan
        for k, r in enumerate(ret):
            if index is not None and np.isfinite(r[6]):
                found = index.reference(_pose(r))
                tip_ref = math.nan if found is None else found
            ref[k] = np.fmax(ref[k], tip_ref)
        excess = ret[:, 5] - (1.0 + point.margin_fraction) * ref
        excess = np.where(np.isfinite(excess), excess, -np.inf)
        if len(excess) >= w:
            sustained = np.lib.stride_tricks.sliding_window_view(excess, w).min(axis=1)
        else:
            sustained = np.full(1, -np.inf)
        shifted = bool(np.any(shift))
        drift, instant, res, res_instant = _rest_drift(op, ret, dwell_s, shifted)  # F5, F6
        rest_f = float(np.median(op[_stop_row(op) :, 5]))  # the still rows' force
        out.append(ReturnCheck(float(np.max(np.abs(shift))), float(sustained.max()), drift,
                               instant, res, res_instant, rest_f))  # fmt: skip
    return out


def tally(checks: Sequence[ReturnCheck], point: CheckPoint) -> str:
    """False alarms and shifted returns stopped per shift (mm), as a line."""
    still = [c for c in checks if c.shift_mm == 0]

    def count(cs: list[ReturnCheck]) -> str:
        asked = sum(c.asked(point) for c in cs)
        return f"{sum(c.stopped(point) for c in cs)}/{len(cs)}" + (
            f" ({asked} of them asked)" if asked else ""
        )

    parts = [f"false alarms {count(still)}"]
    for s in sorted({c.shift_mm for c in checks if c.shift_mm > 0}):
        parts.append(f"{s:g} mm stopped {count([c for c in checks if c.shift_mm == s])}")
    return ", ".join(parts)


def summarize(
    records: Sequence[ReturnForces], fraction: float = 1.0, margins_n: Sequence[float] = ()
) -> str:
    """Per reference and absolute margin: false alarms on undisturbed returns and the
    shifted returns caught (per shift magnitude), at the relative margin ``fraction``."""
    if not records:
        return "(no returns)"
    key = f"{fraction:g}"
    names = list(records[0].needed_n)
    margins = list(margins_n) or [0.1, 0.25, 0.5, 0.75, 1.0, 1.5]
    still = [r for r in records if not any(r.shift_mm)]
    mags = sorted({round(max(abs(x) for x in r.shift_mm), 3) for r in records if any(r.shift_mm)})
    lines = [f"relative margin {100 * fraction:.0f} %; undisturbed returns {len(still)}"]
    for name in names:
        need = [r.needed_n[name][key] for r in still]
        top = max(need) if need else math.nan
        lines.append(f"  {name}: largest margin needed without a shift {top:.2f} N")
        for m in margins:
            fa = sum(n > m for n in need)
            parts = [f"false alarms {fa}/{len(need)}"]
            for s in mags:
                sh = [r for r in records if round(max(abs(x) for x in r.shift_mm), 3) == s]
                caught = sum(r.needed_n[name][key] > m for r in sh)
                parts.append(f"{s:g} mm caught {caught}/{len(sh)}")
            lines.append(f"    margin {m:.2f} N: " + ", ".join(parts))
    return "\n".join(lines)


def _shift(r: dict[str, Any]) -> float:
    return round(max(abs(x) for x in r["shift_mm"]), 3)


def score(
    records: Sequence[dict[str, Any]], reference: str, fraction: str, margin_n: float
) -> tuple[tuple[int, int], dict[float, tuple[int, int]]]:
    """At one operating point: (false alarms, undisturbed returns) and, per shift (mm),
    (returns stopped, shifted returns); ``records`` as the JSON of :func:`main` holds them."""
    still = [r for r in records if not any(r["shift_mm"])]
    fa = sum(r["needed_n"][reference][fraction] > margin_n for r in still)
    caught: dict[float, tuple[int, int]] = {}
    for s in sorted({_shift(r) for r in records if any(r["shift_mm"])}):
        moved = [r for r in records if any(r["shift_mm"]) and _shift(r) == s]
        caught[s] = (sum(r["needed_n"][reference][fraction] > margin_n for r in moved), len(moved))
    return (fa, len(still)), caught


def operating_point(
    records: Sequence[dict[str, Any]], max_false_alarms: float = 0.05
) -> tuple[str, str, float]:
    """The rule fixed before the held-out runs were looked at: per reference and relative
    margin, the smallest of :data:`MARGINS_N` with at most ``max_false_alarms`` of the
    undisturbed returns stopped; of those, the one stopping the most 20 mm (then 10, then
    5 mm) shifted returns. Returns (reference, relative margin, absolute margin N)."""
    best: list[tuple[tuple[int, ...], str, str, float]] = []
    for ref in records[0]["needed_n"]:
        for c in records[0]["needed_n"][ref]:
            for m in MARGINS_N:
                (fa, n), caught = score(records, ref, c, m)
                if fa <= max_false_alarms * n:
                    key = tuple(caught[s][0] for s in sorted(caught, reverse=True))
                    best.append((key, ref, c, m))
                    break
    best.sort(key=lambda b: b[0], reverse=True)
    return best[0][1], best[0][2], best[0][3]


SWEEP = {"radius_mm": (0.0, 4.0, 8.0), "margin_fraction": (0.5, 1.0), "hold_s": (0.0, 0.25, 0.5)}
"""The operating points :func:`choose_point` considers, with the absolute margins of
:data:`MARGINS_N` from 0.05 N (a force channel's resolution) and Eq. (F5) at
:data:`icenav.recovery.drift.DEFAULT_DRIFT_MM`."""


def choose_point(
    raws: dict[str, list[dict[str, Array]]], max_false_alarms: float = 0.05
) -> list[tuple[CheckPoint, str]]:
    """The rule fixed before the held-out pairs of session 7 were run: one point for both
    conditions (the product does not know which it is in); per point of :data:`SWEEP`, the
    smallest absolute margin (>= 0.05 N) with at most ``max_false_alarms`` of the
    undisturbed returns stopped in each condition; of those, the most 20 mm (then 10, then
    5 mm) shifted returns stopped, then the fewest false alarms. Returns the points, best
    first, each with its tally per condition."""
    ranked: list[tuple[tuple[int, ...], CheckPoint, str]] = []
    for r in SWEEP["radius_mm"]:
        for c in SWEEP["margin_fraction"]:
            for h in SWEEP["hold_s"]:
                base = CheckPoint(radius_mm=r, margin_fraction=c, hold_s=h)
                checks = {k: [x for raw in v for x in check_returns(raw, base)]
                          for k, v in raws.items()}  # fmt: skip
                for m in (x for x in MARGINS_N if x >= 0.05):
                    pt = CheckPoint(r, c, m, h, DEFAULT_DRIFT_MM)
                    fa = {k: sum(x.stopped(pt) for x in v if x.shift_mm == 0)
                          for k, v in checks.items()}  # fmt: skip
                    n = {k: sum(x.shift_mm == 0 for x in v) for k, v in checks.items()}
                    if all(fa[k] <= max_false_alarms * n[k] for k in checks):
                        caught = tuple(
                            sum(x.stopped(pt) for v in checks.values() for x in v
                                if x.shift_mm == s)
                            for s in (20.0, 10.0, 5.0)
                        )  # fmt: skip
                        text = "; ".join(f"{k}: {tally(v, pt)}" for k, v in checks.items())
                        ranked.append(((*caught, -sum(fa.values())), pt, text))
                        break
    ranked.sort(key=lambda x: x[0], reverse=True)
    return [(pt, text) for _, pt, text in ranked]


def dwell_table(raws: dict[str, list[dict[str, Array]]], dwells_s: Sequence[float]) -> str:
    """Eq. (F5) alone (no force rule), phase-matched and instantaneous, at the product's
    limit, per condition and dwell (s): false alarms and shifted returns stopped."""
    lines = []
    for form, match in (("phase-matched", True), ("instantaneous", False)):
        pt = CheckPoint(margin_n=math.inf, phase_match=match)
        for name, rs in raws.items():
            for d in dwells_s:
                checks = [x for r in rs for x in check_returns(r, pt, d)]
                lines.append(f"  Eq. (F5) {form}, {name}, dwell {d:g} s: {tally(checks, pt)}")
    return "\n".join(lines)


def _load_raws(paths: Sequence[str]) -> dict[str, list[dict[str, Array]]]:
    """Raw records (``CONDITION_SEED_PATIENT.npz``) grouped by condition."""
    out: dict[str, list[dict[str, Array]]] = {}
    for path in paths:
        name = path.rsplit("/", 1)[-1].split("_", 1)[0]
        with np.load(path) as z:
            out.setdefault(name, []).append({k: z[k] for k in z.files})
    return out


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m icenav.eval.force_study`` (see the module docstring)."""
    ap = argparse.ArgumentParser(prog="python -m icenav.eval.force_study", description=__doc__)
    ap.add_argument("--condition", default="in-vivo", choices=("phantom", "in-vivo"))
    ap.add_argument("--seed", default="100", help="catheter seeds, e.g. 100-104")
    ap.add_argument("--patient", default="0", help="patient seeds, paired in order")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--fraction", type=float, default=1.0, help="relative margin of the summary")
    ap.add_argument("--json", default=None, help="write the per-return records here")
    ap.add_argument("--choose", default=None, help="records (JSON) to choose the point on")
    ap.add_argument("--apply", default=None, help="records (JSON) to apply the point to")
    ap.add_argument("--raw", default=None, help="record each pair's cycles into this folder")
    ap.add_argument("--score", nargs="+", default=None, help="raw records to score")
    ap.add_argument("--sweep", action="store_true", help="with --score: choose the point")
    ap.add_argument(
        "--dwell",
        type=float,
        default=0.0,
        help="with --raw: the operator's hands off before each return (s)",
    )
    ap.add_argument(
        "--rest-force",
        type=float,
        default=None,
        help="with --raw: the operator backs off until the force at rest is below this (N)",
    )
    ap.add_argument(
        "--dwell-eval",
        default=None,
        help="with --score: Eq. (F5) as if each return started this long after "
        "the operator stopped, e.g. 0,1,3,6,10 (s; at most the recorded dwell)",
    )
    args = ap.parse_args(argv)
    if args.score:
        raws = _load_raws(args.score)
        if args.sweep:
            for pt, text in choose_point(raws)[:8]:
                print(f"{pt}\n    {text}")
            return 0
        pt = CheckPoint()
        print(f"the product's check: {pt}")
        kept: dict[str, list[dict[str, float]]] = {}
        for name, rs in raws.items():
            checks = [x for r in rs for x in check_returns(r, pt)]
            kept[name] = [asdict(x) for x in checks]
            print(f"  {name}: {tally(checks, pt)}")
        if args.dwell_eval:
            print(dwell_table(raws, [float(x) for x in args.dwell_eval.split(",")]))
        if args.json:  # per return: the shift, the margin F4 needed, the drift of F5
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump({"point": asdict(pt), "returns": kept}, fh, indent=1)
        return 0
    if args.choose:
        with open(args.choose, encoding="utf-8") as fh:
            dev = json.load(fh)
        ref, c, m = operating_point(dev)
        print(f"operating point: reference {ref}, relative margin {c}, absolute {m:.2f} N")
        for name, path in (("chosen on", args.choose), ("applied to", args.apply)):
            if path is None:
                continue
            with open(path, encoding="utf-8") as fh:
                recs = json.load(fh)
            (fa, n), caught = score(recs, ref, c, m)
            shifts = ", ".join(f"{s:g} mm {a}/{b}" for s, (a, b) in caught.items())
            print(f"  {name} {path}: false alarms {fa}/{n}; shifts stopped {shifts}")
        return 0
    seeds, patients = _seeds(args.seed), _seeds(args.patient)
    if len(patients) == 1:
        patients = patients * len(seeds)
    if len(seeds) != len(patients):
        ap.error("--seed and --patient must pair in order (or one patient for all)")
    if args.raw:
        os.makedirs(args.raw, exist_ok=True)
        for s, p in zip(seeds, patients, strict=True):
            t0 = time.perf_counter()
            cfg = ForceStudyConfig(condition=args.condition, seed=s, patient=p,
                                   rounds=args.rounds, dwell_s=args.dwell,
                                   rest_force_n=args.rest_force)  # fmt: skip
            raw = record_pair(cfg)
            np.savez_compressed(f"{args.raw}/{args.condition}_{s}_{p}.npz", **raw)
            print(f"catheter {s} / patient {p}: {time.perf_counter() - t0:.0f} s", flush=True)
        return 0
    records: list[ReturnForces] = []
    for s, p in zip(seeds, patients, strict=True):
        t0 = time.perf_counter()
        cfg = ForceStudyConfig(condition=args.condition, seed=s, patient=p, rounds=args.rounds)
        records.extend(run_force_study(cfg))
        print(f"catheter {s} / patient {p}: {time.perf_counter() - t0:.0f} s", flush=True)
    for frac in FRACTIONS:
        print(summarize(records, frac))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump([asdict(r) for r in records], fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

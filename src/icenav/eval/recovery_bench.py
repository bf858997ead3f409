"""The simulated set-up of ``icenav eval recovery``: catheter, robot, tracker, imagers,
roadmap and operator, on today's twin or on a disturbed twin (a condition and a patient).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.control.config import ControllerConfig
from icenav.control.tasks import goto_view_task
from icenav.devices.sim_robot import SimulatedRobot
from icenav.geometry.se3 import pose_mean
from icenav.recovery.beats import BeatClip
from icenav.recovery.force import ForceRecord, PathForces
from icenav.recovery.roadmap import Roadmap
from icenav.recovery.views import View
from icenav.refinement.cycle_pose import CycleAveragedPose, ExpirationGate, complete_cycles
from icenav.refinement.gating import GatedBeatImager, PhantomRespiration
from icenav.sim.anatomy import EXAMPLE_VIEWS, default_phantom
from icenav.sim.beat_imager import SimClock, SimulatedBeatImager
from icenav.sim.conditions import Twin, build_twin, condition
from icenav.sim.disturbed import TwinForceSensor, mean_pose
from icenav.sim.operator import ScriptedOperator
from icenav.sim.plant import CatheterPlant
from icenav.sim.plugins import make_plant
from icenav.sim.tracker import EMTracker
from icenav.sim.ultrasound import ProbeConfig, UltrasoundRenderer

__all__ = [
    "Bench",
    "DT",
    "EM_EVERY",
    "REST_BACK_OFFS",
    "REST_FORCE_N",
    "REST_LOOK_S",
    "TwinBeatImager",
]

DT = 0.01
"""Control period of the simulated controller (s)."""

REST_FORCE_N = 0.4
"""Default force (N) above which the looking operator does not leave the catheter resting
(``RecoveryConfig.rest_force_n``): 40 g, counted as excessive for a catheter tip on the
wall (TOCCATA, Reddy et al., Heart Rhythm 2012; clinical contact 10-40 g); an ICE
operator keeps the transducer off the wall, and the force readout (the twin's channel, a
sensing catheter's in the product) shows such a push. Chosen on development pairs
(``docs/results.md``, Table II, session 11)."""
REST_LOOK_S = 1.0
"""How long the looking operator watches the force readout after a move (s)."""
REST_BACK_OFFS = 6
"""Most back-off moves of the looking operator after one exploration move."""

EM_EVERY = 4
"""Control cycles per EM reading of the tip pose kept with the operator's forces (Eq. F2):
25 Hz, the rate at which the twin solves its contact while commands stream in (the
controller reads the tracker's newest sample every cycle; readings within 0.5 mm of the last
kept one are dropped by :class:`icenav.recovery.force.TipForceMap` either way)."""


class TwinBeatImager(SimulatedBeatImager):
    """Beats of a disturbed twin: each frame rendered where the catheter is at that frame's
    time (the heart beat, breathing and the shaft move it), the frames of a beat at the
    phases ``k / n`` of the last beat of the heart's own (varying) rhythm.

    Parameters
    ----------
    twin : Twin
    renderer : UltrasoundRenderer
        Renders the twin's heart.
    clock : callable returning s
    frames_per_beat : int
    """

    def __init__(self, twin: Twin, renderer: Any, clock: Any, frames_per_beat: int = 10) -> None:
        super().__init__(twin.plant, renderer, clock, frames_per_beat, twin.base2anatomy)
        self.twin = twin

    def frame_times(self, now: float) -> NDArray[np.float64]:
        """Times (s) of phases ``k / n`` in the last beat before ``now``."""
        rh = self.twin.rhythm
        k = rh.beat_index(now)
        out = np.empty(self.frames_per_beat)
        for i in range(self.frames_per_beat):
            phase = i / self.frames_per_beat
            t = rh.time_at_phase(k, phase)
            out[i] = t if t < now else rh.time_at_phase(k - 1, phase)
        return out

    def clip_at_times(self, times: NDArray[np.float64]) -> BeatClip:
        """Frames at ``times`` (s), each at the catheter's true pose then."""
        frames = tuple(
            self.renderer.render(  # type: ignore[attr-defined]
                self.twin.base2anatomy @ self.twin.plant.pose_at(float(t)), float(t), check=False
            )
            for t in times
        )
        return self._clip(frames, float(np.min(times)))


class Bench:
    """The simulated set-up for one run (see :class:`icenav.eval.recovery.RecoveryConfig`)."""

    def __init__(self, cfg: Any) -> None:
        self.cfg = cfg
        self.clock = SimClock()
        probe = ProbeConfig(
            image_size=cfg.image_size, n_beams=cfg.n_beams, n_samples=cfg.n_samples, seed=cfg.seed
        )
        self.twin: Twin | None = None
        made: tuple[Any, Any] = (None, None)
        if getattr(cfg, "plant", None) is not None:
            made = make_plant(cfg.plant, cfg.seed, cfg.vessel, clock=self.clock.now)
        if cfg.condition == "none":
            self.plant: Any = made[0] or CatheterPlant(seed=cfg.seed, vessel=cfg.vessel)
            self.tracker: Any = made[1] or EMTracker(
                self.plant, seed=cfg.seed, clock=self.clock.now
            )
            self.renderer = UltrasoundRenderer(default_phantom(), probe)
            self.imager: SimulatedBeatImager = SimulatedBeatImager(
                self.plant, self.renderer, self.clock.now, cfg.frames_per_beat
            )
            n_ref = max(2, cfg.frames_per_beat // cfg.refine_subsample)
            self.refine_imager: SimulatedBeatImager = SimulatedBeatImager(
                self.plant, self.renderer, self.clock.now, n_ref
            )
            self.respiration: Any = PhantomRespiration(self.renderer.phantom)
            self.views: dict[str, tuple[float, float, float, float]] = dict(EXAMPLE_VIEWS)
        else:
            cond = condition(cfg.condition).without(*cfg.disable)
            twin = build_twin(cond, cfg.seed, cfg.patient, self.clock.now, vessel=cfg.vessel,
                              plant=made[0], tracker=made[1])  # fmt: skip
            self.twin = twin
            self.plant = twin.plant
            self.tracker = twin.tracker
            self.renderer = UltrasoundRenderer(twin.phantom, probe)
            self.imager = TwinBeatImager(twin, self.renderer, self.clock.now, cfg.frames_per_beat)
            n_ref = max(2, cfg.frames_per_beat // cfg.refine_subsample)
            self.refine_imager = TwinBeatImager(twin, self.renderer, self.clock.now, n_ref)
            self.respiration = twin.monitor
            self.views = twin.views
        self.cycle_window_s = 0.0
        """Window of the cycle-averaged estimates (s; 0: not used)."""
        self.cycle_sensor: CycleAveragedPose | None = None
        """The EM pose cut at complete breaths / beats, Eq. (R1) (None: the plain average)."""
        if self.twin is not None:
            breathing = self.twin.breathing
            self.cycle_window_s = float(
                cfg.cycle_window_s
                if cfg.cycle_window_s is not None
                else (9.0 if breathing is not None else 3.0)
            )
            if cfg.em_estimator == "cycle":
                self.cycle_sensor = CycleAveragedPose(
                    self.twin.tracker,
                    breathing,
                    self.twin.rhythm.phase,
                    window_s=self.cycle_window_s,
                    rate_hz=cfg.cycle_rate_hz,
                )
        self.expiration: ExpirationGate | None = None
        """End-expiration from the twin's respiratory monitor (Eq. R3), None without
        breathing: the pose stage's moves arrive then (``arrive_at_expiration``)."""
        if self.twin is not None and self.twin.breathing is not None:
            self.expiration = ExpirationGate(self.twin.breathing, self.clock.now)
        self.refine_sensor: CycleAveragedPose | None = self.cycle_sensor
        """The pose stage's estimator: Eq. (R1) over ``cfg.refine_window_s`` when set (a
        shorter window, more corrections in the same time), else :attr:`cycle_sensor`."""
        if self.twin is not None and self.cycle_sensor is not None and cfg.refine_window_s:
            self.refine_sensor = CycleAveragedPose(
                self.twin.tracker,
                self.twin.breathing,
                self.twin.rhythm.phase,
                window_s=cfg.refine_window_s,
                rate_hz=cfg.cycle_rate_hz,
            )
        self.force_record = ForceRecord()
        """The operator's contact forces, per roadmap vertex (Eq. F1) and per measured tip
        pose (Eq. F2), as the controller keeps them (:attr:`Controller.forces`)."""
        self.forces = self.force_record.forces
        """Per roadmap vertex, the contact force of the operator's trace (N)."""
        self.force_sensor: TwinForceSensor | None = None
        """The robot's contact-force channel (None on today's twin, or switched off)."""
        if self.twin is not None and cfg.force_check and self.twin.plant.contact is not None:
            self.force_sensor = TwinForceSensor(self.twin.plant)
        product = ControllerConfig()
        self.controller_config = replace(
            product,
            force_margin_n=float(
                cfg.force_margin_n if cfg.force_margin_n is not None else product.force_margin_n
            ),
            force_margin_fraction=float(
                cfg.force_margin_fraction
                if cfg.force_margin_fraction is not None
                else product.force_margin_fraction
            ),
        )
        """The controller's settings the returns run with (speed, the force check's margins,
        hold and drift limit): the product's, the margins overridable."""
        self.force_margin_n = self.controller_config.force_margin_n
        """Absolute margin of the force check (N)."""
        self.force_margin_fraction = self.controller_config.force_margin_fraction
        """Relative margin of the force check."""
        self._cycle = 0
        self.last_force_margin_use = 0.0
        """Largest fraction of the force margin the last return used (> 1: stopped)."""
        self.last_force_margin_needed_n = 0.0
        """The absolute margin (N) the last return needed not to stop, at the relative one."""
        self.last_stop: str | None = None
        """Why the last return stopped (the force check), None if it arrived."""
        self.robot = SimulatedRobot(self.plant, clock=self.clock.now)
        self.robot.enable()
        self.roadmap = Roadmap(epsilon=1.0)
        self.operator = ScriptedOperator(seed=cfg.seed)
        self.roadmap.add(np.zeros(4))
        self._last_q = np.zeros(4)
        self.last_direction = np.zeros(4, dtype=np.int64)
        """Sign of the last motion of each joint (the play's state, as a controller knows
        it from its own commands)."""

    def record(self, q: Array) -> None:
        """Note a commanded state: roadmap (every visited state, Alg. 1) and directions."""
        self.roadmap.add(q, check=False)
        step = np.sign(np.asarray(q, np.float64) - self._last_q).astype(np.int64)
        self.last_direction = np.where(step != 0, step, self.last_direction)
        self._last_q = np.array(q, np.float64)

    @property
    def beat(self) -> float:
        """Mean heart beat (s)."""
        return self.imager.beat_duration_s

    def drive(self, trace: Array) -> Array:
        """Command an operator trace at the control rate; the contact force read at each
        recorded state is the operator's, kept per vertex and (every :data:`EM_EVERY`
        cycles) at the EM-measured tip pose, as the controller records it
        (:class:`icenav.recovery.force.ForceRecord`). Returns the forces read (n,) (N;
        empty without a force channel)."""
        n = len(trace)
        read: list[float] = []
        for k, q in enumerate(trace):
            moved = not np.array_equal(q, self._last_q)
            self.robot.command_position(q)
            self.record(q)
            if self.force_sensor is not None:
                self._cycle += 1
                now = self.clock.now()
                stops = moved and (k == n - 1 or np.array_equal(trace[k + 1], q))
                tip = None
                if self._cycle % EM_EVERY == 0 or k == n - 1 or stops:
                    tip = self.tip_pose_now()
                # as the controller: where the operator left the tip, noted when the motors
                # moved, and the tip read while they stand still (Eq. F5's reference)
                if moved and tip is not None:
                    self.force_record.note_motion(tip, True, q, now)
                elif not moved and tip is not None and self.force_record.wants_still_readings(now):
                    self.force_record.note_still(now, tip, self._signals)
                f = self.force_sensor.contact_force_n()
                read.append(float(f or 0.0))
                self.force_record.record(self.roadmap.current_vertex, f, tip)
            self.clock.advance(DT)
        return np.asarray(read, np.float64)

    def explore(self, n_moves: int, rest_force_n: float | None = None) -> int:
        """The operator's exploration: ``n_moves`` seeded moves (:meth:`ScriptedOperator.
        explore`). With ``rest_force_n`` (N) and a force channel, the looking operator: after
        each move it reads the force at rest (mean over :data:`REST_LOOK_S`) and, while that
        exceeds ``rest_force_n``, moves halfway back towards where the move started (at most
        :data:`REST_BACK_OFFS` times), as the force study's operator does
        (:mod:`icenav.eval.force_study`, ``--rest-force``). Without either: session 8's blind
        operator, the same trace as ``drive(operator.explore(n_moves))``. Returns the number
        of back-off moves."""
        if rest_force_n is None or self.force_sensor is None:
            self.drive(self.operator.explore(n_moves))
            return 0
        backs = 0
        for _ in range(int(n_moves)):
            q_start = self.operator.state.copy()
            self.drive(self.operator.explore(1))
            for _ in range(REST_BACK_OFFS):
                if float(np.mean(self.drive(self.operator.dwell(REST_LOOK_S)))) <= rest_force_n:
                    break
                self.drive(self.operator.move_to(0.5 * (self.operator.state + q_start)))
                backs += 1
        return backs

    def _signals(self, t: float) -> tuple[float | None, float | None]:
        """The respiratory signal and the cardiac phase at ``t`` (s), as the controller's
        ``signals`` (Eq. F5's phase match)."""
        if self.twin is None:
            return None, None
        resp = float(np.asarray(self.respiration.signal(np.array([t])), np.float64)[0])
        return resp, float(self.twin.rhythm.phase(t))

    def tip_pose_now(self) -> Array | None:
        """(4, 4) the EM-measured tip pose now (one sample, mm; None if it dropped out)."""
        tip = self.tracker.measure_tip2base(1)
        return None if tip is None else np.asarray(tip, np.float64)

    def acquire(self) -> BeatClip:
        """One ECG-gated beat (the catheter held still for a beat)."""
        self.clock.advance(self.beat)
        return self.imager.acquire_beat()

    def acquire_gated(self, reference: BeatClip) -> BeatClip:
        """One beat gated on ECG and respiration to ``reference`` (holds the window)."""
        gated = GatedBeatImager(
            self.imager, self.respiration, reference, self.cfg.gate_window_beats
        )
        self.clock.advance(gated.beat_duration_s)
        return gated.acquire_beat()

    def go(self, view: View) -> None:
        """Return to ``view`` along the roadmap (with the approach), as the controller's "go
        to view" does, with its force check when the twin has contact (Eqs. F1, F2, F4, F5 and
        the settings of :class:`icenav.control.config.ControllerConfig`); a return the check stops
        is noted (:attr:`last_stop`) and then finished without the check, as an operator
        who looked would, so the experiment goes on."""
        check = self.cfg.force_check and self.force_sensor is not None
        self.last_stop = None
        self.last_force_margin_needed_n = 0.0
        self.last_force_margin_use = self._follow(view, check=check)
        if self.last_stop is not None:
            self._follow(view, check=False)
        self.clock.advance(0.2)  # settle

    def _follow(self, view: View, *, check: bool) -> float:
        """Plan from here to ``view`` and follow the path: the product's "go to view" task
        (:func:`icenav.control.tasks.goto_view_task`: Eqs. F1, F2, F4, F5 with the
        controller's margins, hold and drift limit) when ``check``, else the same path
        unchecked; the largest fraction of the force margin used (the force read against the
        larger of the path's and the tip's reference; > 1: over the limit at that cycle)."""
        q0 = np.asarray(self.robot.read_state().q, np.float64)
        path = self.roadmap.plan(q0, view, approach=True)
        margin, fraction = self.force_margin_n, self.force_margin_fraction
        sensor = self.force_sensor
        task = goto_view_task(
            path,
            self.controller_config,
            label=f"go to view {view.name!r}",
            force_sensor=sensor if check else None,
            forces=self.force_record,
            roadmap=self.roadmap,
            tip_pose=self.tip_pose_now,
        )
        along = None
        if sensor is not None and self.forces.n_recorded > 0:
            along = PathForces(self.forces, self.roadmap, path)
        tips = self.force_record.tips
        use = 0.0
        while True:
            if sensor is not None and along is not None:
                f = float(sensor.contact_force_n() or 0.0)
                ref = along.recorded(task.path_index)
                if ref is not None and f > ref and tips.n_samples:
                    at_tip = tips.reference(self.tip_pose_now())  # Eq. (F2)
                    ref = ref if at_tip is None else max(ref, at_tip)
                if ref is not None and margin + fraction * ref > 0:
                    use = max(use, (f - ref) / (margin + fraction * ref))
                    self.last_force_margin_needed_n = max(
                        self.last_force_margin_needed_n, f - ref * (1.0 + fraction)
                    )
            q = task.next_command(np.asarray(self.robot.read_state().q), DT)
            if q is None:
                break
            self.robot.command_position(q)
            self.record(q)  # every visited state is recorded (Alg. 1)
            self.clock.advance(DT)
        # the motors moved, not by the operator: the rest tip is forgotten (Eq. F5)
        self.force_record.note_motion(None, operator=False)
        if task.failure is not None:
            self.last_stop = task.failure
        return use

    def true_pose(self) -> Array:
        """(4, 4) the twin's true tip pose now (mm)."""
        return np.array(self.plant.state.tip2base, np.float64)

    def dct_pose(self) -> Array:
        """(4, 4) the true tip pose averaged over the last ``dct_window_s`` (a dynamic CT's
        5-s rotation images the catheter where it was on average; mm). The catheter must
        have been still over the window; on today's twin it is the pose now."""
        if self.twin is None:
            return self.true_pose()
        now = self.clock.now()
        times = np.linspace(now - self.cfg.dct_window_s, now, self.cfg.dct_samples)
        return mean_pose(np.stack([self.twin.plant.pose_at(float(t)) for t in times]))

    def hold_still(self, seconds: float) -> None:
        """Advance time until the catheter has been still for ``seconds`` (s)."""
        if self.twin is None:
            return
        still = self.clock.now() - self.twin.plant.last_move_s
        if still < seconds:
            self.clock.advance(seconds - still)

    def static_pose(self) -> Array:
        """(4, 4) the twin's true tip pose averaged over the complete breaths (else beats)
        of the last cycle window (mm), Eq. (R1) on the truth sampled at the estimator's
        rate: the catheter's pose with the periodic motion averaged out. The catheter must
        have been still over the window (:meth:`hold_still`); on today's twin the pose now."""
        if self.twin is None:
            return self.true_pose()
        now = self.clock.now()
        rate = float(self.cfg.cycle_rate_hz)
        n = max(2, int(round(self.cycle_window_s * rate)))
        times = now - (n - 1 - np.arange(n)) / rate
        poses = np.stack([self.twin.plant.pose_at(float(t)) for t in times])
        br = self.twin.breathing
        resp = None if br is None else np.asarray(br.signal(times), np.float64)
        phase = np.array([self.twin.rhythm.phase(float(t)) for t in times])
        sel, _ = complete_cycles(times, resp, phase)
        return pose_mean(poses[sel])

    def contact_peak(self) -> float:
        """Largest total contact force since the last call (N); 0 on today's twin."""
        if self.twin is None:
            return 0.0
        peak = self.twin.plant.peak_contact_force_n
        self.twin.plant.reset_peak()
        return peak

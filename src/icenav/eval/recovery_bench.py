"""The simulated set-up of ``icenav eval recovery``: catheter, robot, tracker, imagers,
roadmap and operator, on today's twin or on a disturbed twin (a condition and a patient).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from icenav._typing import Array
from icenav.control.controller import ControllerConfig, PathTask
from icenav.devices.sim_robot import SimulatedRobot
from icenav.recovery.beats import BeatClip
from icenav.recovery.roadmap import Roadmap
from icenav.recovery.views import View
from icenav.refinement.gating import GatedBeatImager, PhantomRespiration
from icenav.sim.anatomy import EXAMPLE_VIEWS, default_phantom
from icenav.sim.beat_imager import SimClock, SimulatedBeatImager
from icenav.sim.conditions import Twin, build_twin, condition
from icenav.sim.disturbed import mean_pose
from icenav.sim.operator import ScriptedOperator
from icenav.sim.plant import CatheterPlant
from icenav.sim.tracker import EMTracker
from icenav.sim.ultrasound import ProbeConfig, UltrasoundRenderer

__all__ = ["Bench", "DT", "TwinBeatImager"]

DT = 0.01
"""Control period of the simulated controller (s)."""


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
                self.base2anatomy @ self.twin.plant.pose_at(float(t)), float(t), check=False
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
        if cfg.condition == "none":
            self.plant: Any = CatheterPlant(seed=cfg.seed, vessel=cfg.vessel)
            self.tracker: Any = EMTracker(self.plant, seed=cfg.seed, clock=self.clock.now)
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
            twin = build_twin(cond, cfg.seed, cfg.patient, self.clock.now, vessel=cfg.vessel)
            self.twin = twin
            self.plant = twin.plant
            self.tracker = twin.tracker
            self.renderer = UltrasoundRenderer(twin.phantom, probe)
            self.imager = TwinBeatImager(twin, self.renderer, self.clock.now, cfg.frames_per_beat)
            n_ref = max(2, cfg.frames_per_beat // cfg.refine_subsample)
            self.refine_imager = TwinBeatImager(twin, self.renderer, self.clock.now, n_ref)
            self.respiration = twin.monitor
            self.views = twin.views
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

    def drive(self, trace: Array) -> None:
        """Command an operator trace at the control rate."""
        for q in trace:
            self.robot.command_position(q)
            self.record(q)
            self.clock.advance(DT)

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
        """Return to ``view`` along the roadmap (with the approach), as the controller does."""
        q0 = np.asarray(self.robot.read_state().q, np.float64)
        path = self.roadmap.plan(q0, view, approach=True)
        task = PathTask(path, np.array(ControllerConfig().max_velocity))
        while True:
            q = task.next_command(np.asarray(self.robot.read_state().q), DT)
            if q is None:
                break
            self.robot.command_position(q)
            self.record(q)  # every visited state is recorded (Alg. 1)
            self.clock.advance(DT)
        self.clock.advance(0.2)  # settle

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

    def contact_peak(self) -> float:
        """Largest total contact force since the last call (N); 0 on today's twin."""
        if self.twin is None:
            return 0.0
        peak = self.twin.plant.peak_contact_force_n
        self.twin.plant.reset_peak()
        return peak

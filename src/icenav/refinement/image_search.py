"""Closed-loop, image-based view refinement (beyond the paper).

After a roadmap return (open loop), the catheter is where the motors say, not quite where
the view was saved: backlash, friction and the vessel change the true pose a little. The
refinement closes the loop on the ultrasound image: a small local search of the *motor*
state that maximises the similarity of one heart beat of live images to the view's saved
beat, frames matched by cardiac phase.

Search
------
A compass (pattern) search with halving steps over (phi1, phi2, phi3, d4):

1. Measure the similarity ``s*`` at the start state ``q*`` (``beats`` gated beats; as many
   again if they look off). If it is within ``stop_within`` of the *ceiling* (the saved beats
   scored against each other), stop: the view is recovered as far as the images can tell,
   and every trial move would shift the transmission's play for nothing.
2. Poll the trial states ``q* +- step_j e_j`` (the last successful direction first). A
   trial is accepted when it beats ``s*`` by at least ``min_improvement`` (the similarity
   is noisy: respiration and the heart beat change between beats). Both thresholds are at
   least ``noise_factor`` times the score's beat-to-beat noise, measured on the saved beats
   (the standard deviation of each against the others).
3. When no trial is accepted the steps halve and ``q*`` is measured again (its score is the
   running mean of its measurements, so a lucky beat does not hold the search).
4. Stop when every step is below ``min_step``, after ``max_evaluations`` beats, after
   ``max_duration_s`` of controller time, or when ``abort()`` returns True; end at ``q*``
   (``verify_end``: only if fresh beats there still beat the start's, else at the start).

Safety
------
* Every commanded state lies in the box ``q_view +- radius`` (default +-3 deg, +-3 deg,
  +-3 deg, +-2 mm): trials are clipped to it and every set-point is checked again before
  it is sent (:class:`NeighbourhoodError` otherwise: a bug, never a silent clip).
* Moves are straight joint lines at bounded speed (``max_velocity``), one set-point per
  control cycle; the search moves at most ``initial_step`` from the incumbent at a time.
* Each trial is approached from the view's arrival direction (overshoot by ``overshoot``
  and come back, inside the box), so the transmission's backlash is taken up the same way
  as when the view was saved (the plant is history dependent).
* Bounded time and evaluations; abortable between any two control cycles.

Image similarity: blurred, down-sampled NCC (:func:`icenav.refinement.similarity.beat_score`'s
recipe) over the reference beat, frames matched by cardiac phase (smooth in pose where raw
speckle NCC is not); with several saved beats the best match over them. A trial that looks
better is measured a second time before it is accepted (``confirm``).

The search is off by default (``search``): the stage then measures the start and reports
whether the view looks recovered or lost, without moving. Options for images that
decorrelate from beat to beat (``RefinementConfig``): search only
the joints the image constrains (``joints``), average several gated beats per measurement
(``beats``), accept a trial only when its gain passes a z-test against the score's noise per
beat (``significance``), and re-measure the end state with fresh beats, going back to the
start unless it still beats it (``verify_end``). What they reach: ``docs/view-recovery.md``.

Two ways to run it: :class:`RefinementTask` (an ``AutomaticTask`` for the controller, one
set-point per cycle) and :func:`refine` (blocking; drives a ``RobotBackend`` with the same
task). Images come from a :class:`~icenav.recovery.beats.BeatImager`;
:class:`icenav.sim.beat_imager.SimulatedBeatImager` renders them on the digital twin.

The EM pose stage is :mod:`icenav.refinement.pose_stage`, the respiratory gating
:mod:`icenav.refinement.gating`, both stages as one task :mod:`icenav.refinement.task`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_joint_state, check_positive
from icenav.devices.robot import RobotBackend
from icenav.errors import ConfigurationError, NeighbourhoodError, ShapeError
from icenav.recovery.beats import BeatClip, BeatImager
from icenav.refinement._stepper import _Measure, _Move, _Request, _Stepper
from icenav.refinement.similarity import beat_score, blur_frames, match_by_phase, ncc_rows

__all__ = [
    "BeatClip",
    "BeatImager",
    "NeighbourhoodError",
    "RefinementConfig",
    "RefinementResult",
    "RefinementStatus",
    "RefinementTask",
    "TrialRecord",
    "beat_score",
    "drive_task",
    "refine",
]

_DEG = math.pi / 180.0


def _four(values: Sequence[float], name: str, unit: str) -> tuple[float, float, float, float]:
    v = tuple(float(x) for x in values)
    if len(v) != 4:
        raise ConfigurationError(f"{name} needs 4 values {unit}, got {v}")
    for x in v:
        check_positive(x, name, unit)
    return v[0], v[1], v[2], v[3]


@dataclass(frozen=True)
class RefinementConfig:
    """Settings of the closed-loop refinement (per joint: phi1, phi2, phi3 rad, d4 mm)."""

    radius: tuple[float, float, float, float] = (3 * _DEG, 3 * _DEG, 3 * _DEG, 2.0)
    """Half-width of the box around the saved view's motor state that no set-point leaves
    (rad, rad, rad, mm)."""
    initial_step: tuple[float, float, float, float] = (1.5 * _DEG, 1.5 * _DEG, 1.5 * _DEG, 0.5)
    """First compass step of each joint (rad, rad, rad, mm); each must be <= its radius."""
    min_step: tuple[float, float, float, float] = (0.2 * _DEG, 0.2 * _DEG, 0.2 * _DEG, 0.1)
    """The search ends when every step is below this (rad, rad, rad, mm)."""
    max_evaluations: int = 24
    """Budget of one-beat measurements (the start's included)."""
    max_duration_s: float = 60.0
    """Budget of controller time (s): moves, holds and beats."""
    min_improvement: float = 0.003
    """A trial must beat the incumbent's blurred similarity by this much (NCC units); about
    1.5 times the beat-to-beat noise of the score with a few reference beats on the twin."""
    stop_within: float = 0.01
    """Do not search when the start beat scores within this of the reference beats' own
    consecutive-beat score (the ceiling, measured on the saved beats; needs >= 2 of them):
    the view is already recovered as well as the images can tell, and every trial move
    would shift the transmission's play (hysteresis) for nothing. NCC units; 0 disables."""
    noise_factor: float = 3.0
    """``min_improvement`` and ``stop_within`` are at least this many times the score's
    beat-to-beat noise measured on the reference beats (the standard deviation of each
    reference beat's score against the others; needs >= 3 of them) and, with
    ``significance``, ``stop_within`` at least this many times the start's own noise per
    beat: the stage searches only when the start is clearly below the ceiling (a view
    lost, not a view a little off). 0: the fixed values only."""
    confirm: bool = True
    """Measure a trial that looks better a second time and accept it only if the mean of
    both beats still beats the incumbent by ``min_improvement`` (fewer false accepts)."""
    overshoot: tuple[float, float, float, float] = (1.0 * _DEG, 1.0 * _DEG, 1.0 * _DEG, 0.5)
    """Approach distance: each trial is reached moving in the view's arrival direction from
    this far back (rad, rad, rad, mm), within the box."""
    max_velocity: tuple[float, float, float, float] = (
        10.0 * _DEG,
        10.0 * _DEG,
        10.0 * _DEG,
        3.0,
    )
    """Joint speed of refinement moves (rad/s, rad/s, rad/s, mm/s)."""
    settle_s: float = 0.05
    """Hold after a move before the beat starts (s)."""
    blur_sigma_px: float = 2.0
    """Gaussian blur of the similarity (pixels of the images)."""
    blur_factor: int = 2
    """Down-sampling of the similarity."""
    search: bool = False
    """Search at all. Off (the default): the stage measures the start and reports whether the
    view looks recovered (``AT_VIEW``) or lost (``LOST``), and never moves. On the twin, in
    vivo, a search from the images alone made returns worse, not better
    (``docs/view-recovery.md``); a lost view is better returned to again."""
    joints: tuple[bool, bool, bool, bool] = (True, True, True, False)
    """Joints the search moves (phi1, phi2, phi3, d4); the others stay where they are."""
    beats: int = 2
    """Gated beats averaged per measurement (the start, every trial, every re-measurement):
    the score's beat-to-beat noise falls as 1 / sqrt(beats); each beat counts against
    ``max_evaluations``."""
    significance: float = 2.0
    """A trial (and the end state, ``verify_end``) must beat the incumbent (the start) by at
    least ``significance * sigma * sqrt(1 / n_a + 1 / n_b)``: a z-test of two means of
    ``n_a`` and ``n_b`` beats, ``sigma`` the score's noise per beat (the larger of the saved
    beats' and the start's beats' standard deviation); 0: off (``min_improvement`` only)."""
    verify_end: bool = True
    """When the search ended away from its start, measure the end state again with fresh
    beats (the accepted ones were selected for being high) and go back to the start unless
    these beat the start's by the ``significance`` test (status ``UNDONE``): never farther
    from the saved view than the start by the stage's own estimator."""

    def __post_init__(self) -> None:
        unit = "(rad, rad, rad, mm)"
        for name in ("radius", "initial_step", "min_step", "overshoot"):
            object.__setattr__(self, name, _four(getattr(self, name), name, unit))
        object.__setattr__(
            self, "max_velocity", _four(self.max_velocity, "max_velocity", "(rad/s, ..., mm/s)")
        )
        for j in range(4):
            if self.initial_step[j] > self.radius[j]:
                raise ConfigurationError(
                    f"initial_step[{j}] = {self.initial_step[j]:.4g} exceeds radius[{j}] = "
                    f"{self.radius[j]:.4g} {unit}"
                )
        n = self.max_evaluations
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ConfigurationError(f"max_evaluations must be an int >= 1, got {n!r}")
        check_positive(self.max_duration_s, "max_duration_s", "s")
        if not (math.isfinite(self.min_improvement) and self.min_improvement >= 0):
            raise ConfigurationError(
                f"min_improvement must be finite and >= 0 (NCC), got {self.min_improvement}"
            )
        if not (math.isfinite(self.stop_within) and self.stop_within >= 0):
            raise ConfigurationError(
                f"stop_within must be finite and >= 0 (NCC), got {self.stop_within}"
            )
        if not (math.isfinite(self.noise_factor) and self.noise_factor >= 0):
            raise ConfigurationError(
                f"noise_factor must be finite and >= 0, got {self.noise_factor}"
            )
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise ConfigurationError(f"settle_s must be finite and >= 0 s, got {self.settle_s}")
        check_positive(self.blur_sigma_px, "blur_sigma_px", "px")
        for name in ("blur_factor", "beats"):
            f = getattr(self, name)
            if isinstance(f, bool) or not isinstance(f, int) or f < 1:
                raise ConfigurationError(f"{name} must be an int >= 1, got {f!r}")
        joints = tuple(bool(x) for x in self.joints)
        if len(joints) != 4 or not any(joints):
            raise ConfigurationError(f"joints must be 4 flags, one True at least: {self.joints!r}")
        object.__setattr__(self, "joints", joints)
        if not (math.isfinite(self.significance) and self.significance >= 0):
            raise ConfigurationError(
                f"significance must be finite and >= 0, got {self.significance}"
            )


class RefinementStatus(enum.Enum):
    """State of a refinement: running, or why it ended."""

    AT_VIEW = "at_view"
    """The start already scored within ``stop_within`` of the ceiling: no search."""
    CONVERGED = "converged"
    """Every step fell below ``min_step``."""
    BUDGET = "budget"
    """``max_evaluations`` beats were measured."""
    TIMEOUT = "timeout"
    """``max_duration_s`` of controller time passed."""
    ABORTED = "aborted"
    """``abort()`` returned True; the robot holds where it was."""
    LOST = "lost"
    """``search`` off: the start scored below the gate (or there is no gate); no move."""
    UNDONE = "undone"
    """``verify_end``: the end state's fresh beats did not beat the start's; back at the
    start."""
    RUNNING = "running"
    """Not finished yet."""


@dataclass(frozen=True)
class TrialRecord:
    """One one-beat measurement of the search."""

    q: Array
    """(4,) motor state measured (rad, rad, rad, mm)."""
    score: float
    """Blurred beat similarity there (NCC, [-1, 1])."""
    accepted: bool
    """Whether it became (or stayed, for a re-measurement) the incumbent."""
    t_s: float
    """Controller time since the start of the refinement (s)."""


@dataclass(frozen=True)
class RefinementResult:
    """Outcome of a refinement."""

    q_start: Array
    """(4,) motor state at the start (rad, rad, rad, mm)."""
    q_final: Array
    """(4,) motor state at the end (the incumbent, unless aborted)."""
    start_score: float
    """Mean blurred similarity of the start measurement (NaN if none)."""
    best_score: float
    """Mean blurred similarity of the final incumbent over its measurements (NaN if none)."""
    trials: tuple[TrialRecord, ...]
    """Every measurement in order (the similarity trace)."""
    status: RefinementStatus
    """Why it ended."""
    duration_s: float
    """Controller time used (s)."""
    n_commands: int
    """Set-points sent."""
    max_offset: Array = field(default_factory=lambda: np.zeros(4))
    """(4,) largest |set-point - q_view| per joint over the run (rad, rad, rad, mm)."""


class RefinementTask:
    """Closed-loop refinement as a controller task (one set-point per control cycle).

    Parameters
    ----------
    q_view : array-like, shape (4,)
        Motor state of the saved view: the centre of the neighbourhood (rad, rad, rad, mm).
    reference : BeatClip or sequence of BeatClip
        The view's saved beat(s). With several consecutive beats the score is the best
        match over them, which makes it nearly independent of the respiratory phase.
    imager : BeatImager
        Live images.
    q_start : array-like, shape (4,), optional
        Where the robot is now (default ``q_view``); must lie in the neighbourhood.
    arrival_direction : 4 ints in (-1, 0, 1)
        The view's arrival direction per joint (0: no approach for that joint).
    config : RefinementConfig
    abort : callable, optional
        Polled every cycle; True ends the refinement at once (status ABORTED).
    """

    label = "refine view"

    def __init__(
        self,
        q_view: ArrayLike,
        reference: BeatClip | Sequence[BeatClip],
        imager: BeatImager,
        *,
        q_start: ArrayLike | None = None,
        arrival_direction: Sequence[int] = (0, 0, 0, 0),
        config: RefinementConfig | None = None,
        abort: Callable[[], bool] | None = None,
    ) -> None:
        self.config = cfg = config if config is not None else RefinementConfig()
        self.q_view = np.array(check_joint_state(q_view, name="q_view"), np.float64)
        if self.q_view.shape != (4,):
            raise ShapeError(f"q_view must have shape (4,), got {self.q_view.shape}")
        q0 = self.q_view if q_start is None else check_joint_state(q_start, name="q_start")
        self.q_start = np.array(q0, np.float64).reshape(4)
        self.radius = np.array(cfg.radius)
        self.lo = self.q_view - self.radius
        self.hi = self.q_view + self.radius
        off = np.abs(self.q_start - self.q_view)
        if np.any(off > self.radius * (1 + 1e-9)):
            j = int(np.argmax(off / self.radius))
            raise NeighbourhoodError(
                f"the start state is {off[j]:.4g} from the view on joint {j}, outside the "
                f"refinement radius {self.radius[j]:.4g} (rad, rad, rad, mm)"
            )
        direction = tuple(int(d) for d in arrival_direction)
        if len(direction) != 4 or any(d not in (-1, 0, 1) for d in direction):
            raise ConfigurationError(
                f"arrival_direction must be 4 values in (-1, 0, 1), got {arrival_direction!r}"
            )
        self.direction = np.array(direction, np.float64)
        refs = (reference,) if isinstance(reference, BeatClip) else tuple(reference)
        if not refs or not all(isinstance(r, BeatClip) for r in refs):
            raise ConfigurationError("reference must be a BeatClip or a non-empty sequence of them")
        if any(r.images.shape[1:] != refs[0].images.shape[1:] for r in refs):
            raise ShapeError("all reference beats must have images of one shape")
        self.references = refs
        self.imager = imager
        self._abort = abort
        self._ref_blur = [blur_frames(r.images, cfg.blur_sigma_px, cfg.blur_factor) for r in refs]
        m = refs[0].mask
        self._mask = None if m is None else m[:: cfg.blur_factor, :: cfg.blur_factor]
        self.ceiling, self.noise = self._ceiling()
        """Mean score of each reference beat against the others (NaN with one beat), and
        the standard deviation of those scores (NaN with fewer than three beats)."""
        k = cfg.noise_factor * self.noise if math.isfinite(self.noise) else 0.0
        self.min_improvement = max(cfg.min_improvement, k)
        """The improvement a trial must show (NCC units): the config's, or ``noise_factor``
        times the reference beats' noise if larger."""
        self.stop_within = max(cfg.stop_within, k) if cfg.stop_within > 0 else 0.0
        """The start is at the view within this of the ceiling (NCC units; 0: never)."""
        self._hold_s = cfg.settle_s + imager.beat_duration_s
        # execution state
        self._gen = self._search()
        # set-points of the current move, the box check and the sent-command bookkeeping;
        # the return ended with the view's approach, hence its direction
        self._run = _Stepper(
            self.q_view,
            self.q_start,
            self.radius,
            np.array(cfg.max_velocity),
            None,
            last_dir=self.direction,
            label="refinement set-point",
        )
        self._hold_left = 0.0
        self._measuring = False
        self._gen_done = False
        self._elapsed = 0.0
        self._status = RefinementStatus.RUNNING
        self._trials: list[TrialRecord] = []
        self._best_q = self.q_start.copy()
        self._best_score = math.nan
        self._start_score = math.nan
        self._n_eval = 0
        self.sigma = self.noise
        """The score's noise per beat for the ``significance`` test (NCC units): the saved
        beats' (``noise``), raised to the start's own beats' standard deviation if larger."""
        self._verified = False

    # --- scoring -------------------------------------------------------------------------
    def score(self, clip: BeatClip) -> float:
        """Blurred beat similarity of ``clip`` to the reference beats: the best over the
        reference beats of :func:`beat_score` (same blur)."""
        if clip.images.shape[1:] != self.references[0].images.shape[1:]:
            raise ShapeError(
                f"live images {clip.images.shape[1:]} differ from the reference's "
                f"{self.references[0].images.shape[1:]}"
            )
        return max(self._score_one(clip, j) for j in range(len(self.references)))

    def _ceiling(self) -> tuple[float, float]:
        if len(self.references) < 2:
            return math.nan, math.nan
        values = []
        for i, ref in enumerate(self.references):
            others = [j for j in range(len(self.references)) if j != i]
            values.append(max(self._score_one(ref, j) for j in others))
        noise = float(np.std(values, ddof=1)) if len(values) >= 3 else math.nan
        return float(np.mean(values)), noise

    def _score_one(self, clip: BeatClip, j: int) -> float:
        cfg = self.config
        ref, ref_blur = self.references[j], self._ref_blur[j]
        a = blur_frames(clip.images[match_by_phase(clip.phases, ref.phases)], cfg.blur_sigma_px,
                  cfg.blur_factor)  # fmt: skip
        if self._mask is not None:
            return float(np.mean(ncc_rows(a[:, self._mask], ref_blur[:, self._mask])))
        n = len(a)
        return float(np.mean(ncc_rows(a.reshape(n, -1), ref_blur.reshape(n, -1))))

    # --- the search (a generator of move / measure requests) --------------------------------
    def _approach(self, q_from: Array, trial: Array) -> list[Array]:
        """Set-point targets to reach ``trial`` moving in the arrival direction at the end."""
        d = self.direction
        delta = trial - q_from
        need = (d != 0) & ((delta * d < 0) | ((delta == 0) & (self._run.last_dir != d)))
        targets = []
        if np.any(need):
            pre = np.clip(trial - d * np.array(self.config.overshoot), self.lo, self.hi)
            targets.append(pre)
        targets.append(trial)
        return targets

    def _beats(self) -> Generator[_Request, float | None, list[float]]:
        """One measurement here: ``config.beats`` gated beats (fewer if the budget ends)."""
        out: list[float] = []
        for _ in range(self.config.beats):
            if self._n_eval >= self.config.max_evaluations:
                break
            s = yield _Measure()
            assert s is not None
            out.append(float(s))
        return out

    def _threshold(self, n_a: int, n_b: int) -> float:
        """What a mean of ``n_a`` beats must gain on one of ``n_b`` (NCC units)."""
        z = self.config.significance
        if z <= 0 or not math.isfinite(self.sigma) or n_a < 1 or n_b < 1:
            return self.min_improvement
        return max(self.min_improvement, z * self.sigma * math.sqrt(1.0 / n_a + 1.0 / n_b))

    def _learn_noise(self, start: list[float]) -> None:
        """With ``significance``: the noise per beat is at least the start's beats' standard
        deviation (the saved beats are few and taken at the saved state), and so is the gate
        (``noise_factor`` times it)."""
        if len(start) < 2 or self.config.significance <= 0:
            return
        self.sigma = float(np.nanmax([self.noise, np.std(start, ddof=1)]))
        if self.stop_within > 0:
            self.stop_within = max(self.stop_within, self.config.noise_factor * self.sigma)

    def _fits(self, n_beats: int) -> bool:
        """``n_beats`` more beats fit in the evaluation budget (and, with ``verify_end``, in
        the time budget, with 2 s of moves)."""
        cfg = self.config
        if self._n_eval + n_beats > cfg.max_evaluations:
            return False
        if cfg.verify_end:
            return self._elapsed + n_beats * self._hold_s + 2.0 <= cfg.max_duration_s
        return True

    def _search(self) -> Generator[_Request, float | None, None]:
        cfg = self.config
        step = np.array(cfg.initial_step)
        min_step = np.array(cfg.min_step)
        best_q = self.q_start.copy()
        start = yield from self._beats()
        for s in start:
            self._record(best_q, s, True)
        best, n_best = float(np.mean(start)), len(start)
        self._start_score = best
        self._best_q, self._best_score = best_q.copy(), best
        gate = self.stop_within > 0 and math.isfinite(self.ceiling)
        self._learn_noise(start)
        if gate and best < self.ceiling - self.stop_within and self._fits(1):
            # one measurement may be unlucky (respiration, the beat): another before moving
            more = yield from self._beats()
            for s in more:
                self._record(best_q, s, True)
            start += more
            best, n_best = float(np.mean(start)), len(start)
            self._best_score = best
            self._learn_noise(start)
        start_mean, n_start = best, n_best
        if gate and best >= self.ceiling - self.stop_within:
            self._status = RefinementStatus.AT_VIEW
            return
        if not cfg.search:
            self._status = RefinementStatus.LOST
            return
        reserve = cfg.beats if cfg.verify_end else 0
        last_ok: tuple[int, float] | None = None
        while True:
            if np.all(step < min_step):
                self._status = RefinementStatus.CONVERGED
                break
            polls = [
                (j, sg)
                for j in range(4)
                for sg in (1.0, -1.0)
                if cfg.joints[j] and step[j] >= min_step[j]
            ]
            if not polls:
                self._status = RefinementStatus.CONVERGED
                break
            if last_ok is not None and last_ok in polls:
                polls.remove(last_ok)
                polls.insert(0, last_ok)
            improved = False
            for j, sg in polls:
                trial = best_q.copy()
                trial[j] += sg * step[j]
                trial = np.clip(trial, self.lo, self.hi)
                if np.array_equal(trial, best_q):
                    continue
                if not self._fits(1 + reserve):
                    break
                for target in self._approach(self._cmd_target(), trial):
                    yield _Move(target)
                vals = yield from self._beats()
                ok = float(np.mean(vals)) > best + self._threshold(len(vals), n_best)
                if ok and cfg.confirm and self._fits(1 + reserve):
                    for s in vals:
                        self._record(trial, s, False)
                    more = yield from self._beats()  # a second measurement, same place
                    vals += more
                    ok = float(np.mean(vals)) > best + self._threshold(len(vals), n_best)
                    for s in more:
                        self._record(trial, s, ok)
                else:
                    ok = ok and not cfg.confirm  # no budget left to confirm it
                    for s in vals:
                        self._record(trial, s, ok)
                if ok:
                    best_q, best, n_best = trial, float(np.mean(vals)), len(vals)
                    self._best_q, self._best_score = best_q.copy(), best
                    last_ok = (j, sg)
                    improved = True
                    break
            if not self._fits(1 + reserve):
                self._status = RefinementStatus.BUDGET
                break
            if not improved:
                step = step * 0.5
                last_ok = None
                if np.all(step < min_step):
                    self._status = RefinementStatus.CONVERGED
                    break
                # re-measure the incumbent: its score becomes the mean of its beats
                for target in self._approach(self._cmd_target(), best_q):
                    yield _Move(target)
                vals = yield from self._beats()
                best = (best * n_best + float(np.sum(vals))) / (n_best + len(vals))
                n_best += len(vals)
                self._best_score = best
                for s in vals:
                    self._record(best_q, s, True)
        if cfg.verify_end and not np.array_equal(best_q, self.q_start):
            # fresh beats at the end state (the accepted ones were the lucky ones)
            for target in self._approach(self._cmd_target(), best_q):
                yield _Move(target)
            vals = yield from self._beats()
            fresh = float(np.mean(vals)) if vals else -math.inf
            ok = fresh > start_mean + self._threshold(len(vals), n_start)
            for s in vals:
                self._record(best_q, s, ok)
            if ok:
                self._best_score = fresh
            else:
                best_q = self.q_start.copy()
                self._best_q, self._best_score = best_q.copy(), start_mean
                self._status = RefinementStatus.UNDONE
            self._verified = True
        # end at the incumbent, approached the same way
        for target in self._approach(self._cmd_target(), best_q):
            yield _Move(target)

    def _cmd_target(self) -> Array:
        return self._run.cmd.copy()

    def _record(self, q: Array, s: float, accepted: bool) -> None:
        self._trials.append(TrialRecord(q.copy(), float(s), accepted, self._elapsed))

    # --- the controller interface --------------------------------------------------------
    @property
    def status(self) -> RefinementStatus:
        """Running, or why it ended."""
        return self._status

    @property
    def progress(self) -> float:
        """Fraction of the evaluation budget used, in [0, 1] (1 when finished)."""
        if self._gen_done and not self._run.queue:
            return 1.0
        return min(1.0, self._n_eval / self.config.max_evaluations)

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """The next motor set-point (4,), or None when the refinement has ended."""
        check_positive(dt, "dt", "s")
        if self._status == RefinementStatus.ABORTED:
            return None
        if self._abort is not None and self._abort():
            self._status = RefinementStatus.ABORTED
            self._gen.close()
            self._gen_done = True
            self._run.queue = []
            return None
        if self._gen_done and not self._run.queue:
            return None
        self._elapsed += dt
        if self._status == RefinementStatus.RUNNING and self._elapsed > self.config.max_duration_s:
            # out of time: stop searching, head for the incumbent with the approach
            self._status = RefinementStatus.TIMEOUT
            self._gen.close()
            self._gen_done = True
            self._measuring = False
            self._run.queue = []
            if self.config.verify_end and not self._verified:
                self._best_q = self.q_start.copy()  # an unverified end state is not kept
                self._best_score = self._start_score
            self._run.queue_moves(self._approach(self._run.cmd, self._best_q), dt)
        while True:
            if self._run.queue:
                return self._run.send(self._run.queue.pop(0))
            if self._gen_done:
                return None
            value: float | None = None
            if self._measuring:
                if self._hold_left > 0:
                    self._hold_left -= dt
                    return self._run.cmd.copy()
                value = self.score(self.imager.acquire_beat())
                self._n_eval += 1
                self._measuring = False
            try:
                req = self._gen.send(value)
            except StopIteration:
                self._gen_done = True
                if self._status == RefinementStatus.RUNNING:
                    self._status = RefinementStatus.CONVERGED
                return None
            if isinstance(req, _Measure):
                self._measuring = True
                self._hold_left = self._hold_s
            else:
                self._run.queue_moves([req.q], dt)

    def result(self) -> RefinementResult:
        """The outcome so far (final once :meth:`next_command` returned None)."""
        start = self._start_score
        return RefinementResult(
            q_start=self.q_start.copy(),
            q_final=self._best_q.copy()
            if self._status != RefinementStatus.ABORTED
            else self._run.cmd.copy(),
            start_score=start,
            best_score=self._best_score,
            trials=tuple(self._trials),
            status=self._status,
            duration_s=self._elapsed,
            n_commands=self._run.n_cmd,
            max_offset=self._run.max_off.copy(),
        )


def refine(
    robot: RobotBackend,
    q_view: ArrayLike,
    reference: BeatClip | Sequence[BeatClip],
    imager: BeatImager,
    *,
    arrival_direction: Sequence[int] = (0, 0, 0, 0),
    config: RefinementConfig | None = None,
    abort: Callable[[], bool] | None = None,
    dt: float = 0.01,
    sleep: Callable[[float], None] | None = None,
    on_command: Callable[[Array], object] | None = None,
    max_cycles: int = 1_000_000,
) -> RefinementResult:
    """Refine the view on ``robot`` (blocking): run a :class:`RefinementTask` to its end.

    Parameters
    ----------
    robot : RobotBackend
        ENABLED, standing within the neighbourhood of ``q_view`` (its encoders give the
        start state).
    q_view, reference, imager, arrival_direction, config, abort
        As for :class:`RefinementTask`.
    dt : float
        Control period (s).
    sleep : callable, optional
        Called with ``dt`` after every cycle: ``time.sleep`` on hardware, a simulation
        clock's ``advance`` on the twin (so the imager sees time pass).
    on_command : callable, optional
        Called with every set-point sent (e.g. to record it in the roadmap).

    Returns
    -------
    RefinementResult
    """
    check_positive(dt, "dt", "s")
    q0 = np.asarray(robot.read_state().q, np.float64)
    task = RefinementTask(
        q_view,
        reference,
        imager,
        q_start=q0,
        arrival_direction=arrival_direction,
        config=config,
        abort=abort,
    )
    drive_task(robot, task, dt, sleep=sleep, on_command=on_command, max_cycles=max_cycles)
    return task.result()


class _SteppedTask(Protocol):
    def next_command(self, q_measured: Array, dt: float) -> Array | None: ...


def drive_task(
    robot: RobotBackend,
    task: _SteppedTask,
    dt: float,
    *,
    sleep: Callable[[float], None] | None = None,
    on_command: Callable[[Array], object] | None = None,
    max_cycles: int = 1_000_000,
) -> None:
    """Run a task's ``next_command`` on ``robot`` until it returns None (blocking): read the
    joint state, send the set-point, report it to ``on_command``, ``sleep(dt)`` if given;
    at most ``max_cycles`` cycles. Shared by :func:`refine` and
    :func:`icenav.refinement.pose_stage.pose_stage`."""
    for _ in range(int(max_cycles)):
        q = np.asarray(robot.read_state().q, np.float64)
        cmd = task.next_command(q, dt)
        if cmd is None:
            return
        robot.command_position(cmd)
        if on_command is not None:
            on_command(cmd)
        if sleep is not None:
            sleep(dt)

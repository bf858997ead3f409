"""``icenav eval recovery``: the paper's view-recovery experiment (Table II) on the twin.

Protocol (the phantom study of Section IV, with the in-vivo metrics of Table II):

1. A scripted operator drives the *motors* to the aortic, mitral and tricuspid valve views
   (model joint states used as motor targets: no compensation; on today's twin
   :data:`icenav.sim.anatomy.EXAMPLE_VIEWS`, in a patient the views an operator finds in
   that heart, :func:`icenav.sim.patient.aim_views`), every state recorded in the roadmap,
   and saves each view where the robot actually is (motor state, true pose, one beat of
   images); then it wanders (random exploration).
2. The robot cycles through the views ``rounds`` times (16, as the phantom study), each
   return planned on the roadmap with the same-direction approach and executed as the
   controller does (:class:`icenav.control.controller.PathTask`: exactly through the recorded
   states at bounded speed); after each return the EM tracker (8 samples averaged), the
   twin's true pose (now, and averaged over a dynamic CT's 5-s rotation) and one beat of
   images are recorded. As in the controller, every commanded state (returns and
   refinement moves) is added to the roadmap, so the recorded trace stays contiguous.
3. Two modes, run one after the other on the same catheter and roadmap: ``open_loop``
   (the paper's system) and ``refined``: after each return the EM pose stage
   (:class:`icenav.refinement.pose_stage.PoseStageTask`: servo the EM-measured tip pose onto
   the EM pose saved with the view; on a disturbed twin both are averaged over complete
   breaths, or beats without breathing, :mod:`icenav.refinement.cycle_pose`, with the
   settings :data:`CYCLE_POSE_STAGE`; on today's twin 64 samples) and then, unless
   ``image_stage`` is off, the image stage (:func:`icenav.refinement.image_search.refine`,
   centred where the pose stage ended, scoring respiratory-gated beats; since session 8 it
   measures and reports whether the view is held, ``at_view`` or ``lost``, and holds still
   unless its search is switched on); without the pose stage (``--no-em``) the image stage
   alone. Every set-point is recorded.
   Returns check the contact force against the operator's trace as the product's "go to
   view" does (:func:`icenav.control.tasks.goto_view_task`: Eqs. F1, F2, F4, F5) on a
   twin with contact; a stopped return is counted and finished without the check.
4. After every return (and refinement) the catheter is held still for the cycle window and
   the twin's true pose averaged over its complete breaths (beats) is recorded
   (``static_tip2base``: the refinement's target is measured on it); then two beats: one
   ECG-gated beat at whatever respiratory phase it falls (``clip``), and one gated on ECG
   *and* respiration to the saved beat (``gated_clip``,
   :class:`icenav.refinement.gating.GatedBeatImager`: the catheter held still for 5 beats).

Conditions (``--condition``, :mod:`icenav.sim.conditions`): ``none`` (today's twin, the
default: nothing disturbs a return), ``phantom`` (the paper's bench study) and ``in-vivo``
(the animal study), in patient ``--patient`` (anatomy, rhythm, breathing). The metrics
are described in :mod:`icenav.eval.recovery_report`.

Images are rendered at 128 x 128 pixels with 64 beams and 10 frames per beat (reduced from
the renderer's 256 x 256, 96 beams, to keep a full run near 2 minutes); the similarity
ceiling is measured at the same settings.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav._validation import check_positive
from icenav.errors import ConfigurationError, IcenavError
from icenav.eval.recovery_bench import DT, REST_FORCE_N, Bench
from icenav.eval.recovery_report import (
    RecoveryRecord,
    format_table,
    make_record,
    raw_similarity,
    record_json,
    roi_error,
    summary_table,
)
from icenav.recovery.beats import BeatClip
from icenav.recovery.views import View
from icenav.refinement.gating import GatedBeatImager
from icenav.refinement.image_search import RefinementConfig, refine
from icenav.refinement.pose_stage import PoseStageConfig, pose_stage
from icenav.refinement.presets import CYCLE_POSE_STAGE, CYCLE_POSE_STAGE_PHANTOM
from icenav.refinement.retry import RetryConfig, retry_return
from icenav.sim.conditions import CONDITIONS, DISTURBANCES

__all__ = [
    "CYCLE_POSE_STAGE",
    "CYCLE_POSE_STAGE_PHANTOM",
    "MODES",
    "RecoveryConfig",
    "RecoveryRecord",
    "RecoveryRun",
    "ReturnSample",
    "TARGETS",
    "config_from_args",
    "cycle_stage_config",
    "format_table",
    "main",
    "run_recovery",
]

_DEG = math.pi / 180.0


TARGETS = ("aortic_valve", "mitral_valve", "tricuspid_valve")
"""The paper's three imaging targets (names of the views and ROI labels)."""
MODES = ("open_loop", "refined")
"""Open-loop return (the paper) and return + closed-loop refinement."""


@dataclass(frozen=True)
class RecoveryConfig:
    """Settings of one run of the experiment."""

    seed: int = 100
    """Catheter, tracker, speckle and operator seed (seeds 0-9 tuned the twin)."""
    vessel: str = "moderate"
    """Vessel of the shaft: straight, moderate or steep."""
    condition: str = "none"
    """Disturbances: none (today's twin), phantom or in-vivo."""
    plant: str | None = None
    """Plant plug-in ``MODULE:FACTORY`` or family name (:func:`icenav.sim.plugins.make_plant`;
    the factory must take ``clock=``); None: today's twin."""
    patient: int = 0
    """Patient seed (anatomy, rhythm, breathing) under a condition."""
    disable: tuple[str, ...] = ()
    """Disturbances of the condition switched off (names of
    :data:`icenav.sim.conditions.DISTURBANCES`)."""
    rounds: int = 16
    """Returns to each target per mode (16 as the phantom study)."""
    modes: tuple[str, ...] = MODES
    """Modes to run, in order."""
    frames_per_beat: int = 10
    """Frames per heart beat of every recorded clip (ECG gated: phases k / n)."""
    refine_subsample: int = 2
    """The refinement sees every this-th frame of a beat."""
    image_size: int = 128
    """Rendered picture size (pixels)."""
    n_beams: int = 64
    """Beams of the rendered sector."""
    n_samples: int = 192
    """Samples per beam."""
    wander_moves: int = 12
    """Random exploration moves after the views are saved."""
    rest_force_n: float | None = REST_FORCE_N
    """The looking operator (:meth:`Bench.explore`): after each exploration move the
    operator reads the contact force at rest and, while its mean over a second exceeds this
    (N), backs off halfway towards where the move started (at most 6 times), as a
    cardiologist does not leave an ICE catheter pushing a wall; None: session 8's blind
    operator. No effect without a contact-force channel (condition ``none``)."""
    em_average: int = 8
    """EM samples averaged per return."""
    ceiling_beats: int = 16
    """Consecutive beat pairs at each saved view for the ceiling (their mean similarity: one
    pair scatters by about 3.3 points on the twin in vivo and the breathing makes pairs close
    in time alike, so three pairs scatter by about 2.4 points, sixteen by about 1.4)."""
    reference_beats: int = 4
    """Beats saved with each view as the image stage's references (the first of the
    ceiling's beats)."""
    em_average_saved: int = 64
    """EM samples averaged for the pose saved with each view (the pose stage's target)."""
    gate_window_beats: int = 5
    """Beats held still per respiratory-gated beat (about one breath)."""
    dct_window_s: float = 5.0
    """Rotation time of the dynamic CT whose average pose is the 'true' tip (s)."""
    dct_samples: int = 26
    """Poses averaged over the DCT window."""
    pose_stage: PoseStageConfig | None = field(default_factory=PoseStageConfig)
    """EM pose stage of the refined mode (None: image stage only)."""
    image_stage_gated: bool = True
    """The image stage scores respiratory-gated beats (else plain ECG-gated beats)."""
    refinement: RefinementConfig = field(default_factory=RefinementConfig)
    """Closed-loop refinement (image stage) settings."""
    em_estimator: str = "cycle"
    """EM pose of the pose stage and of the saved view on a disturbed twin: ``cycle``
    (averaged over complete breaths / beats, :mod:`icenav.refinement.cycle_pose`) or
    ``average`` (``em_average_saved`` consecutive samples, at any respiratory phase)."""
    cycle_window_s: float | None = None
    """Window of the cycle-averaged estimates (s); None: 9 s with breathing, 3 s without."""
    cycle_rate_hz: float = 10.0
    """EM (and truth) samples per second of the cycle-averaged estimates (Hz)."""
    refine_window_s: float | None = None
    """Window of the pose stage's own cycle-averaged estimates (s); None: the cycle window
    (the saved pose and the static metric always use the cycle window)."""
    cycle_pose_stage: PoseStageConfig | None = None
    """Pose stage settings with the cycle-averaged estimator (its hold is set to the
    window); None: :data:`CYCLE_POSE_STAGE_PHANTOM` in the phantom, else
    :data:`CYCLE_POSE_STAGE`."""
    image_stage: bool = False
    """On a disturbed twin, run the image stage after the EM stage too (it always runs when
    there is no EM stage, ``--no-em``, and on today's twin); off by default: under the
    disturbances its many small moves added error."""
    refine_strategy: str = "pose_stage"
    """EM stage on a disturbed twin: ``pose_stage`` (corrective steps,
    :data:`CYCLE_POSE_STAGE`) or ``retry`` (measured re-approach,
    :mod:`icenav.refinement.retry`)."""
    retry: RetryConfig = field(default_factory=RetryConfig)
    """Settings of the ``retry`` strategy."""
    force_check: bool = True
    """Returns read the twin's contact force and stop above the operator's + the margin,
    as the product's "go to view" does (:func:`icenav.control.tasks.goto_view_task`; a
    disturbed twin with contact only)."""
    force_margin_n: float | None = None
    """Absolute margin of the force check (N); None: the product's
    (:attr:`icenav.control.config.ControllerConfig.force_margin_n`)."""
    force_margin_fraction: float | None = None
    """Relative margin of the force check (fraction of the operator's force); None: the
    product's (:attr:`icenav.control.config.ControllerConfig.force_margin_fraction`)."""


@dataclass(frozen=True)
class ReturnSample:
    """What was recorded after one return."""

    target: str
    """View name."""
    mode: str
    """open_loop or refined."""
    q: Array
    """(4,) motor state at the end (rad, rad, rad, mm)."""
    true_tip2base: Array
    """(4, 4) the twin's true pose when the EM pose was taken (mm)."""
    em_tip2base: Array | None
    """(4, 4) EM-measured pose (mm), None if every sample dropped out."""
    clip: BeatClip
    """One beat of images after the return (ECG gated, any respiratory phase)."""
    gated_clip: BeatClip | None = None
    """One beat gated on ECG and respiration to the saved beat (None if not measured)."""
    dct_tip2base: Array = field(default_factory=lambda: np.eye(4))
    """(4, 4) the true pose averaged over the DCT window after the return (mm)."""
    max_contact_force_n: float = 0.0
    """Largest total contact force during the return and its refinement (N)."""
    pose_stage_tip2base: Array | None = None
    """(4, 4) the twin's true pose after the pose stage, before the image stage (mm)."""
    pose_stage_status: str = ""
    """How the pose stage ended ("" for open loop)."""
    pose_stage_measurements: int = 0
    """EM measurements the pose stage used."""
    pose_stage_s: float = 0.0
    """Controller time of the pose stage (s)."""
    pose_stage_trace: tuple[tuple[float, float], ...] = ()
    """EM-measured (position mm, orientation deg) error of each pose-stage measurement."""
    refine_evaluations: int = 0
    """One-beat measurements the image stage used (0 for open loop)."""
    refine_moved: bool = False
    """Whether the image stage moved the robot."""
    refine_s: float = 0.0
    """Controller time of the image stage (s)."""
    refine_trace: tuple[float, ...] = ()
    """Blurred similarity of each refinement measurement."""
    static_tip2base: Array = field(default_factory=lambda: np.eye(4))
    """(4, 4) the true pose averaged over complete breaths / beats after the return (mm)."""
    pose_stage_undone: bool = False
    """The pose stage ended worse than it started and went back to the start state."""
    force_margin_use: float = 0.0
    """Largest fraction of the force check's margin used along the return (> 1: stopped)."""
    force_margin_needed_n: float = 0.0
    """The absolute margin (N) this return needed not to stop (at the relative margin)."""
    return_stopped: str | None = None
    """Why the return stopped early (the force check), None when it arrived."""


@dataclass(frozen=True)
class RecoveryRun:
    """Everything a run produced."""

    config: RecoveryConfig
    """The settings."""
    records: tuple[RecoveryRecord, ...]
    """One per (target, mode)."""
    returns: tuple[ReturnSample, ...]
    """Every return in order."""
    views: dict[str, View]
    """The saved views."""
    saved_tip2base: dict[str, Array]
    """True pose at each saved view (mm)."""
    saved_clips: dict[str, BeatClip]
    """The saved beat of each view."""
    saved_em_tip2base: dict[str, Array]
    """EM-measured pose saved with each view (averaged; mm): the pose stage's target."""
    seconds: float
    """Wall time of the run (s)."""
    saved_dct_tip2base: dict[str, Array] = field(default_factory=dict)
    """True pose at each saved view averaged over the DCT window (mm)."""
    saved_static_tip2base: dict[str, Array] = field(default_factory=dict)
    """True pose at each saved view averaged over complete breaths / beats (mm)."""


def cycle_stage_config(cfg: RecoveryConfig, window_s: float) -> PoseStageConfig:
    """The pose stage's settings on the cycle-averaged estimator of window ``window_s`` (s):
    ``cfg.cycle_pose_stage``, else :data:`CYCLE_POSE_STAGE_PHANTOM` in the phantom and
    :data:`CYCLE_POSE_STAGE` otherwise, holding the catheter for the whole window before
    every measurement."""
    base = cfg.cycle_pose_stage
    if base is None:
        base = CYCLE_POSE_STAGE_PHANTOM if cfg.condition == "phantom" else CYCLE_POSE_STAGE
    return replace(base, hold_s=check_positive(window_s, "window_s", "s") + base.settle_s)


def run_recovery(cfg: RecoveryConfig | None = None) -> RecoveryRun:
    """Run the experiment (see the module docstring)."""
    cfg = cfg if cfg is not None else RecoveryConfig()
    t_wall = time.perf_counter()
    b = Bench(cfg)
    views: dict[str, View] = {}
    saved_pose: dict[str, Array] = {}
    saved_dct: dict[str, Array] = {}
    saved_em: dict[str, Array] = {}
    saved_static: dict[str, Array] = {}
    saved_clip: dict[str, BeatClip] = {}
    refine_refs: dict[str, list[BeatClip]] = {}
    ceiling: dict[str, tuple[float, float, float]] = {}
    for name in TARGETS:
        b.drive(b.operator.move_to(b.views[name]))
        b.drive(b.operator.dwell(0.5))
        pose = b.true_pose()
        views[name] = b.roadmap.make_view(name, created_s=b.clock.now(), tip2base=pose)
        saved_pose[name] = pose
        b.hold_still(b.cycle_window_s)
        if b.cycle_sensor is not None:
            em = b.cycle_sensor.measure_tip2base()
        else:
            em = b.tracker.measure_tip2base(n_average=cfg.em_average_saved)
        if em is not None:
            saved_em[name] = np.asarray(em, np.float64)
        saved_static[name] = b.static_pose()
        clips = [b.acquire() for _ in range(cfg.ceiling_beats + 1)]
        saved_clip[name] = clips[0]
        refine_refs[name] = [
            c.subsampled(cfg.refine_subsample) for c in clips[: cfg.reference_beats]
        ]
        sims = [raw_similarity(c1, c0) for c0, c1 in zip(clips, clips[1:], strict=False)]
        rois = [roi_error(c1, c0, name) for c0, c1 in zip(clips, clips[1:], strict=False)]
        finite = [r for r in rois if math.isfinite(r)]
        gated = raw_similarity(b.acquire_gated(clips[0]), clips[0])
        saved_dct[name] = b.dct_pose()
        ceiling[name] = (
            float(np.mean(sims)),
            float(np.mean(finite)) if finite else math.nan,
            gated,
        )
    b.explore(cfg.wander_moves, cfg.rest_force_n)
    b.contact_peak()

    samples: list[ReturnSample] = []
    for mode in cfg.modes:
        for _ in range(cfg.rounds):
            for name in TARGETS:
                samples.append(
                    _one_return(b, cfg, mode, views[name], saved_em, saved_clip, refine_refs)
                )
    records = []
    for mode in cfg.modes:
        for name in TARGETS:
            rs = [s for s in samples if s.target == name and s.mode == mode]
            records.append(
                make_record(
                    cfg,
                    name,
                    mode,
                    rs,
                    saved_pose[name],
                    saved_dct[name],
                    saved_clip[name],
                    ceiling[name],
                    saved_static[name],
                )  # fmt: skip
            )
    return RecoveryRun(
        cfg,
        tuple(records),
        tuple(samples),
        views,
        saved_pose,
        saved_clip,
        saved_em,
        time.perf_counter() - t_wall,
        saved_dct,
        saved_static,
    )


def _one_return(
    b: Bench,
    cfg: RecoveryConfig,
    mode: str,
    view: View,
    saved_em: dict[str, Array],
    saved_clip: dict[str, BeatClip],
    refine_refs: dict[str, list[BeatClip]],
) -> ReturnSample:
    """Return to ``view`` (and refine it in the refined mode); measure the result."""
    name = view.name
    b.go(view)
    extra: dict[str, Any] = {
        "force_margin_use": b.last_force_margin_use,
        "force_margin_needed_n": b.last_force_margin_needed_n,
        "return_stopped": b.last_stop,
    }
    if mode == "refined" and b.last_stop is None:
        q_centre = np.asarray(view.q, np.float64)
        cycle = b.cycle_sensor
        if cfg.refine_strategy == "retry" and cycle is not None and name in saved_em:
            t0 = b.clock.now()

            def measure() -> Array | None:
                b.hold_still(b.cycle_window_s + 0.05)
                return cycle.measure_tip2base()

            rr = retry_return(saved_em[name], measure, lambda: b.go(view), config=cfg.retry)
            extra.update(
                pose_stage_tip2base=b.true_pose(),
                pose_stage_status=f"retry x{rr.moves}",
                pose_stage_measurements=len(rr.errors_mm),
                pose_stage_s=b.clock.now() - t0,
                pose_stage_trace=tuple(zip(rr.position_mm, rr.rotation_deg, strict=True)),
                pose_stage_undone=rr.ended_worse,
            )
        elif cfg.pose_stage is not None and name in saved_em:
            sensor: Any = b.tracker
            ps_cfg = cfg.pose_stage
            if b.refine_sensor is not None:
                sensor = b.refine_sensor
                ps_cfg = cycle_stage_config(cfg, sensor.window_s)
            ps = pose_stage(
                b.robot,
                view.q,
                saved_em[name],
                sensor,
                arrival_direction=view.arrival_direction,
                start_direction=tuple(int(d) for d in b.last_direction),
                config=ps_cfg,
                expiration=b.expiration,
                dt=DT,
                sleep=b.clock.advance,
                on_command=b.record,
            )
            q_centre = ps.q_final
            extra.update(
                pose_stage_tip2base=b.true_pose(),
                pose_stage_status=ps.status.value,
                pose_stage_measurements=len(ps.measurements),
                pose_stage_s=ps.duration_s,
                pose_stage_trace=tuple(
                    (m.position_mm, math.degrees(m.rotation_rad)) for m in ps.measurements
                ),
                pose_stage_undone=ps.undone,
            )
        if cfg.image_stage or b.cycle_sensor is None or "pose_stage_status" not in extra:
            extra.update(_image_stage(b, cfg, view, q_centre, refine_refs[name]))
        b.clock.advance(0.2)
    b.hold_still(b.cycle_window_s)
    em = b.tracker.measure_tip2base(n_average=cfg.em_average)
    true = b.true_pose()
    static = b.static_pose()
    clip = b.acquire()
    gated = b.acquire_gated(saved_clip[name])
    return ReturnSample(
        name,
        mode,
        np.asarray(b.robot.read_state().q, np.float64),
        true,
        None if em is None else np.asarray(em, np.float64),
        clip,
        gated_clip=gated,
        dct_tip2base=b.dct_pose(),
        max_contact_force_n=b.contact_peak(),
        static_tip2base=static,
        **extra,
    )


def _image_stage(
    b: Bench, cfg: RecoveryConfig, view: View, q_centre: Array, refs: list[BeatClip]
) -> dict[str, Any]:
    """The image stage centred at ``q_centre``; what it did."""
    imager: Any = b.refine_imager
    if cfg.image_stage_gated:
        imager = GatedBeatImager(b.refine_imager, b.respiration, refs[0], cfg.gate_window_beats)
    res = refine(
        b.robot,
        q_centre,
        refs,
        imager,
        arrival_direction=view.arrival_direction,
        config=cfg.refinement,
        dt=DT,
        sleep=b.clock.advance,
        on_command=b.record,
    )
    return {
        "refine_evaluations": len(res.trials),
        "refine_moved": res.n_commands > 0,
        "refine_s": res.duration_s,
        "refine_trace": tuple(t.score for t in res.trials),
    }


# --- CLI ------------------------------------------------------------------------------------


def _seeds(text: str) -> list[int]:
    """'110' or '110-119' or '110,112' -> seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        a = int(lo)
        out += list(range(a, int(hi) + 1)) if hi else [a]
    if not out or min(out) < 0:
        raise argparse.ArgumentTypeError(f"seeds must be >= 0, got {text!r}")
    return out


def _rest_force(text: str) -> float | None:
    """``--rest-force``: a force limit (N, > 0) or ``none``."""
    if text.strip().lower() == "none":
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be a force > 0 N or 'none', got {text!r}")
    return value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav eval recovery",
        description="The paper's view-recovery experiment (Table II) on the digital twin, "
        "open loop and with closed-loop refinement, on today's twin or under the phantom / "
        "in-vivo disturbances.",
    )
    p.add_argument(
        "--seed", type=_seeds, default=[100],
        help="catheter seed(s): N, A-B or A,B (0-9 tuned the twin; 110-119 held out)",
    )  # fmt: skip
    p.add_argument("--vessel", choices=("straight", "moderate", "steep"), default="moderate")
    p.add_argument(
        "--condition", choices=sorted(CONDITIONS), default="none",
        help="disturbances: none (today's twin), phantom (bench), in-vivo (animal)",
    )  # fmt: skip
    p.add_argument(
        "--patient", type=_seeds, default=[0],
        help="patient seed(s), paired with the catheter seeds (0-4 tuned; 100-109 held out)",
    )  # fmt: skip
    p.add_argument(
        "--disable", action="append", default=[], choices=DISTURBANCES,
        help="switch a disturbance of the condition off (repeatable)",
    )  # fmt: skip
    p.add_argument(
        "--plant", metavar="MODULE:FACTORY",
        help="plant plug-in (or family name) whose factory takes clock= (docs/digital-twin.md)",
    )  # fmt: skip
    p.add_argument("--rounds", type=int, default=16, help="returns per target and mode")
    p.add_argument(
        "--rest-force", type=_rest_force, default=REST_FORCE_N, metavar="N|none",
        help="the operator backs off after an exploration move until the contact force at "
        f"rest is below this (N; default {REST_FORCE_N}: 40 g, what counts as excessive for "
        "a catheter on a wall); none: the blind operator of session 8",
    )  # fmt: skip
    p.add_argument("--json", type=Path, help="write the records (a JSON list) to this file")
    p.add_argument("--plots", type=Path, help="write recovery_*.png here (first run)")
    p.add_argument("--open-loop-only", action="store_true", help="skip the refined mode (faster)")
    p.add_argument(
        "--no-em", action="store_true", help="refine from the images alone (no EM pose stage)"
    )
    p.add_argument(
        "--quick", action="store_true", help="2 rounds, 6 frames per beat, small budgets (tests)"
    )
    p.add_argument(
        "--engine", choices=("local", "ray"), default="local",
        help="where the runs go: this process (default) or Ray (pip install 'icenav[cluster]'; "
        "one CPU a run); a progress bar counts them",
    )  # fmt: skip
    p.add_argument(
        "--address", default=None,
        help="with --engine ray: the address of an existing Ray cluster (default: start a "
        "local one for this run)",
    )  # fmt: skip
    return p


def config_from_args(args: argparse.Namespace, seed: int | None = None,
                     patient: int | None = None) -> RecoveryConfig:  # fmt: skip
    """The run's settings from parsed CLI arguments (for one catheter and patient)."""
    cfg = RecoveryConfig(
        seed=args.seed[0] if seed is None else seed,
        vessel=args.vessel,
        rounds=args.rounds,
        condition=args.condition,
        patient=args.patient[0] if patient is None else patient,
        disable=tuple(args.disable),
        plant=args.plant,
        rest_force_n=args.rest_force,
    )
    if args.quick:
        cfg = replace(
            cfg,
            rounds=min(args.rounds, 2),
            frames_per_beat=6,
            n_beams=48,
            n_samples=128,
            wander_moves=3,
            ceiling_beats=1,
            refinement=replace(cfg.refinement, max_evaluations=6),
            cycle_rate_hz=5.0,
        )
    if args.open_loop_only:
        cfg = replace(cfg, modes=("open_loop",))
    if args.no_em:
        cfg = replace(cfg, pose_stage=None)
    return cfg


def _pairs(args: argparse.Namespace) -> list[tuple[int, int]]:
    seeds, patients = args.seed, args.patient
    if len(patients) == 1:
        patients = patients * len(seeds)
    if len(patients) != len(seeds):
        raise ConfigurationError(
            f"--patient gives {len(patients)} seeds for {len(seeds)} catheters; give one, or "
            "as many as catheters (they are paired in order)"
        )
    return list(zip(seeds, patients, strict=True))


def _run_pair(pair: tuple[int, int], args: argparse.Namespace) -> RecoveryRun:
    """One (catheter, patient) run for the engine (module level: picklable)."""
    return run_recovery(config_from_args(args, *pair))


def main(argv: Sequence[str] | None = None) -> int:
    """``icenav eval recovery [--seed N] [--condition C --patient P] [--rounds 16] ...``."""
    args = _parser().parse_args(list(argv or []))
    if args.rounds < 2:
        print("icenav eval recovery: --rounds must be >= 2", file=sys.stderr)
        return 2
    try:
        pairs = _pairs(args)
    except ConfigurationError as exc:
        print(f"icenav eval recovery: {exc}", file=sys.stderr)
        return 2
    if args.address is not None and args.engine != "ray":
        print("icenav eval recovery: --address needs --engine ray", file=sys.stderr)
        return 2
    from icenav.eval.engine import run_jobs

    try:
        runs = run_jobs(
            _run_pair, pairs, engine=args.engine, address=args.address, kwargs={"args": args},
            describe=lambda p: f"catheter {p[0]}, patient {p[1]}", desc="runs",
        )  # fmt: skip
    except IcenavError as exc:  # a run failed (named), or Ray cannot start
        print(f"icenav eval recovery: {exc}", file=sys.stderr)
        return 1
    all_records: list[RecoveryRecord] = []
    total = 0.0
    for i, ((_, patient), run) in enumerate(zip(pairs, runs, strict=True)):
        cfg = run.config
        total += run.seconds
        where = "" if cfg.condition == "none" else f", condition {cfg.condition}, patient {patient}"
        off = f" (without {', '.join(cfg.disable)})" if cfg.disable else ""
        print(
            f"view recovery on the twin: catheter seed {cfg.seed}, vessel {cfg.vessel}{where}"
            f"{off}, {cfg.rounds} rounds x {len(TARGETS)} targets per mode, images "
            f"{cfg.image_size} px, {cfg.frames_per_beat} frames per beat ({run.seconds:.1f} s)"
        )
        print(format_table(run.records))
        all_records += run.records
        if args.plots is not None and i == 0:
            from icenav.eval.recovery_plots import plot_images, plot_spread, plot_traces

            args.plots.mkdir(parents=True, exist_ok=True)
            for path in (
                plot_images(run, args.plots / "recovery_images.png"),
                plot_spread(run, args.plots / "recovery_spread.png"),
                plot_traces(run, args.plots / "recovery_refinement_traces.png"),
            ):
                print(f"wrote {path}")
    if len(pairs) > 1:
        print(f"\nmean over {len(pairs)} runs (catheter, patient): {pairs}")
        print(summary_table(all_records))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([record_json(r) for r in all_records], indent=1) + "\n")
        print(f"wrote {args.json}")
    print(f"total {total:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

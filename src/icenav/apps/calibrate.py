"""``icenav calibrate``: a calibration file from a recorded CSV (docs/calibration.md).

::

    icenav calibrate --from-csv REC.csv --out CAL.json
                     [--kind auto|dense|five_point|dense+hysteresis]
                     [--registration FILE | --tracker-config FILE] [--joint-tol 0.001]
                     [--skip-bad-rows] [--catheter-id ID]
    icenav calibrate --record-twin REC.csv [--kind ...] [--seed N] [--vessel V]

The recording (columns in :mod:`icenav.apps.calibration_csv`) is replayed to the control
core's calibration procedures (``make_procedure(kind)``, run by ``run_procedure``, then
``fit``): each kind whose states the recording contains (at least 90 % of them) is fitted
and its quality printed; ``auto`` tries them all. The registration (tracker to robot base)
is given (``--registration``: a calibration file that has one, a session file, or a
registration JSON) or estimated from the recording's registration states (the straight
catheter translated and rolled) with the sensor mount of ``--tracker-config``. The file
written (:class:`icenav.calibration.files.CalibrationFile`, version 3) holds the best kind
found (dense+hysteresis, else the dense raster, else the five points): its tracked samples,
its fitted model (the per-tendon / hysteresis knob map, or F) and the registration; ``icenav
demo|serve|run --calibration CAL.json`` and ``icenav eval spin --calibration`` install that
model. ``--record-twin`` writes such a recording
from the twin (the registration states first, then the kind's).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icenav.errors import FileFormatError, IcenavError, RegistrationError

__all__ = ["COVERAGE", "KINDS", "load_registration", "main", "replay_kind"]

KINDS = ("dense", "five_point", "dense+hysteresis")
"""Calibration kinds fitted from a recording (``auto`` tries each)."""
COVERAGE = 0.9
"""Share of a kind's states the recording must contain for the kind to be fitted."""
FIVE_POINT_TOL_MM = 5.0
"""Default of ``--five-point-tol-mm``: a recorded state stands for a 5-point target when its
tracked tip is this close in (x, y) (mm). The 5-point procedure's own search stops at 1 mm
but keeps its best state when it gets no closer in 8 steps (6 mm off on catheter 52), and
F only needs five well-spread tracked pairs, not exact targets."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav calibrate",
        description="Fit the calibrations a recorded CSV of joint states and tracked sensor "
        "poses contains (dense raster, 5-point, dense+hysteresis) and write a calibration "
        "file; or record such a CSV from the twin.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--from-csv", type=Path, metavar="FILE", help="the recording to fit")
    src.add_argument(
        "--record-twin",
        type=Path,
        metavar="FILE",
        help="write a recording from the twin instead (registration states, then --kind's)",
    )
    p.add_argument("--out", type=Path, metavar="CAL.json", help="the calibration file to write")
    p.add_argument(
        "--kind",
        choices=("auto", *KINDS),
        default="auto",
        help="which calibration to fit (auto: every kind the recording contains; with "
        "--record-twin: which to record, auto = dense)",
    )
    reg = p.add_mutually_exclusive_group()
    reg.add_argument(
        "--registration",
        type=Path,
        metavar="FILE",
        help="the registration: a calibration file with one, a session (.sqlite), or a "
        "registration JSON (Registration.to_dict)",
    )
    reg.add_argument(
        "--tracker-config",
        type=Path,
        metavar="FILE",
        help="estimate the registration from the recording with this tracker TOML's sensor "
        "mount ([mount] sensor2tip)",
    )
    p.add_argument(
        "--joint-tol",
        type=float,
        default=1e-3,
        help="how close (rad, mm) a recorded joint state must be to a procedure's state "
        "(default 0.001; (0, 0.1])",
    )
    p.add_argument(
        "--five-point-tol-mm",
        type=float,
        default=FIVE_POINT_TOL_MM,
        help="a recording that is not icenav's 5-point search: a state stands for a target "
        f"when its tracked tip is this close in (x, y) (default {FIVE_POINT_TOL_MM:g} mm; "
        "(0, 20])",
    )
    p.add_argument(
        "--skip-bad-rows",
        action="store_true",
        help="leave bad rows out (listed) instead of refusing the file",
    )
    p.add_argument("--catheter-id", default="", help="the catheter's serial number (kept)")
    p.add_argument("--seed", type=int, default=100, help="--record-twin: catheter seed (>= 0)")
    p.add_argument(
        "--vessel",
        choices=("straight", "moderate", "steep"),
        default="straight",
        help="--record-twin: vessel",
    )
    return p


def _check(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    if args.from_csv is not None:
        if args.out is None:
            parser.error("--from-csv needs --out CAL.json")
        if not args.from_csv.is_file():
            parser.error(f"--from-csv {args.from_csv}: no such file")
        if args.out.exists() and args.out.is_dir():
            parser.error(f"--out {args.out} is a directory")
    for opt in ("registration", "tracker_config"):
        path = getattr(args, opt)
        if path is not None and not path.is_file():
            parser.error(f"--{opt.replace('_', '-')} {path}: no such file")
    if not (math.isfinite(args.joint_tol) and 0 < args.joint_tol <= 0.1):
        parser.error(f"--joint-tol must be in (0, 0.1] rad or mm, got {args.joint_tol}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0 (an integer), got {args.seed}")
    tol = args.five_point_tol_mm
    if not (math.isfinite(tol) and 0 < tol <= 20):
        parser.error(f"--five-point-tol-mm must be in (0, 20] mm, got {tol}")


def load_registration(path: Path) -> Any:
    """The :class:`~icenav.devices.registration.Registration` in a session (SQLite), a
    calibration file, or a registration JSON; FileFormatError / RegistrationError naming the
    file when it holds none."""
    from icenav.devices.registration import Registration

    with path.open("rb") as fh:
        head = fh.read(16)
    if head.startswith(b"SQLite format 3"):
        from icenav.persistence.store import SessionStore

        with SessionStore(path, read_only=True) as store:
            reg = store.registration()
        if reg is None:
            raise RegistrationError(f"{path}: the session holds no registration")
        return reg
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{path}: neither a session nor a JSON file: {exc}") from exc
    if isinstance(doc, dict) and "tracker2base" in doc:
        return Registration.from_dict(doc, str(path))
    if isinstance(doc, dict) and "registration" in doc:
        return Registration.from_dict(doc["registration"], f"{path}: registration")
    raise RegistrationError(f"{path}: holds no registration (no 'registration' or 'tracker2base')")


def replay_kind(kind: str, samples: Any, registration: Any, joint_tol: float, **kw: Any) -> Any:
    """Replay ``samples`` to ``make_procedure(kind)``: ``(procedure, recording, replay)``.
    The states are looked up in the recording's order; for the dense raster and the
    registration (static states whose fits ignore the order) in any order when the ordered
    replay finds too few."""
    from icenav.apps.calibration_csv import ReplayTracker
    from icenav.calibration.procedure import run_procedure
    from icenav.calibration.procedures import make_procedure

    procedure = make_procedure(kind, **kw)
    replay = ReplayTracker(samples, joint_tol, registration)
    recording = run_procedure(procedure, replay.move, replay)
    if kind in ("dense", "registration") and replay.found < COVERAGE * replay.asked:
        replay = ReplayTracker(samples, joint_tol, registration, ordered=False)
        recording = run_procedure(procedure, replay.move, replay)
    return procedure, recording, replay


def five_point_reached(
    replay: Any, registration: Any, joint_tol: float, tol_mm: float = FIVE_POINT_TOL_MM
) -> tuple[Any, str]:
    """The paper's 5-point calibration from any recording: for each of the five target tips
    (:func:`icenav.calibration.plans.five_point_targets`) the recorded state, knobs only
    (roll and translation at zero), whose tracked tip comes closest in (x, y), kept when
    within ``tol_mm`` (an operator who drove to the targets with the joystick recorded
    them). Returns the :class:`~icenav.calibration.plans.Recording` of the five (None
    when fewer than 3 were reached) and what was found, for the operator."""
    from icenav.calibration.plans import MotionPlan, Recording, five_point_targets

    q, sensor = replay.visits()
    knobs_only = np.all(np.abs(q[:, 2:]) <= joint_tol, axis=1) & np.all(
        np.isfinite(sensor[:, 0, 0])
    )
    _, targets = five_point_targets()
    q5 = np.zeros((5, 4))  # the states that reached each target (zeros: not reached)
    poses = np.full((5, 4, 4), np.nan)
    notes = []
    if np.any(knobs_only):
        idx = np.flatnonzero(knobs_only)
        tips = np.array([registration.tip2base(sensor[k]) for k in idx])
        for i, xy in enumerate(targets):
            d = np.linalg.norm(tips[:, :2, 3] - xy, axis=1)
            j = int(np.argmin(d))
            notes.append(f"{d[j]:.1f}")
            if d[j] <= tol_mm:
                q5[i] = q[idx[j]]
                poses[i] = tips[j]
    reached = int(np.sum(np.isfinite(poses[:, 0, 0])))
    text = (
        f"{reached} of 5 targets reached within {tol_mm:g} mm (nearest tips "
        f"{', '.join(notes) or 'none'} mm)"
    )
    if reached < 3:
        return None, text
    plan = MotionPlan.make(q5, "five-point", n_average=1, retries=0)
    return Recording(plan=plan, tip2base=poses, attempts=np.ones(5, dtype=np.int64)), text


def _estimate_registration(samples: Any, tracker_config: Path, joint_tol: float) -> Any:
    from icenav.apps.hardware import load_tracker_config

    mount = load_tracker_config(tracker_config).sensor2tip
    if mount is None:
        raise RegistrationError(
            f"{tracker_config}: [mount] sensor2tip is needed to estimate the registration"
        )
    procedure, recording, replay = replay_kind(
        "registration", samples, None, joint_tol, sensor2tip=mount
    )
    if replay.found < COVERAGE * replay.asked:
        raise RegistrationError(
            f"the recording holds {replay.found} of the {replay.asked} registration states "
            "(the straight catheter translated and rolled); record them, or give "
            "--registration FILE"
        )
    reg = procedure.fit(recording).details
    print(
        f"registration: estimated from {reg.n_points} states, residual "
        f"{reg.rms_residual_mm:.2f} mm RMS (max {reg.max_residual_mm:.2f} mm)"
    )
    return reg


def _fit_from_csv(args: argparse.Namespace) -> int:
    from icenav.apps.calibration_csv import read_calibration_csv
    from icenav.calibration.files import CalibrationFile

    samples = read_calibration_csv(args.from_csv, skip_bad_rows=args.skip_bad_rows)
    for s in samples.skipped:
        print(f"skipped {s}", file=sys.stderr)
    print(f"{args.from_csv}: {samples.n} rows, {int(samples.valid.sum())} valid")
    if args.registration is not None:
        registration = load_registration(args.registration)
        print(f"registration: from {args.registration}")
    elif args.tracker_config is not None:
        registration = _estimate_registration(samples, args.tracker_config, args.joint_tol)
    else:
        raise RegistrationError(
            "the sensor poses are in the tracker frame: give --registration FILE, or "
            "--tracker-config FILE (the sensor mount) to estimate it from the recording"
        )
    kinds = KINDS if args.kind == "auto" else (args.kind,)
    fitted: dict[str, Any] = {}
    for kind in kinds:
        procedure, recording, replay = replay_kind(kind, samples, registration, args.joint_tol)
        share = replay.found / max(replay.asked, 1)
        if share < COVERAGE and kind == "five_point":
            recording, text = five_point_reached(
                replay, registration, args.joint_tol, args.five_point_tol_mm
            )
            print(f"five_point: not icenav's search; {text}")
            if recording is not None:
                fitted[kind] = outcome = procedure.fit(recording)
                print(f"five_point: {outcome.quality.describe()}")
            continue
        if share < COVERAGE:
            print(
                f"{kind}: not in the recording ({replay.found} of {replay.asked} states found, "
                f"{COVERAGE:.0%} needed)"
            )
            continue
        outcome = procedure.fit(recording)
        fitted[kind] = outcome
        print(f"{kind}: {replay.found} of {replay.asked} states; {outcome.quality.describe()}")
    if not fitted:
        raise FileFormatError(
            f"{args.from_csv}: contains none of the calibrations {', '.join(kinds)} "
            f"(see above; --joint-tol {args.joint_tol:g} rad or mm)"
        )
    best = next(k for k in ("dense+hysteresis", "dense", "five_point") if k in fitted)
    out = CalibrationFile.from_outcome(
        fitted[best], registration, catheter_id=args.catheter_id, notes=f"icenav calibrate: {best}"
    )
    out.save(args.out)
    print(
        f"wrote {args.out}: {best} calibration ({out.calibration.n_samples} samples, the fitted "
        "model) with the registration"
    )
    return 0


def _record_twin(args: argparse.Namespace) -> int:
    from icenav.apps.calibration_csv import RecordingTracker
    from icenav.calibration.procedure import run_procedure
    from icenav.calibration.procedures import make_procedure
    from icenav.sim import CatheterPlant, EMTracker

    plant = CatheterPlant(seed=args.seed, vessel=args.vessel)
    t = [0.0]
    tracker = EMTracker(plant, seed=args.seed, clock=lambda: t[0])
    tracker.start()
    kind = "dense" if args.kind == "auto" else args.kind
    with args.record_twin.open("w", encoding="utf-8", newline="") as out:
        out.write(f"# icenav calibrate --record-twin: seed {args.seed}, {args.vessel} vessel\n")
        rec = RecordingTracker(tracker, out, clock=lambda: t[0])

        def move(q: Any) -> None:
            plant.move(q)
            rec.move(q)
            t[0] += 0.5  # the robot's move and the settling, in simulated time

        mount = np.asarray(tracker.config.sensor2tip)
        for k in ("registration", kind):
            run_procedure(make_procedure(k, sensor2tip=mount), move, rec)
    print(f"wrote {args.record_twin}: {rec.rows} rows (registration, {kind})")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    _check(args, parser)
    try:
        return _record_twin(args) if args.record_twin is not None else _fit_from_csv(args)
    except IcenavError as exc:
        print(f"icenav calibrate: {exc}", file=sys.stderr)
        return 1

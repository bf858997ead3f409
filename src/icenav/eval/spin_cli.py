"""``icenav eval spin``'s command line: parse the options, run the catheters, print and write.

The experiment itself (calibrations, conditions, the spin of one catheter) is
:mod:`icenav.eval.spin`; the tables and plots are :mod:`icenav.eval.spin_report`. This module
turns ``--seeds``, ``--jobs``, ``--engine``, ``--vessel``, ... into calls of
:func:`icenav.eval.spin.evaluate_catheter` on an engine (:mod:`icenav.eval.engine`) and
prints the tables.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from icenav.calibration.files import CalibrationFile
from icenav.errors import ConfigurationError, IcenavError, InvalidValueError, JobError
from icenav.eval.spin import (
    ALL_CONDITIONS,
    CONDITIONS,
    FILE,
    CatheterRun,
    SpinRecord,
    evaluate_catheter,
)
from icenav.eval.spin_report import (
    format_family_matrix,
    format_table,
    format_vessel_effect,
    plot_commands,
    plot_curvature,
    plot_tip,
)
from icenav.geometry.kinematics import forward
from icenav.sim.families import FAMILIES, family
from icenav.sim.plugins import load_factory

__all__ = ["main", "parse_seeds"]


def parse_seeds(text: str) -> list[int]:
    """Catheter seeds from ``"110"``, ``"110-119"`` or ``"110,112,115-116"`` (sorted,
    unique). Raises ValueError naming the bad part."""
    seeds: set[int] = set()
    for part in (p.strip() for p in str(text).split(",")):
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a, b = (int(lo), int(hi)) if sep else (int(part), int(part))
        except ValueError:
            raise InvalidValueError(
                f"seeds must be integers or ranges like 110-119, got {part!r}"
            ) from None
        if a < 0 or b < a:
            raise InvalidValueError(f"seed range must be ascending and >= 0, got {part!r}")
        seeds.update(range(a, b + 1))
    if not seeds:
        raise InvalidValueError(f"no seed in {text!r}")
    return sorted(seeds)


Job = tuple[str | None, int]
"""One catheter of the run: (plant spec or None for the default twin, seed)."""


def _evaluate(job: Job, *, first: Job, **kwargs: Any) -> CatheterRun:
    """One catheter for the engine (a module-level function: picklable). The plant is
    passed by its spec (a family name or ``MODULE:FACTORY``), resolved in the worker."""
    plant, seed = job
    return evaluate_catheter(seed, keep=job == first, plant=plant, **kwargs)


def _job_name(job: Job) -> str:
    plant, seed = job
    return f"catheter {seed}" + ("" if plant is None else f" of {plant}")


def _run_catheters(
    jobs_to_run: Sequence[Job],
    jobs: int,
    *,
    engine: str = "local",
    address: str | None = None,
    **kwargs: Any,
) -> list[CatheterRun]:
    """:func:`evaluate_catheter` for each seed on an engine (:mod:`icenav.eval.engine`: the
    local process pool, ``jobs`` at a time, or Ray), printing each catheter as it finishes;
    the runs come back in the order of ``jobs_to_run``."""
    from tqdm import tqdm

    from icenav.eval.engine import run_jobs

    t0 = time.perf_counter()
    done = 0

    def report(job: Job, run: CatheterRun) -> None:
        nonlocal done
        done += 1
        for line in run.calibration_text:
            tqdm.write(line)
        tqdm.write(
            f"  {_job_name(job)} done in {run.seconds:.0f} s "
            f"({done}/{len(jobs_to_run)} catheters, {time.perf_counter() - t0:.0f} s elapsed)"
        )

    runs: list[CatheterRun] = run_jobs(
        _evaluate,
        list(jobs_to_run),
        engine=engine,
        jobs=jobs,
        address=address,
        kwargs={"first": jobs_to_run[0], **kwargs},
        on_result=report,
        describe=_job_name,
        desc="catheters",
    )
    return runs


def _write_plots(
    out: Path, runs: Sequence[CatheterRun], records: Sequence[SpinRecord], vessel: str
) -> None:
    """Fig. 5 (commands) and the true tip of the first catheter in ``vessel``; Fig. 7
    (curvature) from every record."""
    out.mkdir(parents=True, exist_ok=True)
    first = runs[0]
    if not first.commands:
        return
    bend = max(k[1] for k in first.commands)
    path = out / f"spin_commands_{bend}deg.png"
    plot_commands({k[1:]: v for k, v in first.commands.items() if k[0] == vessel}, bend, path)
    print(f"wrote {path} (catheter {first.seed}, {vessel} vessel)")
    tips = {k[2]: v for k, v in first.tips.items() if k[0] == vessel and k[1] == bend}
    path = out / f"spin_tip_{vessel}_{bend}deg.png"
    plot_tip(tips, forward(np.array([math.radians(bend), 0, 0, 0]))[:3, 3], bend, path)
    print(f"wrote {path}")
    for p in plot_curvature(records, out):
        print(f"wrote {p}")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="icenav eval spin",
        description="The paper's image-spinning experiment (Table I, Figs. 5 and 7) on the "
        "digital twin: calibrate each catheter in the straight vessel, spin in the test "
        "vessels.",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=100,
        help="catheter seed (calibrated and tested); seeds 0-9 tuned the twin",
    )
    p.add_argument(
        "--seeds",
        help="many catheters instead of --seed, e.g. 110-119 or 110,112: the tables give the "
        "mean and the worst catheter",
    )
    p.add_argument(
        "--vessel",
        default="straight",
        help="test vessel(s): straight, moderate, steep, comma-separated or 'all' (calibration "
        "is always in the straight vessel; default straight)",
    )
    p.add_argument(
        "--jobs", type=int, default=1, help="catheters evaluated in parallel (processes)"
    )
    p.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help="where the catheters run: the local process pool (default, --jobs at a time) "
        "or Ray (pip install 'icenav[cluster]'; one CPU a catheter)",
    )
    p.add_argument(
        "--address",
        default=None,
        help="with --engine ray: the address of an existing Ray cluster (default: start a "
        "local one for this run)",
    )
    p.add_argument("--json", type=Path, help="write the records (a JSON list) to this file")
    p.add_argument(
        "--plots",
        type=Path,
        help="write spin_commands_*.png and spin_tip_*.png (Fig. 5) and curvature_*.png "
        "(Fig. 7; with one --vessel the other two are run for it) here",
    )
    p.add_argument("--samples", type=int, default=360, help="samples per spin (default 360)")
    p.add_argument("--bends", default="20,40,60", help="initial AP bends in deg (default 20,40,60)")
    p.add_argument(
        "--conditions",
        default=",".join(CONDITIONS),
        help="comma-separated subset of " + ", ".join(ALL_CONDITIONS) + " (default: all)",
    )
    p.add_argument(
        "--in-situ",
        action="store_true",
        help="re-identify dense+hysteresis's plays in a curved test vessel before the spin "
        "(needs the tip sensor in the vessel; the default is the paper's protocol: "
        "calibrated in the straight vessel only)",
    )
    p.add_argument(
        "--study", action="store_true", help="also print the calibration-size / interpolant study"
    )
    p.add_argument(
        "--costs",
        action="store_true",
        help="print the robot time and moves of each calibration at the controller's speeds "
        "and exit",
    )
    p.add_argument(
        "--calibration",
        type=Path,
        metavar="CAL.json",
        help="also spin with this calibration file's compensation, as the console installs "
        "it (condition 'file': the fitted model of a version 3 file, F built on the samples "
        "of an older one; 'icenav calibrate' or 'icenav export-calibration' write it); with "
        "--seed, the catheter it was recorded on",
    )
    plant = p.add_mutually_exclusive_group()
    plant.add_argument(
        "--plant",
        metavar="MODULE:FACTORY",
        help="run on a plant plug-in: an importable module or a .py file and a factory "
        "(seed, vessel) -> (plant, tracker) (docs/digital-twin.md, 'Plant plug-ins')",
    )
    plant.add_argument(
        "--plant-family",
        metavar="NAME|all",
        help="run on plant families (comma-separated names, PLANT+TRACKER, or 'all': "
        + ", ".join(FAMILIES)
        + "); prints a table per family and the family x condition x bend matrix",
    )
    return p


def _plants(plant: str | None, plant_family: str | None) -> list[str | None]:
    """The plant specs of the run (None: the default twin), each checked here, before any
    catheter runs (PluginError / ConfigurationError naming the bad one)."""
    if plant is not None:
        load_factory(plant)
        return [plant]
    if plant_family is None:
        return [None]
    names = (
        list(FAMILIES)
        if plant_family.strip() == "all"
        else [n.strip() for n in plant_family.split(",") if n.strip()]
    )
    if not names:
        raise ConfigurationError(f"--plant-family names no family: {plant_family!r}")
    for name in names:
        family(name)
    return list(dict.fromkeys(names))


def _fail(text: str) -> int:
    print(f"icenav eval spin: {text}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """``icenav eval spin [--seed N | --seeds A-B] [--vessel V[,V]] [--plant MODULE:FACTORY |
    --plant-family NAME|all] [--json F] [--plots D]``."""
    args = _parser().parse_args(list(argv or []))
    if args.costs:
        from icenav.eval.spin_cost import (
            calibration_costs,
            format_costs,
            short_calibration_cost,
        )

        print(
            format_costs(
                [
                    *calibration_costs(),
                    short_calibration_cost(),
                    short_calibration_cost(rings=True),
                    short_calibration_cost(rings=True, bias_circle=True),
                ]
            )
        )
        return 0
    try:
        bends = [int(b) for b in args.bends.split(",") if b.strip()]
    except ValueError:
        return _fail(f"--bends must be integers in deg, got {args.bends!r}")
    conds = [c.strip() for c in args.conditions.split(",") if c.strip()]
    bad = [c for c in conds if c not in ALL_CONDITIONS]
    if bad or not conds:
        return _fail(f"unknown condition(s) {bad}; choose from {ALL_CONDITIONS}")
    if not bends or any(not (0 < b <= 90) for b in bends):
        return _fail(f"--bends must be in (0, 90] deg, got {args.bends!r}")
    if args.samples < 10:
        return _fail(f"--samples must be >= 10, got {args.samples}")
    vessel_names = ("straight", "moderate", "steep")
    vessels = (
        list(vessel_names)
        if args.vessel.strip() == "all"
        else [v.strip() for v in args.vessel.split(",") if v.strip()]
    )
    if not vessels or any(v not in vessel_names for v in vessels):
        return _fail(f"--vessel must be among {vessel_names} or 'all', got {args.vessel!r}")
    vessels = [v for v in vessel_names if v in vessels]
    try:
        seeds = parse_seeds(args.seeds) if args.seeds is not None else [args.seed]
    except ValueError as exc:
        return _fail(f"--seeds: {exc}")
    if args.seeds is None and args.seed < 0:
        return _fail(f"--seed must be >= 0, got {args.seed}")
    if not 1 <= args.jobs <= 64:
        return _fail(f"--jobs must be in [1, 64] processes, got {args.jobs}")
    try:
        plants = _plants(args.plant, args.plant_family)
    except ConfigurationError as exc:
        return _fail(str(exc))
    calibration_file = None
    if args.calibration is not None:
        if args.seeds is not None or len(plants) > 1:
            return _fail(
                "--calibration is one catheter's: give the catheter it was recorded on with "
                "--seed N (and one plant at most), not --seeds or several families"
            )
        try:  # read it here, so a bad file is named before anything runs
            CalibrationFile.load(args.calibration)
        except IcenavError as exc:
            return _fail(f"--calibration {args.calibration}: {exc}")
        calibration_file = str(args.calibration)
        conds = [*conds, FILE]
    t0 = time.perf_counter()
    run_vessels = vessels
    if args.plots is not None and len(vessels) == 1:
        run_vessels = list(vessel_names)  # Fig. 7 needs every vessel; the table keeps one
    print(
        f"icenav eval spin: {len(seeds)} catheter(s)"
        + ("" if plants == [None] else f" of {', '.join(map(str, plants))}")
        + f", vessels {', '.join(run_vessels)}"
        + (" (the others for the curvature figure only)" if run_vessels != vessels else "")
        + f", bends {bends} deg, {len(conds)} condition(s), {args.samples} samples per spin"
    )
    try:
        runs = _run_catheters(
            [(plant, seed) for plant in plants for seed in seeds],
            args.jobs,
            engine=args.engine,
            address=args.address,
            vessels=run_vessels,
            bends_deg=bends,
            n_samples=args.samples,
            conditions=conds,
            in_situ=args.in_situ,
            calibration_file=calibration_file,
        )
    except (ConfigurationError, JobError) as exc:
        return _fail(str(exc))
    all_records = [r for run in runs for r in run.records]
    records = [r for r in all_records if r.vessel in vessels]
    print("\nspin RMSE (EM-tracked, the paper's protocol; the paper's Table I in parentheses)")
    for name in dict.fromkeys(r.plant for r in records):
        if plants != [None]:
            print(f"\nplant {name}")
        print(format_table([r for r in records if r.plant == name]))
    if len(plants) > 1:
        print("\n" + format_family_matrix(records))
    effect = format_vessel_effect(records)
    if effect:
        print("\n" + effect)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([asdict(r) for r in records], indent=1) + "\n")
        print(f"\nwrote {args.json} ({len(records)} record(s))")
    if args.plots is not None:
        _write_plots(args.plots, runs, all_records, vessels[0])
    if args.study:
        print(
            "\ncalibration study (RMS distance of the true tip from the model tip, "
            "reaching 150 random targets within +-60 deg from rest):"
        )
        from icenav.eval.spin_study import calibration_study

        for row in calibration_study(seeds[0]):
            print(
                f"  {row['set']:<44s} {row['n_points']:>4d} pts  {row['interpolant']:<14s}"
                f" {row['rms_mm']:5.2f} mm"
            )
    print(f"\ntotal {time.perf_counter() - t0:.1f} s")
    return 0

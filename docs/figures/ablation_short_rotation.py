"""A development diagnosis (docs/results.md, session 13, short12): where the short
calibration's rotation error comes from. ``short+rings+prior`` with one of its parts replaced
by what the full calibration (ours, ``dense+hysteresis``) measured on the same catheter, every
variant fitted on the SAME recording of the short plan, and each spin's rotation error split
into the image's turn about the tip axis (``axial``: the roll's and the twist's plays, eq. R1)
and the tilt of the tip axis (``tilt``: the bending plane's direction and the bend, i.e. F)::

    R_e = R_intended^T R_measured,  axial = atan2(R_e[1,0] - R_e[0,1], R_e[0,0] + R_e[1,1]),
    tilt = arccos(z_intended . z_measured)                                            (R1)

Variants (truth is read for the diagnosis only, never by a method):

- ``prior``: ``short+rings+prior`` as it is (play prior and map prior);
- ``+twist``: ours' twist law (the spin circle's, session 12) instead of the prior's;
- ``+plays``: ours' whole per-joint compensator (roll base, roll and twist laws);
- ``+bias``: ours' tracker bias removed from the short recording and the five points first;
- on a second recording, of the plan with the short roll circle (``short_ring_plan(
  bias_circle=True)``): ``circle0`` fitted without its bias (the bent sweep's coarser step
  alone), ``circle`` with it (B1), ``circle+T`` with it and the circle's twist prior (T1:
  ``short+rings+prior`` since session 13), ``circle+twist`` with it and ours' twist law;
- ``ours``: ``dense+hysteresis``.

Prints, per variant, EM / true RMS position and rotation at 20 / 40 / 60 deg and the true
pose's axial / tilt RMS; writes ``{"family", "seed", "set": "rotation", "rows", "split"}``
(``rows`` as ``make_short_spin_table.py`` reads them). Development catheters only
(210-214, 218-229; 215-217 made the priors)::

    python docs/figures/ablation_short_rotation.py default 210 [OUT.json [lean]]

``lean``: only ``prior``, ``circle``, ``circle+T`` and ``ours`` (session 13's before /
after). ``prior`` is session 12's ``short+rings+prior`` (the priors without T0).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from typing import Any

import numpy as np
from ablation_rows import spin_runs

from icenav.calibration.plans import Recording
from icenav.calibration.procedure import run_visits
from icenav.calibration.procedures import plan_visits
from icenav.calibration.short import fit_short_rings, short_ring_plan
from icenav.eval import spin as S


def split(measured: Any, intended: Any) -> tuple[float, float]:
    """(R1): RMS axial turn and tilt (deg) of measured (n, 4, 4) against intended."""
    r = np.einsum("nji,njk->nik", intended[:, :3, :3], measured[:, :3, :3])
    axial = np.arctan2(r[:, 1, 0] - r[:, 0, 1], r[:, 0, 0] + r[:, 1, 1])
    z = np.einsum("ni,ni->n", intended[:, :3, 2], measured[:, :3, 2])
    tilt = np.arccos(np.clip(z, -1.0, 1.0))
    rms = [math.degrees(float(np.sqrt(np.mean(a**2)))) for a in (axial, tilt)]
    return rms[0], rms[1]


def spin_rows(rig: Any, tracker: Any, commands: Any) -> tuple[list[float], list[float]]:
    """(EM mm, EM deg, true mm, true deg) and (true axial deg, true tilt deg) per bend."""
    errs: list[float] = []
    parts: list[float] = []
    for e, true, intended in spin_runs(rig, tracker, commands):
        errs += e
        parts += list(split(true, intended))
    return errs, parts


def main() -> None:
    fam, seed = sys.argv[1], int(sys.argv[2])
    out_path = sys.argv[3] if len(sys.argv) > 3 else None
    lean = len(sys.argv) > 4 and sys.argv[4] == "lean"
    if not (210 <= seed <= 214 or 218 <= seed <= 229):
        raise SystemExit("development catheters only (210-214, 218-229)")
    rig, tracker = S.make_rig(seed, "straight", fam)
    five = S.run_calibration("five_point", rig, tracker).calibration_set
    ours = S.run_calibration("dense+hysteresis", rig, tracker).details
    twist_prior = S.family_play_prior(fam)  # with the circle's twist (T0), session 13
    prior = dataclasses.replace(twist_prior, twist_circle=None)  # session 12's priors
    rig.reset()
    plan = short_ring_plan()
    rec = run_visits(plan_visits(plan.plan), rig.move, tracker)
    base = fit_short_rings(plan, rec, five, prior=prior, map_prior=prior.map)
    h, oh = base.hysteresis, ours.hysteresis.compensator
    bias = ours.tracker_bias
    t = np.array(rec.tip2base)
    t[rec.measured] = bias.correct_poses(t[rec.measured])
    unbiased = Recording(plan=rec.plan, tip2base=t, attempts=rec.attempts)
    variants: dict[str, Any] = {
        "prior": base,
        "+twist": dataclasses.replace(base, hysteresis=h.with_plays(h.roll_play, oh.twist_play)),
        "+plays": dataclasses.replace(base, hysteresis=oh),
        "+bias": fit_short_rings(
            plan, unbiased, bias.correct_calibration(five), prior=prior, map_prior=prior.map
        ),
    }
    rig.reset()
    cplan = short_ring_plan(bias_circle=True)
    crec = run_visits(plan_visits(cplan.plan), rig.move, tracker)
    circle = fit_short_rings(cplan, crec, five, prior=prior, map_prior=prior.map)
    ch = circle.hysteresis
    variants["circle0"] = fit_short_rings(
        dataclasses.replace(cplan, bias_circle=False), crec, five, prior=prior, map_prior=prior.map
    )
    variants["circle"] = circle
    variants["circle+T"] = fit_short_rings(
        cplan, crec, five, prior=twist_prior, map_prior=twist_prior.map
    )
    variants["circle+twist"] = dataclasses.replace(
        circle, hysteresis=ch.with_plays(ch.roll_play, oh.twist_play)
    )
    b_at = np.array([[0.0, 0.0, 60.0], [30.0, 0.0, 50.0], [0.0, 40.0, 45.0]])
    print(
        f"{fam} {seed} bias at 3 points ours "
        + str(np.round(bias.at(b_at), 2).tolist())
        + " circle "
        + str(np.round(circle.tracker_bias.at(b_at), 2).tolist()),
        flush=True,
    )
    if lean:
        variants = {k: variants[k] for k in ("prior", "circle", "circle+T")}
    rows: dict[str, list[float]] = {}
    splits: dict[str, list[float]] = {}
    for name in [*variants, "ours"]:
        if name == "ours":

            def commands(q: Any) -> Any:
                return S.knob_map_commands(ours.knob_map(), S._approach_path(q))
        else:
            cal = variants[name]

            def commands(q: Any, cal: Any = cal) -> Any:
                return S.short_ring_commands(cal, q)

        rows[name], splits[name] = spin_rows(rig, tracker, commands)
        e, p = rows[name], splits[name]
        print(
            f"{fam} {seed} {name:12s} EM "
            + " / ".join(f"{e[4 * i]:.2f} mm {e[4 * i + 1]:.2f} deg" for i in range(3))
            + " | true "
            + " / ".join(f"{e[4 * i + 2]:.2f} mm {e[4 * i + 3]:.2f} deg" for i in range(3))
            + " | axial/tilt "
            + " / ".join(f"{p[2 * i]:.2f}/{p[2 * i + 1]:.2f}" for i in range(3)),
            flush=True,
        )
    if out_path:
        with open(out_path, "w") as fh:
            json.dump(
                {"family": fam, "seed": seed, "set": "rotation", "rows": rows, "split": splits},
                fh,
                indent=1,
            )


if __name__ == "__main__":
    main()

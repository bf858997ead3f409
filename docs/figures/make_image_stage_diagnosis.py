"""Why the image stage does not gain: its score against the true error (docs/view-recovery.md).

Usage::

    python docs/figures/make_image_stage_diagnosis.py --seed 100 --patient 0 \
        --json /tmp/diag_100.json                      # measure one development pair
    python docs/figures/make_image_stage_diagnosis.py --drift --seed 100 --patient 0 \
        --rounds 3 --json /tmp/drift_100.json          # a still catheter's static error
    cd docs/figures && python make_image_stage_diagnosis.py --plot 'image_stage/diag_*.json' \
        'image_stage/drift_*.json'                     # docs/figures/image_stage_diagnosis.png
    python docs/figures/make_image_stage_diagnosis.py --ablate c45f301 --seed 107 --patient 7 \
        --rounds 4 --json /tmp/pab.json                # paired ablation of a variant

Development pairs only (catheters 100-109 with patients 0-9), in vivo, the evaluation's
bench (:class:`icenav.eval.recovery_bench.Bench`, 128-px pictures). The views are saved as
``icenav eval recovery`` saves them (the saved beats are the image stage's references).
Then, for each view and each joint, the catheter is returned to the view along the roadmap
and moved to ``q_view + offset e_j`` the way the image stage moves (approached from the
view's arrival direction), held still, and measured:

* the true static error against the saved view (the twin's true pose averaged over complete
  breaths, as the evaluation's static metric);
* ``beats`` scores of the image stage (:meth:`RefinementTask.score`) on beats gated on ECG
  and respiration (:class:`GatedBeatImager`, as the stage measures), and as many on beats
  gated on ECG alone (to see whether breathing fools the score).

The figure: (a) the gated score against the true orientation error, (b) against the true
position error, (c) the score against the commanded offset per joint (mean and sd of the
beats), with the stage's ceiling and its noise threshold.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import sys
from pathlib import Path

import numpy as np

from icenav.eval.recovery import TARGETS, RecoveryConfig
from icenav.eval.recovery_bench import DT, Bench
from icenav.geometry.se3 import rigid_inverse as inv
from icenav.refinement.gating import GatedBeatImager
from icenav.refinement.image_search import RefinementConfig, RefinementTask, refine

OUT = Path(__file__).resolve().parent / "image_stage_diagnosis.png"
JOINTS = ("knob 1 (deg)", "knob 2 (deg)", "roll (deg)", "translation (mm)")
OFFSETS = (-3.0, -1.5, -0.75, 0.0, 0.75, 1.5, 3.0)
"""Offsets of each joint (deg for the knobs and roll, half of it in mm for translation)."""


def _error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = inv(b) @ a
    pos = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    c = float(np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    return pos, math.degrees(math.acos(c))


def _move(b: Bench, targets: list[np.ndarray], vmax: np.ndarray) -> None:
    for target in targets:
        q0 = np.asarray(b.robot.read_state().q, np.float64)
        n = max(1, math.ceil(float(np.max(np.abs(target - q0) / (vmax * DT)))))
        for f in np.arange(1, n + 1) / n:
            q = q0 + f * (target - q0)
            b.robot.command_position(q)
            b.record(q)
            b.clock.advance(DT)


def sweep(seed: int, patient: int, beats: int, targets: tuple[str, ...]) -> list[dict]:
    """Measure one development pair (see the module docstring)."""
    cfg = RecoveryConfig(seed=seed, patient=patient, condition="in-vivo")
    rc = RefinementConfig()
    b, saved = _bench(cfg, targets)
    rows = []
    vmax = np.array(rc.max_velocity)
    for name in targets:
        view, static, refs = saved[name]
        gated = GatedBeatImager(b.refine_imager, b.respiration, refs[0], cfg.gate_window_beats)
        task = RefinementTask(view.q, refs, gated, arrival_direction=view.arrival_direction)
        d = np.array(view.arrival_direction, np.float64)
        for j in range(4):
            for off in OFFSETS:
                b.go(view)
                q = np.asarray(view.q, np.float64).copy()
                q[j] += off * (0.5 if j == 3 else math.pi / 180.0)
                pre = q - d * np.array(rc.overshoot)
                _move(b, [pre, q], vmax)
                b.hold_still(b.cycle_window_s)
                pos, rot = _error(b.static_pose(), static)
                g, u = [], []
                for _ in range(beats):
                    b.clock.advance(gated.beat_duration_s)
                    g.append(task.score(gated.acquire_beat()))
                    b.clock.advance(b.refine_imager.beat_duration_s)
                    u.append(task.score(b.refine_imager.acquire_beat()))
                rows.append(
                    dict(
                        seed=seed,
                        patient=patient,
                        view=name,
                        joint=j,
                        offset=off,
                        pos_mm=pos,
                        rot_deg=rot,
                        gated=g,
                        ungated=u,
                        ceiling=task.ceiling,
                        noise=task.noise,
                    )  # fmt: skip
                )
                print(f"{seed}/{patient} {name} j{j} {off:+.2f}: {pos:.2f} mm {rot:.2f} deg "
                      f"gated {np.mean(g):.4f}+-{np.std(g):.4f} ungated {np.mean(u):.4f} "
                      f"ceiling {task.ceiling:.4f} noise {task.noise:.4f}", flush=True)  # fmt: skip
    return rows


def _bench(cfg: RecoveryConfig, targets: tuple[str, ...]) -> tuple[Bench, dict[str, tuple]]:
    """The bench with the views saved as ``icenav eval recovery`` saves them, then the
    operator's wander: (view, static pose, reference beats) per view."""
    b = Bench(cfg)
    saved: dict[str, tuple] = {}
    for name in targets:
        b.drive(b.operator.move_to(b.views[name]))
        b.drive(b.operator.dwell(0.5))
        view = b.roadmap.make_view(name, created_s=b.clock.now(), tip2base=b.true_pose())
        b.hold_still(b.cycle_window_s)
        static = b.static_pose()
        clips = [b.acquire() for _ in range(cfg.ceiling_beats + 1)]
        refs = [c.subsampled(cfg.refine_subsample) for c in clips]
        saved[name] = (view, static, refs)
    b.drive(b.operator.explore(cfg.wander_moves))
    return b, saved


VARIANTS = {
    "default": RefinementConfig(),
    "c45f301": RefinementConfig(search=True),
    "session7": RefinementConfig(
        joints=(True, True, True, True),
        beats=1,
        significance=0.0,
        verify_end=False,
        noise_factor=1.5,
        search=True,
    ),
    "safe": RefinementConfig(noise_factor=1.5, search=True),
    "safe_all_joints": RefinementConfig(
        noise_factor=1.5, joints=(True, True, True, True), search=True
    ),
    "knobs": RefinementConfig(noise_factor=1.5, joints=(True, True, False, False), search=True),
}
"""Image-stage settings of the paired ablation (``--ablate NAME``)."""


def ablate(seed: int, patient: int, variant: str, rounds: int) -> list[dict]:
    """Paired ablation: after each roadmap return, the true static error before and after
    the image stage (settings ``VARIANTS[variant]``, gated beats as the evaluation's)."""
    cfg = RecoveryConfig(seed=seed, patient=patient, condition="in-vivo")
    b, saved = _bench(cfg, TARGETS)
    rows = []
    for k in range(rounds):
        for name in TARGETS:
            view, static, refs = saved[name]
            b.go(view)
            b.hold_still(b.cycle_window_s)
            before = _error(b.static_pose(), static)
            gated = GatedBeatImager(b.refine_imager, b.respiration, refs[0], cfg.gate_window_beats)
            res = refine(b.robot, view.q, refs, gated, arrival_direction=view.arrival_direction,
                         config=VARIANTS[variant], dt=DT, sleep=b.clock.advance,
                         on_command=b.record)  # fmt: skip
            b.clock.advance(0.2)
            b.hold_still(b.cycle_window_s)
            after = _error(b.static_pose(), static)
            rows.append(
                dict(
                    seed=seed,
                    patient=patient,
                    view=name,
                    round=k,
                    variant=variant,
                    before=before,
                    after=after,
                    moved=res.n_commands > 0,
                    status=res.status.value,
                    beats=len(res.trials),
                    s=res.duration_s,
                )  # fmt: skip
            )
            print(f"{variant} {seed}/{patient} {k} {name}: {before[0]:.2f} mm {before[1]:.2f} deg "
                  f"-> {after[0]:.2f} mm {after[1]:.2f} deg  {res.status.value} "
                  f"{len(res.trials)} beats {res.duration_s:.0f} s", flush=True)  # fmt: skip
    return rows


def drift(seed: int, patient: int, rounds: int, windows: int = 6) -> list[dict]:
    """A still catheter after a roadmap return: the true static error against the saved
    view over ``windows`` consecutive cycle windows (9 s each), no command but the held
    set-point (what any measuring stage costs in time)."""
    cfg = RecoveryConfig(seed=seed, patient=patient, condition="in-vivo")
    b, saved = _bench(cfg, TARGETS)
    rows = []
    for k in range(rounds):
        for name in TARGETS:
            view, static, _ = saved[name]
            b.go(view)
            t0 = b.clock.now()
            errs = []
            for _ in range(windows):
                q = np.asarray(b.robot.read_state().q, np.float64)
                while b.clock.now() - t0 < (len(errs) + 1) * b.cycle_window_s:
                    b.robot.command_position(q)  # the controller re-sends its set-point
                    b.clock.advance(DT)
                errs.append((b.clock.now() - t0, *_error(b.static_pose(), static)))
            rows.append(dict(seed=seed, patient=patient, view=name, round=k, errors=errs))
            print(f"drift {seed}/{patient} {k} {name}: "
                  + " ".join(f"{e[1]:.2f}" for e in errs) + " mm", flush=True)  # fmt: skip
    return rows


def summary(rows: list[dict]) -> str:
    """Per view: the score's noise per gated beat at a still catheter, the slope against the
    true orientation / position error, and the correlation of score with error."""
    out = []
    keys = sorted({(r["seed"], r["view"]) for r in rows})
    for key in keys:
        rs = [r for r in rows if (r["seed"], r["view"]) == key]
        noise_g = np.mean([np.std(r["gated"], ddof=1) for r in rs])
        noise_u = np.mean([np.std(r["ungated"], ddof=1) for r in rs])
        s = np.array([np.mean(r["gated"]) for r in rs])
        rot = np.array([r["rot_deg"] for r in rs])
        pos = np.array([r["pos_mm"] for r in rs])
        best = rs[int(np.argmax(s))]
        out.append(
            f"{key[0]} {key[1]}: noise per gated beat {noise_g:.4f} (ungated {noise_u:.4f}), "
            f"ref noise {rs[0]['noise']:.4f}; corr(score, rot) {np.corrcoef(s, rot)[0, 1]:+.2f}, "
            f"corr(score, pos) {np.corrcoef(s, pos)[0, 1]:+.2f}; slope "
            f"{np.polyfit(rot, s, 1)[0]:+.4f}/deg {np.polyfit(pos, s, 1)[0]:+.4f}/mm; "
            f"best-scoring state {best['pos_mm']:.2f} mm {best['rot_deg']:.2f} deg vs smallest "
            f"error {min(pos):.2f} mm {min(rot):.2f} deg; ceiling {rs[0]['ceiling']:.4f}, mean "
            f"score {s.mean():.4f}"
        )
    return "\n".join(out)


def plot(rows: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    still = [r for r in rows if "errors" in r]
    rows = [r for r in rows if "gated" in r]
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.4))
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:red")
    for r in rows:
        # each measurement relative to its view's ceiling (NCC points)
        y = 100 * (np.mean(r["gated"]) - r["ceiling"])
        c = colors[r["joint"]]
        axes[0].plot(r["rot_deg"], y, "o", color=c, ms=3, alpha=0.7)
        axes[1].plot(r["pos_mm"], y, "o", color=c, ms=3, alpha=0.7)
    for j in range(4):
        rs = [r for r in rows if r["joint"] == j]
        for k, off in enumerate(OFFSETS):
            v = [100 * (g - r["ceiling"]) for r in rs if r["offset"] == off for g in r["gated"]]
            x = off + 0.12 * (j - 1.5)
            axes[2].errorbar(x, np.mean(v), yerr=np.std(v), fmt="o", color=colors[j], ms=4,
                             label=JOINTS[j] if k == 0 else None)  # fmt: skip
    noise = 100 * np.nanmean([np.std(r["gated"], ddof=1) for r in rows])
    for r in still:
        t = [e[0] for e in r["errors"]]
        axes[3].plot(t, [e[1] - r["errors"][0][1] for e in r["errors"]], "-", color="0.5", lw=0.7)
    if still:
        e = np.array([[x[1] - r["errors"][0][1] for x in r["errors"]] for r in still])
        axes[3].plot(t, e.mean(axis=0), "k-", lw=2, label=f"mean of {len(still)} returns")
        axes[3].legend(fontsize=8)
    axes[3].set_xlabel("time since the return, catheter still (s)")
    axes[3].set_ylabel("true static position error - first window's (mm)")
    axes[3].axhline(0.0, color="k", lw=0.8)
    for ax in axes[:3]:
        ax.axhline(0.0, color="k", lw=0.8)
        ax.axhspan(-noise, noise, color="0.85", zorder=0)
        ax.set_ylabel("gated score - ceiling (NCC points)")
    axes[0].set_xlabel("true orientation error vs the saved view (deg)")
    axes[1].set_xlabel("true position error vs the saved view (mm)")
    axes[2].set_xlabel("commanded offset (deg; translation: x 0.5 mm)")
    axes[2].legend(fontsize=8)
    pairs = sorted({(r["seed"], r["patient"]) for r in rows})
    fig.suptitle(
        f"Image stage's score (ECG + respiration gated beats) against the true error, in vivo, "
        f"development pairs {pairs}; grey band: +- the score's sd per gated beat "
        f"({noise:.2f} points)", fontsize=9,
    )  # fmt: skip
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--seed", type=int, default=100)
    p.add_argument("--patient", type=int, default=0)
    p.add_argument("--beats", type=int, default=3)
    p.add_argument("--views", default=",".join(TARGETS))
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", nargs="*", help="JSON files of earlier sweeps to plot")
    p.add_argument("--ablate", choices=sorted(VARIANTS), help="paired ablation of a variant")
    p.add_argument("--rounds", type=int, default=4, help="returns per view (--ablate)")
    p.add_argument("--drift", action="store_true", help="a still catheter's static error")
    args = p.parse_args(argv)
    if args.plot:
        rows = [r for pat in args.plot for f in sorted(glob.glob(pat))
                for r in json.loads(Path(f).read_text())]  # fmt: skip
        print(summary([r for r in rows if "gated" in r]))
        plot(rows, OUT)
        return 0
    if args.seed not in range(100, 110) or args.patient not in range(0, 10):
        print("development pairs only: catheters 100-109, patients 0-9", file=sys.stderr)
        return 2
    if args.drift:
        rows = drift(args.seed, args.patient, args.rounds)
        if args.json:
            args.json.write_text(json.dumps(rows) + "\n")
        e = np.array([[x[1] for x in r["errors"]] for r in rows])
        print("mean static error (mm) per window:", np.round(e.mean(axis=0), 3))
    elif args.ablate:
        rows = ablate(args.seed, args.patient, args.ablate, args.rounds)
        if args.json:
            args.json.write_text(json.dumps(rows) + "\n")
        for key in ("before", "after"):
            e = np.array([r[key] for r in rows])
            print(f"{key}: {e[:, 0].mean():.2f} mm {e[:, 1].mean():.2f} deg")
    else:
        rows = sweep(args.seed, args.patient, args.beats, tuple(args.views.split(",")))
        print(summary(rows))
    if args.json:
        args.json.write_text(json.dumps(rows) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

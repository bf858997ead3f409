"""The twin's still tip against a published in-vivo measurement of a catheter tip resting
on a beating wall (`docs/digital-twin.md` 9.8): how far the tip's trajectory moves from one
beat to the next at the same phase, binned by the contact force it rests with.

    python docs/figures/review_still_tip.py [--pairs 100:0,101:1,102:2] [--states 14]

The published figure: Lessick, Kornowski, Fuchs, Ben-Haim (2001), NOGA mapping catheter on
the left-ventricular endocardium of seven pigs, "LocStab", the mean displacement between the
tip's trajectories of two consecutive cardiac cycles: 1.33 +- 0.61 mm (tip in contact;
with and without a needle anchoring it: no slippage). The same quantity here: for every
pair of consecutive beats of a still state, the tip's true position at 20 phases of each
beat (the twin's own beat clock), the mean distance between the two trajectories; then the
mean and sd over the beats of the state.

Twin's truth only (a review of the twin, not a method); development pairs (catheters
100-102, patients 0-2), states: each pair's three views, then states bent from them in
random directions by 10-80 deg (seeded) so the resting force spans free to above 1 N. Writes
``docs/figures/review_still_tip.json`` and ``docs/figures/review_still_tip.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icenav.sim.conditions import build_twin  # noqa: E402

HERE = Path(__file__).parent
LESSICK_MM = (1.33, 0.61)
"""LocStab, mean +- sd (mm), Lessick et al. 2001."""
PHASES = np.linspace(0.0, 1.0, 20, endpoint=False)
BEATS = 6
"""Consecutive beats sampled per state (5 pairs)."""
SETTLE_S = 3.0
"""Wait after the move before the first beat (the shaft settles; s)."""
BINS_N = (0.0, 0.02, 0.1, 0.2, 0.4, 1.0, np.inf)
"""Force bins of the table (N): free, light, 10-20 g, 20-40 g (clinical), above."""


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _loc_stab(twin, clock: _Clock) -> tuple[float, float, float, float]:
    """(mean, sd of LocStab over beat pairs (mm), mean contact force (N), tip range (mm))."""
    plant, rhythm = twin.plant, twin.rhythm
    k0 = rhythm.beat_index(clock.t + SETTLE_S) + 1
    trajs, forces = [], []
    for k in range(k0, k0 + BEATS):
        pts = []
        for ph in PHASES:
            st = plant.state_at(rhythm.time_at_phase(k, float(ph)))
            pts.append(st.tip2base[:3, 3].copy())
            forces.append(st.contact_force_n)
        trajs.append(np.array(pts))
    d = [np.linalg.norm(trajs[i + 1] - trajs[i], axis=1).mean() for i in range(BEATS - 1)]
    allp = np.concatenate(trajs)
    return float(np.mean(d)), float(np.std(d)), float(np.mean(forces)), float(np.ptp(allp, 0).max())


def _states(twin, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    views = [np.asarray(v, np.float64) for v in twin.views.values()]
    out = list(views)
    while len(out) < n:
        q = views[len(out) % len(views)].copy()
        a = rng.uniform(0, 2 * np.pi)
        q[:2] += np.radians(rng.uniform(10.0, 80.0)) * np.array([np.cos(a), np.sin(a)])
        q[3] += rng.uniform(-5.0, 15.0)
        out.append(q)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", default="100:0,101:1,102:2")
    ap.add_argument("--states", type=int, default=24)
    args = ap.parse_args()
    rows: list[dict[str, float | str | int]] = []
    for cond in ("in-vivo", "phantom"):
        for pair in args.pairs.split(","):
            cat, pat = (int(x) for x in pair.split(":"))
            clock = _Clock()
            twin = build_twin(cond, cat, pat, clock)
            rng = np.random.default_rng(1000 * cat + pat)
            for i, q in enumerate(_states(twin, args.states, rng)):
                clock.t += 1.0
                twin.plant.move(q)
                m, s, f, rng_mm = _loc_stab(twin, clock)
                clock.t += SETTLE_S + BEATS * 1.2
                rows.append(dict(condition=cond, catheter=cat, patient=pat, state=i,
                                 loc_stab_mm=m, loc_stab_sd_mm=s, force_n=f,
                                 range_mm=rng_mm))  # fmt: skip
                print(
                    f"{cond:8s} {cat}/{pat} state {i:2d}: force {f:5.2f} N, "
                    f"LocStab {m:5.2f} +- {s:4.2f} mm, range {rng_mm:5.1f} mm",
                    flush=True,
                )
    (HERE / "review_still_tip.json").write_text(json.dumps({"rows": rows}, indent=1))
    _table(rows)
    _plot(rows)


def _table(rows: list[dict]) -> None:
    print(
        "\n| condition | force (N) | states | LocStab, mean of states (mm) | sd over beats (mm) |"
    )
    print("|---|---|---:|---:|---:|")
    for cond in ("in-vivo", "phantom"):
        for lo, hi in zip(BINS_N[:-1], BINS_N[1:], strict=True):
            sel = [r for r in rows if r["condition"] == cond and lo <= r["force_n"] < hi]
            if not sel:
                continue
            m = np.mean([r["loc_stab_mm"] for r in sel])
            s = np.mean([r["loc_stab_sd_mm"] for r in sel])
            print(f"| {cond} | {lo:g}-{hi:g} | {len(sel)} | {m:.2f} | {s:.2f} |")
    print(f"| Lessick et al. 2001 (pig LV, in contact) | | | {LESSICK_MM[0]} | {LESSICK_MM[1]} |")


def _plot(rows: list[dict]) -> None:
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for cond, color in (("in-vivo", "tab:red"), ("phantom", "tab:blue")):
        sel = [r for r in rows if r["condition"] == cond]
        ax.errorbar([max(r["force_n"], 1e-3) for r in sel], [r["loc_stab_mm"] for r in sel],
                    yerr=[r["loc_stab_sd_mm"] for r in sel], fmt="o", ms=4, alpha=0.7,
                    color=color, label=f"twin, {cond}")  # fmt: skip
    m, s = LESSICK_MM
    ax.axhspan(m - s, m + s, color="0.8", alpha=0.6, label="Lessick et al. 2001, mean +- sd")
    ax.axhline(m, color="0.4", lw=1.0)
    ax.axvspan(0.1, 0.4, color="tab:green", alpha=0.08, label="clinical contact 10-40 g")
    ax.set_xscale("log")
    ax.set_xlabel("mean contact force of the still tip (N; free drawn at 0.001)")
    ax.set_ylabel("beat-to-beat tip displacement, same phase (mm)")
    ax.set_title("The twin's still tip against an in-vivo measurement", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(HERE / "review_still_tip.png", dpi=120)


if __name__ == "__main__":
    main()

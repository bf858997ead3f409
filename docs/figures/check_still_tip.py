"""The tracked and the true tip with the motors still, after the operator's stop and after a
return (nobody moves): how far a still catheter's tip goes with the beat, the breath and the
shaft (`docs/view-recovery.md`, "Session 8: the tip-drift check after the operator has
looked"). Development pairs only.

    python docs/figures/check_still_tip.py in-vivo 100 0 3 out.npz

Writes per stop ``op{k}`` / ``ret{k}`` arrays of rows (t, EM x y z, true x y z, respiratory
signal, cardiac phase) every 50 ms for 20 s, and prints each one's ranges.
"""

from __future__ import annotations

import sys

import numpy as np

from icenav.eval.recovery import TARGETS, RecoveryConfig
from icenav.eval.recovery_bench import Bench


def series(b: Bench, seconds: float = 20.0, dt: float = 0.05) -> np.ndarray:
    """Rows of the still tip every ``dt`` for ``seconds`` (the clock advances)."""
    assert b.twin is not None
    rows = []
    for _ in range(int(seconds / dt) + 1):
        now = b.clock.now()
        p = b.tip_pose_now()
        em = np.full(3, np.nan) if p is None else p[:3, 3]
        r = float(np.asarray(b.twin.monitor.signal(now)).reshape(-1)[0])
        rows.append([now, *em, *b.true_pose()[:3, 3], r, float(b.twin.rhythm.phase(now))])
        b.clock.advance(dt)
    return np.asarray(rows)


def main() -> None:
    cond, seed, patient, n, out = sys.argv[1], *map(int, sys.argv[2:5]), sys.argv[5]
    b = Bench(RecoveryConfig(condition=cond, seed=seed, patient=patient, force_check=True))
    views = {}
    for name in TARGETS:
        b.drive(b.operator.move_to(b.views[name]))
        b.drive(b.operator.dwell(0.5))
        views[name] = b.roadmap.make_view(name, created_s=b.clock.now())
    b.drive(b.operator.explore(12))
    res = {}
    for k in range(n):
        b.drive(b.operator.explore(2))
        res[f"op{k}"] = series(b)
        b.go(views[TARGETS[k % 3]])
        res[f"ret{k}"] = series(b)
    np.savez(out, **res)
    for key, a in res.items():
        print(f"{key}: true tip range x / y / z {np.ptp(a[:, 4:7], axis=0).round(1)} mm")


if __name__ == "__main__":
    main()

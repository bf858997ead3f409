"""Consecutive beats of a still catheter on the in-vivo twin (docs/digital-twin.md 9.3b).

Usage::

    python docs/figures/make_twin_beats.py            # writes docs/figures/twin_beats.png

Catheter 100, patient 0 (development seeds), the aortic view, the evaluation's picture
(128 px); the frame at the same cardiac phase (0.3, mid-systole) of three consecutive beats,
and the evaluation's beat similarity (NCC over the whole beat, frames matched by phase) of
each beat against the first: the session-6 twin (display smoothing of 1.5 px whatever the
picture size, no P6), the physical display smoothing without P6, and both (this twin).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import icenav.eval.recovery_bench as recovery_bench
import icenav.sim.conditions as conditions
from icenav.eval.recovery import RecoveryConfig
from icenav.eval.recovery_bench import Bench
from icenav.eval.recovery_report import raw_similarity
from icenav.sim.ultrasound import ProbeConfig

OUT = Path(__file__).resolve().parent / "twin_beats.png"


def _probe_px(px: float) -> object:
    def probe(**kw: object) -> ProbeConfig:
        return ProbeConfig(speckle_reduction_px=px, **kw)  # type: ignore[arg-type]

    return probe


def frames(shape_sd_mm: float | None, smoothing_px: float | None) -> tuple[list, list]:
    """The phase-0.3 frame of three consecutive beats (uint8 images) and the beat
    similarity (%) of each beat against the first."""
    saved = conditions.CONDITIONS["in-vivo"]
    saved_probe = recovery_bench.ProbeConfig
    if shape_sd_mm is not None:
        conditions.CONDITIONS["in-vivo"] = replace(
            saved, rhythm=replace(saved.rhythm, shape_sd_mm=shape_sd_mm)
        )
    if smoothing_px is not None:
        recovery_bench.ProbeConfig = _probe_px(smoothing_px)  # type: ignore[assignment,misc]
    try:
        b = Bench(RecoveryConfig(seed=100, patient=0, condition="in-vivo"))
    finally:
        conditions.CONDITIONS["in-vivo"] = saved
        recovery_bench.ProbeConfig = saved_probe  # type: ignore[misc]
    b.drive(b.operator.move_to(b.views["aortic_valve"]))
    b.drive(b.operator.dwell(0.5))
    b.hold_still(3.0)
    clips = [b.acquire() for _ in range(3)]
    sims = [100.0 * raw_similarity(c, clips[0]) for c in clips]
    return [np.asarray(c.images[3]) for c in clips], sims


def main() -> int:
    rows = [
        ("session 6", frames(0.0, 1.5)),
        ("display in mm, no P6", frames(0.0, None)),
        ("this twin (P6)", frames(None, None)),
    ]
    fig, axes = plt.subplots(3, 3, figsize=(8.4, 9.0))
    for r, (label, (imgs, sims)) in enumerate(rows):
        for c, img in enumerate(imgs):
            ax = axes[r, c]
            ax.imshow(img, cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            title = f"beat {c + 1}"
            if c:
                title += f", beat NCC {sims[c]:.1f} %"
            ax.set_title(title, fontsize=9)
        axes[r, 0].set_ylabel(label)
    fig.suptitle("Still catheter, aortic view, phase 0.3 of three consecutive beats")
    fig.tight_layout()
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The tip-drift check's resolution (Eq. F6) against the force the tip rests with, per
undisturbed and shifted return of the force study's records, and where the check stopped
(`docs/view-recovery.md` and `docs/results.md`, "The force check (session 9)").

    python docs/figures/make_drift_resolution.py

Reads ``docs/figures/force_check_s9_{dev,heldout}_{blind,looking}.json`` (written by
``python -m icenav.eval.force_study --score ... --json``) and writes
``docs/figures/drift_resolution.png``.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).parent
LIMIT_MM, FRACTION = 5.0, 0.5  # icenav.recovery.drift: DEFAULT_DRIFT_MM, RESOLUTION_FRACTION


def _load(name: str) -> dict[str, list[dict[str, float]]]:
    with open(HERE / f"force_check_s9_{name}.json", encoding="utf-8") as fh:
        return json.load(fh)["returns"]


def main() -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    panels = (
        ("blind operator (session 8's protocol)", ("dev_blind", "heldout_blind")),
        ("operator who backs off walls above 0.4 N", ("dev_looking", "heldout_looking")),
    )
    for ax, (title, names) in zip(axes, panels, strict=True):
        for name in names:
            for cond, rows in _load(name).items():
                f = np.array([r["rest_force_n"] for r in rows])
                res = np.array([r["resolution_mm"] for r in rows])
                ok = np.isfinite(f) & np.isfinite(res)
                held = name.startswith("heldout")
                ax.scatter(
                    np.maximum(f[ok], 1e-3), res[ok], s=14, alpha=0.6,
                    marker="o" if held else "x",
                    color="tab:red" if cond == "in-vivo" else "tab:blue",
                    label=f"{cond}, {'held out' if held else 'development'}",
                )  # fmt: skip
        ax.axhline(FRACTION * LIMIT_MM, color="k", lw=0.8, ls="--")
        ax.axvline(0.4, color="0.5", lw=0.8, ls=":")
        ax.text(1.2e-3, FRACTION * LIMIT_MM * 1.08, "cannot tell above (Eq. F6)", fontsize=8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("force the still tip rests with, median (N; 0 drawn at 0.001)")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7, loc="upper left")
    axes[0].set_ylabel("resolution R of the tip-drift check (mm)")
    fig.tight_layout()
    fig.savefig(HERE / "drift_resolution.png", dpi=110)


if __name__ == "__main__":
    main()

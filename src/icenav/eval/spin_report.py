"""Tables and plots of ``icenav eval spin`` over one or many catheters (Table I, Figs. 5, 7).

The records of :mod:`icenav.eval.spin` (one per catheter, vessel, bend and condition) are
summarised per (vessel, condition, bend) over the catheters: the mean EM-tracked and true
RMSE and the worst catheter (:func:`summarize`). :func:`format_table` prints them beside the
paper's Table I; :func:`format_vessel_effect` prints what a curved vessel adds to the
straight result of the same catheters, beside the paper's bounds for its Fig. 7 (dense:
less than +1 mm / +5 deg; simplified: less than +2 mm / +5 deg).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from icenav.eval.paper import paper_results

if TYPE_CHECKING:
    from icenav.eval.spin import SpinRecord

__all__ = [
    "BENDS_DEG",
    "CellSummary",
    "PAPER_VESSEL_BOUNDS",
    "VesselEffect",
    "format_family_matrix",
    "format_table",
    "format_vessel_effect",
    "paper_table",
    "plot_commands",
    "plot_curvature",
    "plot_tip",
    "summarize",
    "summarize_plants",
    "vessel_effect",
]

Array = NDArray[np.float64]

BENDS_DEG = (20, 40, 60)
"""The paper's initial AP bends (deg)."""
PAPER_VESSEL_BOUNDS = {"dense": (1.0, 5.0), "simplified": (2.0, 5.0)}
"""What the paper's curved vessels added at most (Section IV, Fig. 7): condition ->
(position mm, rotation deg)."""
VESSEL_ORDER = ("straight", "moderate", "steep")
_CONDITION_ORDER = (
    "none",
    "dense",
    "simplified",
    "dense+hysteresis",
    "dense+knob-hysteresis",
    "dense+hysteresis+em",
    "short",
    "short+rings",
    "short+rings+prior",
    "file",
)


@dataclass(frozen=True)
class CellSummary:
    """One cell of a table: one vessel, condition and bend, over the catheters run."""

    n: int
    """Number of catheters."""
    position_mm: float
    """Mean over catheters of the EM-tracked position RMSE (mm)."""
    rotation_deg: float
    """Mean of the EM-tracked rotation RMSE (deg)."""
    true_position_mm: float
    """Mean of the true-pose position RMSE (mm)."""
    true_rotation_deg: float
    """Mean of the true-pose rotation RMSE (deg)."""
    worst_position_mm: float
    """Largest EM-tracked position RMSE of a single catheter (mm)."""
    worst_rotation_deg: float
    """Largest EM-tracked rotation RMSE of a single catheter (deg)."""


def paper_table() -> dict[str, list[list[float]]]:
    """The paper's Table I: condition -> [[pos mm, rot deg] per bend 20 / 40 / 60]."""
    t = paper_results()["table_I_spinning_benchtop_straight"]
    return {k: t[k] for k in ("none", "dense", "simplified")}


def _ordered(values: Iterable[str], order: Sequence[str]) -> list[str]:
    vals = set(values)
    return [v for v in order if v in vals] + sorted(vals - set(order))


def _cell(rs: Sequence[SpinRecord]) -> CellSummary:
    return CellSummary(
        n=len(rs),
        position_mm=float(np.mean([r.position_rmse_mm for r in rs])),
        rotation_deg=float(np.mean([r.rotation_rmse_deg for r in rs])),
        true_position_mm=float(np.mean([r.true_position_rmse_mm for r in rs])),
        true_rotation_deg=float(np.mean([r.true_rotation_rmse_deg for r in rs])),
        worst_position_mm=float(max(r.position_rmse_mm for r in rs)),
        worst_rotation_deg=float(max(r.rotation_rmse_deg for r in rs)),
    )


def summarize(records: Sequence[SpinRecord]) -> dict[tuple[str, str, int], CellSummary]:
    """Mean and worst over catheters, keyed by (vessel, condition, bend_deg)."""
    groups: dict[tuple[str, str, int], list[SpinRecord]] = {}
    for r in records:
        groups.setdefault((r.vessel, r.condition, r.bend_deg), []).append(r)
    return {key: _cell(rs) for key, rs in groups.items()}


def summarize_plants(
    records: Sequence[SpinRecord],
) -> dict[tuple[str, str, str, int], CellSummary]:
    """Mean and worst over catheters, keyed by (plant, vessel, condition, bend_deg)."""
    groups: dict[tuple[str, str, str, int], list[SpinRecord]] = {}
    for r in records:
        groups.setdefault((r.plant, r.vessel, r.condition, r.bend_deg), []).append(r)
    return {key: _cell(rs) for key, rs in groups.items()}


def format_family_matrix(records: Sequence[SpinRecord]) -> str:
    """The plant x condition x bend matrix, one block per vessel: per cell the mean EM
    position and rotation RMSE over the catheters, the worst catheter's, and the mean
    true-pose RMSE (mm deg); plants in the order they first appear."""
    cells = summarize_plants(records)
    bends = sorted({r.bend_deg for r in records})
    plants = list(dict.fromkeys(r.plant for r in records))
    width = max(22, *(len(p) + 2 for p in plants))
    lines = []
    for vessel in _ordered((r.vessel for r in records), VESSEL_ORDER):
        seeds = _seeds_text([r for r in records if r.vessel == vessel])
        lines += [
            f"plant x condition x bend, vessel {vessel}, {seeds} per plant: "
            "mean EM mm deg | worst EM mm deg | mean true mm deg",
            (
                "plant".ljust(width)
                + "condition".ljust(22)
                + "".join(f"{b:>3d} deg".ljust(36) for b in bends)
            ).rstrip(),
        ]
        for plant in plants:
            conds = _ordered(
                (r.condition for r in records if r.plant == plant and r.vessel == vessel),
                _CONDITION_ORDER,
            )
            for cond in conds:
                row = plant.ljust(width) + cond.ljust(22)
                for b in bends:
                    c = cells.get((plant, vessel, cond, b))
                    row += (
                        "-"
                        if c is None
                        else f"{c.position_mm:4.1f} {c.rotation_deg:4.1f} | "
                        f"{c.worst_position_mm:4.1f} {c.worst_rotation_deg:4.1f} | "
                        f"{c.true_position_mm:4.1f} {c.true_rotation_deg:4.1f}"
                    ).ljust(36)
                lines.append(row.rstrip())
        lines.append("")
    return "\n".join(lines).rstrip()


def _seeds_text(records: Sequence[SpinRecord]) -> str:
    seeds = sorted({r.seed for r in records})
    if len(seeds) == 1:
        return f"catheter {seeds[0]}"
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"catheters {seeds[0]}-{seeds[-1]} (mean of {len(seeds)})"
    return f"catheters {', '.join(map(str, seeds))} (mean of {len(seeds)})"


def format_table(records: Sequence[SpinRecord]) -> str:
    """Table I per vessel: mean EM-tracked RMSE (the paper's in parentheses), the true-pose
    RMSE and, over several catheters, the worst one."""
    paper = paper_table()
    cells = summarize(records)
    bends = sorted({r.bend_deg for r in records})
    lines = []
    for vessel in _ordered((r.vessel for r in records), VESSEL_ORDER):
        in_situ = any(r.in_situ for r in records if r.vessel == vessel)
        lines.append(
            f"vessel {vessel}, {_seeds_text([r for r in records if r.vessel == vessel])}"
            + (", ours re-identified in the vessel" if in_situ else "")
            + ": EM mm deg (paper) | true mm deg"
            + (" | worst EM mm deg" if any(c.n > 1 for c in cells.values()) else "")
        )
        lines.append(
            ("condition".ljust(22) + "".join(f"{b:>3d} deg".ljust(52) for b in bends)).rstrip()
        )
        conds = _ordered((r.condition for r in records if r.vessel == vessel), _CONDITION_ORDER)
        for cond in conds:
            row = cond.ljust(22)
            for b in bends:
                c = cells.get((vessel, cond, b))
                if c is None:
                    row += "-".ljust(52)
                    continue
                ref = " (-)"
                if cond in paper and b in BENDS_DEG and vessel == "straight":
                    pp, pr = paper[cond][BENDS_DEG.index(b)]
                    ref = f" ({pp:.1f}, {pr:.1f})"
                cell = (
                    f"{c.position_mm:5.1f} {c.rotation_deg:5.1f}{ref}"
                    f" | {c.true_position_mm:4.1f} {c.true_rotation_deg:4.1f}"
                )
                if c.n > 1:
                    cell += f" | {c.worst_position_mm:4.1f} {c.worst_rotation_deg:4.1f}"
                row += cell.ljust(52)
            lines.append(row.rstrip())
        lines.append("")
    return "\n".join(lines).rstrip()


@dataclass(frozen=True)
class VesselEffect:
    """What a curved vessel adds to the straight result, one condition and bend."""

    n: int
    """Catheters run in both vessels."""
    position_mm: float
    """Mean over catheters of curved minus straight EM position RMSE (mm)."""
    rotation_deg: float
    """Mean of curved minus straight EM rotation RMSE (deg)."""
    worst_position_mm: float
    """Largest single-catheter increase of the position RMSE (mm)."""
    worst_rotation_deg: float
    """Largest single-catheter increase of the rotation RMSE (deg)."""


def vessel_effect(records: Sequence[SpinRecord]) -> dict[tuple[str, str, int], VesselEffect]:
    """Curved minus straight, per catheter, then mean and worst over the catheters that ran
    both: keyed by (curved vessel, condition, bend_deg)."""
    straight = {
        (r.plant, r.seed, r.condition, r.bend_deg): r for r in records if r.vessel == "straight"
    }
    diffs: dict[tuple[str, str, int], list[tuple[float, float]]] = {}
    for r in records:
        s = straight.get((r.plant, r.seed, r.condition, r.bend_deg))
        if r.vessel == "straight" or s is None:
            continue
        diffs.setdefault((r.vessel, r.condition, r.bend_deg), []).append(
            (
                r.position_rmse_mm - s.position_rmse_mm,
                r.rotation_rmse_deg - s.rotation_rmse_deg,
            )
        )
    out = {}
    for key, d in diffs.items():
        a = np.array(d)
        out[key] = VesselEffect(
            n=len(d),
            position_mm=float(a[:, 0].mean()),
            rotation_deg=float(a[:, 1].mean()),
            worst_position_mm=float(a[:, 0].max()),
            worst_rotation_deg=float(a[:, 1].max()),
        )
    return out


def format_vessel_effect(records: Sequence[SpinRecord]) -> str:
    """What each curved vessel adds to the straight result (mean, worst catheter), beside
    the paper's bounds; empty if no catheter ran the straight and a curved vessel."""
    eff = vessel_effect(records)
    if not eff:
        return ""
    bends = sorted({k[2] for k in eff})
    rows = []
    for vessel in _ordered((k[0] for k in eff), VESSEL_ORDER):
        for cond in _ordered((k[1] for k in eff if k[0] == vessel), _CONDITION_ORDER):
            bound = PAPER_VESSEL_BOUNDS.get(cond)
            label = f"{vessel:<9s} {cond}" + (
                f" [< {bound[0]:.0f} mm, < {bound[1]:.0f} deg]" if bound else ""
            )
            cells = []
            for b in bends:
                e = eff.get((vessel, cond, b))
                cells.append(
                    "-"
                    if e is None
                    else f"{e.position_mm:+5.2f} {e.rotation_deg:+5.1f} / "
                    f"{e.worst_position_mm:+4.1f} {e.worst_rotation_deg:+4.1f}"
                )
            rows.append((label, cells))
    width = max(len(label) for label, _ in rows) + 2
    lines = [
        "what the curved vessel adds to the straight result (EM mm deg, mean over catheters; "
        "worst catheter after the slash; the paper's bound in brackets):",
        (
            "vessel    condition".ljust(width) + "".join(f"{b:>3d} deg".ljust(26) for b in bends)
        ).rstrip(),
    ]
    lines += [
        (label.ljust(width) + "".join(c.ljust(26) for c in cells)).rstrip() for label, cells in rows
    ]
    return "\n".join(lines)


# --- plots ---------------------------------------------------------------------------------


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_commands(commands: Mapping[tuple[int, str], Array], bend: int, out: Path) -> None:
    """Motor knob commands of the spin from ``bend`` deg per condition (cf. the paper's
    Fig. 5): ``commands[(bend, condition)]`` is (n, 4) (rad, rad, rad, mm)."""
    plt = _pyplot()
    conds = [c for c in _CONDITION_ORDER if (bend, c) in commands]
    fig, axes = plt.subplots(1, len(conds), figsize=(3.6 * len(conds), 3.2), sharey=True)
    for ax, c in zip(np.atleast_1d(axes), conds, strict=True):
        q = commands[(bend, c)]
        ax.plot(np.degrees(q[:, 0]), label="phi1 (AP)")
        ax.plot(np.degrees(q[:, 1]), label="phi2 (RL)")
        ax.set_title(c)
        ax.set_xlabel("time step")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("motor knob angle (deg)")
    np.atleast_1d(axes)[0].legend(loc="lower left", fontsize=8)
    fig.suptitle(f"Spin commands from ({bend} deg, 0) (cf. the paper's Fig. 5)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


_COLOURS = {
    "dense": "tab:red",
    "simplified": "tab:blue",
    "dense+hysteresis": "tab:green",
    "dense+knob-hysteresis": "tab:olive",
    "dense+hysteresis+em": "tab:purple",
    "none": "tab:gray",
}


def plot_curvature(records: Sequence[SpinRecord], out_dir: Path) -> list[Path]:
    """The paper's Fig. 7: EM-tracked position and orientation RMSE against the initial
    bend, per condition (colour) and vessel (solid straight, dotted moderate, dashed steep),
    mean over the catheters (the band spans the best to the worst catheter). Writes
    ``curvature_position.png`` and ``curvature_rotation.png`` into ``out_dir``."""
    plt = _pyplot()
    styles = {"straight": "-", "moderate": ":", "steep": "--"}
    paths = []
    for key, label, name in (
        ("position_rmse_mm", "position RMSE (mm)", "curvature_position.png"),
        ("rotation_rmse_deg", "orientation RMSE (deg)", "curvature_rotation.png"),
    ):
        fig, ax = plt.subplots(figsize=(6.5, 5.6))
        for cond in _CONDITION_ORDER[1:]:
            for vessel, ls in styles.items():
                rs = [r for r in records if r.condition == cond and r.vessel == vessel]
                if not rs:
                    continue
                bends = sorted({r.bend_deg for r in rs})
                vals = [[getattr(r, key) for r in rs if r.bend_deg == b] for b in bends]
                mean = [float(np.mean(v)) for v in vals]
                ax.plot(
                    bends,
                    mean,
                    ls,
                    color=_COLOURS.get(cond, "k"),
                    marker="o",
                    ms=3,
                    label=f"{cond}, {vessel}",
                )
                if max(len(v) for v in vals) > 1 and vessel == "straight":
                    ax.fill_between(
                        bends,
                        [min(v) for v in vals],
                        [max(v) for v in vals],
                        color=_COLOURS.get(cond, "k"),
                        alpha=0.12,
                        lw=0,
                    )
        ax.set_xlabel("initial AP bend (deg)")
        ax.set_ylabel(label + ", EM tracked")
        ax.set_title(f"Vessel curvature, {_seeds_text(records)} (cf. the paper's Fig. 7)")
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0.0)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.14))
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def plot_tip(tips: Mapping[str, Array], intended_mm: Array, bend: int, out: Path) -> None:
    """True tip positions (n, 3) per condition during the spin from ``bend`` deg, seen along
    the base z axis, with the intended tip (3,) (mm, base frame)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(4.5, 4.2))
    for c, pts in tips.items():
        ax.plot(pts[:, 0], pts[:, 1], label=c, lw=1)
    ax.plot([intended_mm[0]], [intended_mm[1]], "k*", ms=10, label="intended")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"True tip during the spin from {bend} deg")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)

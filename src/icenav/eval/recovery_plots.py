"""Plots of ``icenav eval recovery``: example images (the paper's Figs. 9-10), the spread
of the returns (Fig. 8) and the refinement's traces."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from icenav.eval.metrics import geometric_median_index, match_by_phase
from icenav.eval.recovery_report import raw_similarity
from icenav.recovery.beats import BeatClip

if TYPE_CHECKING:
    from icenav.eval.recovery import RecoveryRun, ReturnSample

__all__ = ["plot_images", "plot_spread", "plot_traces"]

MODES = ("open_loop", "refined")
TARGETS = ("aortic_valve", "mitral_valve", "tricuspid_valve")


def _shown_clip(s: ReturnSample) -> BeatClip:
    return s.gated_clip if s.gated_clip is not None else s.clip


def _median_return(run: RecoveryRun, name: str, mode: str) -> ReturnSample | None:
    rs = [s for s in run.returns if s.target == name and s.mode == mode]
    if not rs:
        return None
    sims = [raw_similarity(_shown_clip(s), run.saved_clips[name]) for s in rs]
    return rs[int(np.argsort(sims)[len(sims) // 2])]


def plot_images(run: RecoveryRun, out: Path) -> Path:
    """Figs. 9-10 style: saved view, an open-loop and a refined return (the return of median
    similarity; its respiratory-gated beat, with the gated similarity)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    modes = [m for m in MODES if m in run.config.modes]
    fig, axes = plt.subplots(
        len(TARGETS), 1 + len(modes), figsize=(3.0 * (1 + len(modes)), 3.0 * len(TARGETS))
    )
    axes = np.atleast_2d(axes)
    for i, name in enumerate(TARGETS):
        ref = run.saved_clips[name]
        panels: list[tuple[str, BeatClip | None]] = [("saved", ref)]
        for m in modes:
            s = _median_return(run, name, m)
            panels.append((m.replace("_", " "), None if s is None else _shown_clip(s)))
        for j, (title, clip) in enumerate(panels):
            ax = axes[i, j]
            ax.set_axis_off()
            if clip is None:
                continue
            k = int(match_by_phase(clip.phases, ref.phases[:1])[0])
            ax.imshow(clip.images[k], cmap="gray", vmin=0, vmax=255)
            roi = clip.frames[k].rois.get(name)  # type: ignore[attr-defined]
            if roi is not None and roi.visible:
                ax.plot(roi.centroid_px[1], roi.centroid_px[0], "r+", ms=10)
            sim = "" if j == 0 else f" {100 * raw_similarity(clip, ref):.0f} % (gated)"
            ax.set_title(f"{name.split('_')[0]}: {title}{sim}", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_spread(run: RecoveryRun, out: Path) -> Path:
    """Fig. 8 style: EM-measured tips around the geometric-median return, true tips around
    the saved pose (base x and z, mm: z is the catheter's axis, where translation play
    shows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(TARGETS), figsize=(4.2 * len(TARGETS), 4.0))
    colours = {"open_loop": "tab:blue", "refined": "tab:orange"}
    for ax, name in zip(np.atleast_1d(axes), TARGETS, strict=True):
        for mode in run.config.modes:
            rs = [s for s in run.returns if s.target == name and s.mode == mode]
            em = np.stack([s.em_tip2base[:3, 3] for s in rs if s.em_tip2base is not None])
            if len(em):
                g = geometric_median_index(em)
                d = em - em[g]
                ax.scatter(d[:, 0], d[:, 2], s=18, c=colours[mode], label=f"{mode} EM - GM")
            tr = np.stack([s.dct_tip2base[:3, 3] for s in rs]) - run.saved_dct_tip2base[name][:3, 3]
            ax.scatter(tr[:, 0], tr[:, 2], s=22, marker="x", c=colours[mode],
                       label=f"{mode} true - saved")  # fmt: skip
        ax.axhline(0, c="0.8", lw=0.5)
        ax.axvline(0, c="0.8", lw=0.5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name.replace("_", " "))
        ax.set_xlabel("base x (mm)")
        ax.set_ylabel("base z (mm)")
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_traces(run: RecoveryRun, out: Path) -> Path:
    """The refinement's traces: EM-measured pose error of each pose-stage measurement
    (position and orientation), and the image stage's blurred similarity."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"aortic_valve": "tab:red", "mitral_valve": "tab:green"}
    fig, axes = plt.subplots(1, 3, figsize=(13.0, 3.6))
    for s in run.returns:
        c = colours.get(s.target, "tab:blue")
        if s.pose_stage_trace:
            tr = np.array(s.pose_stage_trace)
            x = np.arange(len(tr))
            axes[0].plot(x, tr[:, 0], c=c, alpha=0.4, lw=0.8, marker="o", ms=3)
            axes[1].plot(x, tr[:, 1], c=c, alpha=0.4, lw=0.8, marker="o", ms=3)
        if s.refine_trace:
            axes[2].plot(range(len(s.refine_trace)), s.refine_trace, c=c, alpha=0.4, lw=0.8,
                         marker="o", ms=3)  # fmt: skip
    axes[0].set_ylabel("EM position error (mm)")
    axes[1].set_ylabel("EM orientation error (deg)")
    for ax in axes[:2]:
        ax.set_xlabel("pose-stage measurement (64 EM samples)")
        ax.set_yscale("symlog", linthresh=0.1)
    axes[2].set_xlabel("image-stage measurement (one gated beat)")
    axes[2].set_ylabel("blurred similarity to the saved beats")
    fig.suptitle("refinement traces (red aortic, green mitral, blue tricuspid)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out

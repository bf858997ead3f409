"""Make the imaging figures of docs/imaging.md (docs/figures/us_*.png) and print the numbers.

Run: ``.venv/bin/python docs/figures/make_imaging_figures.py`` (about 20 s).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import scipy.ndimage as ndi  # noqa: E402

from icenav.eval.metrics import beat_similarity, blurred_ncc, roi_centroid_distance  # noqa: E402
from icenav.sim.anatomy import (  # noqa: E402
    BLOOD_LABELS,
    EXAMPLE_VIEWS,
    STANDARD_VIEWS,
    HeartPhantom,
    Region,
    Tissue,
    default_phantom,
    tip2anatomy,
)
from icenav.sim.ultrasound import UltrasoundRenderer  # noqa: E402

HERE = Path(__file__).parent
TITLES = {"aortic_valve": "aortic valve", "mitral_valve": "mitral valve", "tricuspid_valve": "tricuspid valve"}  # fmt: skip  # noqa: E501


_SHORT = {
    Tissue.RA_BLOOD: "RA",
    Tissue.RV_BLOOD: "RV",
    Tissue.LA_BLOOD: "LA",
    Tissue.LV_BLOOD: "LV",
    Tissue.AORTA_BLOOD: "Ao",
    Tissue.PA_BLOOD: "PA",
    Tissue.CAVA_BLOOD: "SVC/IVC",
    Tissue.SEPTUM: "IAS",
    Tissue.TRICUSPID_VALVE: "TV",
    Tissue.MITRAL_VALVE: "MV",
    Tissue.AORTIC_VALVE: "AV",
    Tissue.PERICARDIUM: "pericardium",
    Tissue.LUNG: "lung",
}


def _annotate(ax: plt.Axes, labels: np.ndarray) -> None:
    """Write each structure's short name at its label-map centroid (>= 40 pixels)."""
    for tissue, text in _SHORT.items():
        rows, cols = np.nonzero(labels == tissue)
        if rows.size >= 40:
            ax.text(cols.mean(), rows.mean(), text, color="yellow", fontsize=8,
                    ha="center", va="center")  # fmt: skip


def _depth_scale(ax: plt.Axes, r: UltrasoundRenderer) -> None:
    px = r.config.pixel_mm
    for cm in range(0, int(r.config.depth_mm // 10) + 1, 2):
        ax.plot([2, 6], [cm * 10 / px] * 2, color="w", lw=0.8)
        ax.text(8, cm * 10 / px, f"{cm}", color="w", fontsize=6, va="center")


def views_figure(r: UltrasoundRenderer) -> None:
    """The standard views at two phases, each with its structures named (label map)."""
    period = r.phantom.motion.period_s
    views = list(STANDARD_VIEWS.values())
    fig, axes = plt.subplots(2, len(views), figsize=(4.0 * len(views), 8.4))
    for col, view in enumerate(views):
        pose = tip2anatomy(np.asarray(view.q))
        for row, phase in enumerate((0.15, 0.65)):
            f = r.render(pose, phase * period)
            ax = axes[row, col]
            ax.imshow(f.image, cmap="gray", vmin=0, vmax=255)
            _annotate(ax, f.labels)
            _depth_scale(ax, r)
            qd = np.degrees(view.q[:3])
            ax.set_title(
                f"{view.title}, phase {phase:.2f}\n"
                f"q = ({qd[0]:.0f}, {qd[1]:.0f}, {qd[2]:.0f}) deg, d4 = {view.q[3]:.0f} mm",
                fontsize=9,
            )
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_ylim(190, 0)
    fig.suptitle(
        "Simulated ICE standard views (14 cm depth, scale in cm; names from the label map; "
        "distal side of the catheter on the right)"
    )
    fig.tight_layout()
    fig.savefig(HERE / "us_views.png", dpi=70)
    plt.close(fig)


def effects_figure(r: UltrasoundRenderer) -> dict[str, float]:
    """Shadow behind a calcified nodule, gain and TGC settings, beam width with depth."""
    period = r.phantom.motion.period_s
    pose = tip2anatomy(np.asarray(STANDARD_VIEWS["home"].q))
    t = 0.65 * period
    nodule_at = pose[:3, :3] @ np.array([45.0, 0.0, -8.0]) + pose[:3, 3]
    ph = default_phantom()
    calcified = HeartPhantom(
        ph.chambers, ph.vessels, ph.valves, motion=ph.motion, pericardium_mm=2.0,
        lungs=ph.lungs,
        inclusions=(Region("nodule", tuple(nodule_at), (3.0, 3.0, 3.0), Tissue.CALCIFICATION),),
    )  # fmt: skip
    panels = [
        ("home view", r.render(pose, t).image),
        ("calcified nodule: acoustic shadow", UltrasoundRenderer(calcified).render(pose, t).image),
        ("gain -12 dB", r.with_settings(gain_db=-12.0).render(pose, t).image),
        ("TGC off (attenuation shows)", r.with_settings(tgc_db_per_cm=0.0).render(pose, t).image),
        ("depth 8 cm", r.with_settings(depth_mm=80.0).render(pose, t).image),
    ]
    fig, axes = plt.subplots(1, len(panels) + 1, figsize=(4.0 * (len(panels) + 1), 4.2))
    for ax, (title, img) in zip(axes, panels, strict=False):
        ax.imshow(img, cmap="gray", vmin=0, vmax=255)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    depth = np.linspace(5.0, 160.0, 100)
    axes[-1].plot(depth, r.config.lateral_fwhm_mm(depth), label="lateral (Eq. I5)")
    axes[-1].axhline(r.config.psf_axial_mm * 2.355, color="gray", ls=":", label="axial")
    axes[-1].set_xlabel("depth (mm)")
    axes[-1].set_ylabel("two-way FWHM (mm)")
    axes[-1].legend(fontsize=8)
    axes[-1].set_title("resolution vs depth", fontsize=9)
    fig.tight_layout()
    fig.savefig(HERE / "us_effects.png", dpi=70)
    plt.close(fig)
    return contrast_numbers(r)


def contrast_numbers(r: UltrasoundRenderer) -> dict[str, float]:
    """Mean grey of blood over myocardium in the standard views (label-map interiors: blood
    3 px, myocardium 1 px inside their outlines; as the test), at phases 0.15 and 0.65."""
    out = {}
    period = r.phantom.motion.period_s
    blood_ids = [int(b) for b in BLOOD_LABELS]
    for key, view in STANDARD_VIEWS.items():
        for phase in (0.15, 0.65):
            f = r.render(tip2anatomy(np.asarray(view.q)), phase * period)
            blood = ndi.binary_erosion(np.isin(f.labels, blood_ids), iterations=3)
            myo = ndi.binary_erosion(f.labels == Tissue.MYOCARDIUM, iterations=1)
            ratio = f.image[blood].mean() / f.image[myo].mean()
            out[f"{key}_{phase:.2f}_blood_over_myocardium"] = float(ratio)
    return out


def anatomy_figure() -> None:
    ph = default_phantom()
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    # coronal (x-z) slice through the RA centre and axial (x-y) slice at z = 20 mm
    xs = np.linspace(-40, 100, 281)
    zs = np.linspace(-60, 90, 301)
    X, Z = np.meshgrid(xs, zs)
    lab = ph.labels_at(np.stack([X, np.zeros_like(X), Z], -1), 0.0)
    axes[0].imshow(lab, origin="lower", extent=(xs[0], xs[-1], zs[0], zs[-1]), cmap="tab20")
    axes[0].set_xlabel("x: patient left (mm)")
    axes[0].set_ylabel("z: superior (mm)")
    axes[0].set_title("coronal slice y = 0 (anatomy frame, LPS)")
    ys = np.linspace(-70, 50, 241)
    X2, Y2 = np.meshgrid(xs, ys)
    lab2 = ph.labels_at(np.stack([X2, Y2, np.full_like(X2, 20.0)], -1), 0.0)
    axes[1].imshow(lab2, origin="lower", extent=(xs[0], xs[-1], ys[0], ys[-1]), cmap="tab20")
    axes[1].set_xlabel("x: patient left (mm)")
    axes[1].set_ylabel("y: posterior (mm)")
    axes[1].set_title("axial slice z = 20 mm")
    knobs = np.radians(np.arange(-30.0, 31.0, 10.0))
    d4 = np.arange(-20.0, 21.0, 10.0)
    p1, p2, dd = np.meshgrid(knobs, knobs, d4, indexing="ij")
    q = np.stack([p1.ravel(), p2.ravel(), np.zeros(p1.size), dd.ravel()], -1)
    tips = tip2anatomy(q)[:, :3, 3]
    axes[0].plot(tips[:, 0], tips[:, 2], "k.", ms=2, label="tips, bends <= 30 deg")
    axes[1].plot(tips[:, 0], tips[:, 1], "k.", ms=2)
    for view, qv in EXAMPLE_VIEWS.items():
        t = tip2anatomy(np.asarray(qv))
        p, d = t[:3, 3], t[:3, 0] * 25.0
        axes[0].annotate("", p[[0, 2]] + d[[0, 2]], p[[0, 2]], arrowprops={"arrowstyle": "->"})
        axes[0].plot(*p[[0, 2]], "o", label=f"{TITLES[view]} view")
        axes[1].plot(*p[[0, 1]], "o")
    axes[0].legend(fontsize=7, loc="lower right")
    names = ", ".join(f"{t.value}={t.name.lower()}" for t in Tissue)
    fig.text(0.01, 0.01, names, fontsize=6)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(HERE / "us_anatomy.png", dpi=80)
    plt.close(fig)


def similarity_figure(r: UltrasoundRenderer) -> dict[str, dict[str, float]]:
    period = r.phantom.motion.period_s
    n = 12
    numbers: dict[str, dict[str, float]] = {}
    steps = np.arange(0.0, 6.01, 0.5)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for view, q in EXAMPLE_VIEWS.items():
        pose = tip2anatomy(np.asarray(q))

        def clip(p: np.ndarray, beat: int) -> tuple[list, list, list]:
            fr = [r.render(p, (beat + k / n) * period) for k in range(n)]
            return [f.image for f in fr], [f.cardiac_phase for f in fr], fr

        ref, ref_ph, ref_fr = clip(pose, 0)
        mask = ref_fr[0].labels >= 0
        raw, blur = [], []
        for s in steps:
            moved = pose.copy()
            moved[:3, 3] += pose[:3, :3] @ np.array([0.0, s, 0.0])
            imgs, ph, _ = clip(moved, 1)
            raw.append(beat_similarity(imgs, ph, ref, ref_ph, mask=mask))
            blur.append(beat_similarity(imgs, ph, ref, ref_ph, mask=mask, blurred=True))
        _, _, still = clip(pose, 1)
        roi = [
            roi_centroid_distance(a.rois[view].centroid_mm, b.rois[view].centroid_mm)
            for a, b in zip(ref_fr, still, strict=True)
            if a.rois[view].visible and b.rois[view].visible
        ]
        ax[0].plot(steps, 100 * np.array(raw), "o-", label=TITLES[view])
        ax[1].plot(steps, 100 * np.array(blur), "o-", label=TITLES[view])
        numbers[view] = {
            "ceiling_pct": 100 * raw[0],
            "moved_2mm_pct": 100 * raw[4],
            "roi_consecutive_beat_mm": float(np.mean(roi)),
        }
        # single-frame blurred NCC against out-of-plane offset at one phase
        f0 = r.render(pose, 0.3 * period)
        numbers[view]["blurred_ncc_1mm_same_phase"] = blurred_ncc(
            f0.image,
            r.render(pose @ _shift(1.0), 0.3 * period).image,
            mask=f0.labels >= 0,
        )
    for a, title in zip(ax, ("raw NCC (the paper's)", "blurred, down-sampled NCC"), strict=True):
        a.axhline(89.8, color="k", ls=":", lw=0.8)
        a.axhline(81.1, color="gray", ls=":", lw=0.8)
        a.set_xlabel("out-of-plane offset from the view, next beat (mm)")
        a.set_ylabel("similarity over one beat (%)")
        a.set_title(title)
        a.legend(fontsize=8)
    fig.suptitle("Dotted: the paper's consecutive-beat ceiling (89.8 %) and return mean (81.1 %)")
    fig.tight_layout()
    fig.savefig(HERE / "us_similarity.png", dpi=80)
    plt.close(fig)
    return numbers


def _shift(dy_mm: float) -> np.ndarray:
    t = np.eye(4)
    t[1, 3] = dy_mm
    return t


def workspace_numbers() -> dict[str, float]:
    ph = default_phantom()
    knobs = np.radians(np.arange(-90.0, 91.0, 10.0))
    d4 = np.arange(-20.0, 21.0, 5.0)
    p1, p2, dd = np.meshgrid(knobs, knobs, d4, indexing="ij")
    q = np.stack([p1.ravel(), p2.ravel(), np.zeros(p1.size), dd.ravel()], -1)
    bend = np.degrees(np.hypot(q[:, 0], q[:, 1]))
    lab = ph.labels_at(tip2anatomy(q)[:, :3, 3], 0.0)
    blood = np.isin(lab, [int(b) for b in BLOOD_LABELS])
    out = {}
    for lim in (30, 45, 60, 130):
        m = bend <= lim
        out[f"ra_bend_le_{lim}"] = float(np.mean(lab[m] == Tissue.RA_BLOOD))
        out[f"blood_bend_le_{lim}"] = float(np.mean(blood[m]))
    return out


def main() -> None:
    r = UltrasoundRenderer()
    views_figure(r)
    print("contrast:", {k: round(v, 3) for k, v in effects_figure(r).items()})
    anatomy_figure()
    print("workspace fractions:", {k: round(v, 3) for k, v in workspace_numbers().items()})
    for view, nums in similarity_figure(r).items():
        print(view, {k: round(v, 3) for k, v in nums.items()})


if __name__ == "__main__":
    main()

"""Print the Table II summaries of docs/results.md from the held-out records of
``icenav eval recovery --json`` (one file per catheter / patient pair).

Usage::

    cd docs/figures
    python make_recovery_tables.py 'recovery_s6_in-vivo_seed11?_patient10?.json'
    python make_recovery_tables.py 'recovery_s6_phantom_seed11?_patient10?.json'

Per target: the mean over the pairs of each pair's mean, and in how many pairs the target
holds (in vivo static true tip < 1.0 mm and orientation < 1.5 deg, phantom < 0.5 mm and
< 0.5 deg; gated similarity within 3 points of the consecutive-beat ceiling); then, from
the records that keep each return's static error (session 7 on), in how many *returns*
each target holds, the worst return, and the returns the force check stopped.
"""

from __future__ import annotations

import glob
import json
import sys

import numpy as np

TARGETS = ("aortic_valve", "mitral_valve", "tricuspid_valve")
LIMITS = {"in-vivo": (1.0, 1.5), "phantom": (0.5, 0.5), "none": (0.5, 0.5)}


def _load(pattern: str) -> list[dict[str, object]]:
    files = sorted(glob.glob(pattern))
    if not files:
        raise SystemExit(f"no file matches {pattern!r}")
    out: list[dict[str, object]] = []
    for f in files:
        with open(f, encoding="utf-8") as fh:
            out.extend(json.load(fh))
    return out


def _mean(rows: list[dict[str, object]], key: str) -> float:
    vals = [float(r[key]) for r in rows if r.get(key) is not None]  # type: ignore[arg-type]
    return float(np.mean(vals)) if vals else float("nan")


def main(pattern: str) -> None:
    recs = _load(pattern)
    cond = str(recs[0]["condition"])
    mm_lim, deg_lim = LIMITS[cond]
    pairs = sorted({(r["seed"], r["patient"]) for r in recs})
    rounds = sorted({r["n_returns"] for r in recs})
    print(f"{cond}: {len(pairs)} pairs {pairs}, returns per target and mode {rounds}")
    ol = [r for r in recs if r["mode"] == "open_loop"]
    print("open loop, mean over pairs (all targets):")
    for key in (
        "tip_error_mm_mean",
        "em_orientation_error_deg_mean",
        "true_tip_error_gm_mm_mean",
        "similarity_true_gm_pct_mean",
        "similarity_ceiling_pct",
        "roi_true_gm_error_mm_mean",
        "roi_ceiling_mm",
    ):
        print(f"  {key:34s} {_mean(ol, key):7.2f}")
    print(
        f"| {cond} | open loop mm / deg | refined mm (< {mm_lim}) | refined deg (< {deg_lim})"
        " | gated sim. - consecutive ceiling (within 3 points) | undone |"
    )
    print("|---|---|---|---|---|---|")
    all_ol, all_rf = [], []
    for t in (*TARGETS, "all"):
        sel = TARGETS if t == "all" else (t,)
        o = [r for r in ol if r["target"] in sel]
        f = [r for r in recs if r["mode"] == "refined" and r["target"] in sel]
        if not f:
            continue
        mm = [float(r["true_static_tip_error_mm_mean"]) for r in f]  # type: ignore[arg-type]
        deg = [float(r["true_static_orientation_error_deg_mean"]) for r in f]  # type: ignore[arg-type]
        gap = [
            float(r["similarity_gated_pct_mean"]) - float(r["similarity_ceiling_pct"])  # type: ignore[arg-type]
            for r in f
        ]
        n = len(f)
        if t == "all":
            mx_mm = max(float(r["true_static_tip_error_mm_max"]) for r in f)  # type: ignore[arg-type]
            mx_deg = max(float(r["true_static_orientation_error_deg_max"]) for r in f)  # type: ignore[arg-type]
            print(
                f"| all | {_mean(o, 'true_static_tip_error_mm_mean'):.2f} / "
                f"{_mean(o, 'true_static_orientation_error_deg_mean'):.2f} | "
                f"{np.mean(mm):.2f} (largest {mx_mm:.2f}) | {np.mean(deg):.2f} (largest "
                f"{mx_deg:.2f}) | | {_mean(f, 'pose_stage_undone_fraction'):.2f} |"
            )
            continue
        all_ol.extend(o)
        all_rf.extend(f)
        print(
            f"| {t.split('_')[0]} | {_mean(o, 'true_static_tip_error_mm_mean'):.2f} / "
            f"{_mean(o, 'true_static_orientation_error_deg_mean'):.2f} | {np.mean(mm):.2f} "
            f"({sum(x < mm_lim for x in mm)} of {n} pairs) | {np.mean(deg):.2f} "
            f"({sum(x < deg_lim for x in deg)} of {n}) | {np.mean(gap):+.1f} "
            f"({sum(g >= -3.0 for g in gap)} of {n}) | "
            f"{_mean(f, 'pose_stage_undone_fraction'):.2f} |"
        )


def per_return(pattern: str) -> None:
    """Per target and mode: returns meeting each target, both, the worst, force stops."""
    recs = _load(pattern)
    cond = str(recs[0]["condition"])
    mm_lim, deg_lim = LIMITS[cond]
    print(f"per return ({cond}; < {mm_lim} mm, < {deg_lim} deg):")
    for mode in ("open_loop", "refined"):
        for t in (*TARGETS, "all"):
            sel = TARGETS if t == "all" else (t,)
            rs = [r for r in recs if r["mode"] == mode and r["target"] in sel]
            mm = [float(x) for r in rs for x in r.get("true_static_tip_errors_mm") or []]  # type: ignore[attr-defined]
            deg = [float(x) for r in rs for x in r.get("true_static_orientation_errors_deg") or []]  # type: ignore[attr-defined]
            stops = sum(int(r.get("returns_stopped") or 0) for r in rs)  # type: ignore[call-overload]
            if not mm:
                continue
            both = sum(a < mm_lim and b < deg_lim for a, b in zip(mm, deg, strict=True))
            n_mm, n_deg = sum(a < mm_lim for a in mm), sum(b < deg_lim for b in deg)
            print(
                f"  {mode:9s} {t.split('_')[0]:9s} n={len(mm):3d}  < mm {n_mm:3d}"
                f"  < deg {n_deg:3d}  both {both:3d}  worst "
                f"{max(mm):.2f} mm / {max(deg):.2f} deg  force stops {stops}"
            )


if __name__ == "__main__":
    for arg in sys.argv[1:] or ["docs/figures/recovery_s6_in-vivo_seed11?_patient10?.json"]:
        main(arg)
        per_return(arg)

"""Write ``catheter_tip.vtk``: the catheter's last 20 mm and the imaging direction, in the tip
frame (mm), as a legacy VTK polydata that ``icenav.mrml`` shows under ``TipToBase``.

The tip frame (icenav's ``tip2base``): z along the catheter (the shaft lies at z < 0), x the
imaging direction (the image plane is x-z). Run ``python examples/slicer/make_catheter_tip.py``
to write the file beside this script.
"""

from __future__ import annotations

import math
from pathlib import Path

RADIUS_MM = 1.65  # the catheter's radius (CatheterGeometry.catheter_radius, 10 Fr)
LENGTH_MM = 20.0  # shaft drawn behind the tip
ARROW_MM = 12.0  # imaging-direction arrow
SIDES = 16


def _ring(z: float, r: float) -> list[tuple[float, float, float]]:
    return [
        (r * math.cos(2 * math.pi * k / SIDES), r * math.sin(2 * math.pi * k / SIDES), z)
        for k in range(SIDES)
    ]


def polydata() -> tuple[list[tuple[float, float, float]], list[list[int]]]:
    """Points (mm, tip frame) and polygons: a closed cylinder z in [-LENGTH_MM, 0] and a
    square-section arrow along +x from the tip."""
    pts = _ring(-LENGTH_MM, RADIUS_MM) + _ring(0.0, RADIUS_MM)
    polys = [[k, (k + 1) % SIDES, SIDES + (k + 1) % SIDES, SIDES + k] for k in range(SIDES)]
    polys += [list(range(SIDES))[::-1], list(range(SIDES, 2 * SIDES))]  # the two caps
    base = len(pts)
    w = 0.4
    pts += [(0.0, -w, -w), (0.0, w, -w), (0.0, w, w), (0.0, -w, w), (ARROW_MM, 0.0, 0.0)]
    polys += [[base, base + 1, base + 4], [base + 1, base + 2, base + 4]]
    polys += [[base + 2, base + 3, base + 4], [base + 3, base, base + 4]]
    polys += [[base + 3, base + 2, base + 1, base]]
    return pts, polys


def write(path: Path) -> None:
    pts, polys = polydata()
    lines = ["# vtk DataFile Version 3.0", "icenav catheter tip (tip frame, mm)", "ASCII"]
    lines += ["DATASET POLYDATA", f"POINTS {len(pts)} float"]
    lines += [f"{x:.4f} {y:.4f} {z:.4f}" for x, y, z in pts]
    size = sum(len(p) + 1 for p in polys)
    lines.append(f"POLYGONS {len(polys)} {size}")
    lines += [" ".join(str(i) for i in [len(p), *p]) for p in polys]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


if __name__ == "__main__":
    write(Path(__file__).with_name("catheter_tip.vtk"))

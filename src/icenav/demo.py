"""``icenav demo``: until the console lands, a short headless run that prints the tip pose
of the constant-curvature model for a few knob settings."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

import numpy as np

from icenav.kinematics import CatheterGeometry, forward

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="icenav demo", description=__doc__)
    parser.add_argument("--headless", action="store_true", help="no browser (the default now)")
    parser.parse_args(argv)
    g = CatheterGeometry()
    print("icenav demo: tip of the image centre frame in the base frame (model, mm)")
    print(f"{'phi1 deg':>9} {'phi2 deg':>9} {'phi3 deg':>9} {'d4 mm':>7}   x, y, z (mm)")
    settings = [(0, 0, 0, 0), (30, 0, 0, 0), (0, 60, 0, 0), (45, 45, 90, 10), (90, -90, 0, -20)]
    for p1, p2, p3, d4 in settings:
        q = np.array([math.radians(p1), math.radians(p2), math.radians(p3), d4])
        pos = forward(q, g)[:3, 3]
        x, y, z = pos
        print(f"{p1:9.1f} {p2:9.1f} {p3:9.1f} {d4:7.1f}   {x:7.2f} {y:7.2f} {z:7.2f}")
    return 0

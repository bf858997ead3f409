"""``icenav eval spin --study``: accuracy of F against the number of calibration points and
the interpolant (beyond the paper), on one catheter in the straight vessel."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.compensation.elasticity import ElasticityMap, grid_subset_indices
from icenav.eval.spin import make_rig, run_calibration
from icenav.geometry.kinematics import forward

__all__ = ["calibration_study"]


def calibration_study(
    seed: int, sizes: Sequence[int] = (5, 9, 13, 25, 49, 361), n_test: int = 150
) -> list[dict[str, Any]]:
    """Accuracy of F against the number of calibration points (beyond the paper).

    Subsets of the dense raster (5 = the paper's five points taken from the grid, 9, 13,
    25, 49, all 361) and the 5-point *search*; each F drives the plant from rest to random
    model knob pairs within +-60 deg, and the true tip's distance from the model tip is
    measured (RMS, mm). Also compares interpolants on the full set.
    """
    plant, tracker = make_rig(seed, "straight")
    dense = run_calibration("dense", plant, tracker).calibration_set
    five = run_calibration("five_point", plant, tracker).calibration_set
    rng = np.random.default_rng(seed)
    k = rng.uniform(-1.0, 1.0, (n_test, 2)) * math.radians(60.0)
    q = np.zeros((n_test, 4))
    q[:, :2] = k
    target = forward(q)[:, :3, 3]

    def accuracy(fn: Callable[[Array, Array], tuple[Array, Array]]) -> float:
        a, b = fn(k[:, 0], k[:, 1])
        err = []
        for i in range(n_test):
            plant.reset()
            err.append(np.linalg.norm(plant.move([a[i], b[i], 0.0, 0.0])[:3, 3] - target[i]))
        return float(np.sqrt(np.mean(np.square(err))))

    rows: list[dict[str, Any]] = [
        {"set": "none", "n_points": 0, "interpolant": "-", "rms_mm": accuracy(lambda a, b: (a, b))}
    ]
    for n in sizes:
        sub = dense if n == dense.n_samples else dense.subset(grid_subset_indices(dense.q_motor, n))
        m = ElasticityMap.build(sub)
        rows.append(
            {
                "set": f"grid subset {n}",
                "n_points": sub.n_samples,
                "interpolant": m.report.interpolant,
                "rms_mm": accuracy(m.model_to_motor_knobs),
            }
        )
    m = ElasticityMap.build(five)
    rows.append(
        {
            "set": "5-point search",
            "n_points": 5,
            "interpolant": m.report.interpolant,
            "rms_mm": accuracy(m.model_to_motor_knobs),
        }
    )
    m = ElasticityMap.build(five, relative_to_model=False)
    rows.append(
        {
            "set": "5-point search, raw positions (paper)",
            "n_points": 5,
            "interpolant": "rbf",
            "rms_mm": accuracy(m.model_to_motor_knobs),
        }
    )
    for label, kw in (
        ("spline s=0", {"interpolant": "spline", "smoothing": 0.0}),
        ("spline s=n*(0.7 mm)^2 (default)", {"interpolant": "spline"}),
        ("spline s=n*(1.4 mm)^2", {"interpolant": "spline", "smoothing": 1.96 * dense.n_samples}),
        ("thin-plate rbf", {"interpolant": "rbf"}),
        ("clough-tocher", {"interpolant": "clough-tocher"}),
        ("spline, raw positions (paper)", {"interpolant": "spline", "relative_to_model": False}),
    ):
        m = ElasticityMap.build(dense, **kw)
        rows.append(
            {
                "set": f"dense: {label}",
                "n_points": dense.n_samples,
                "interpolant": m.report.interpolant,
                "rms_mm": accuracy(m.model_to_motor_knobs),
            }
        )
    return rows

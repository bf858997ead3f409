"""Shared helpers of the geometry tests."""

from __future__ import annotations

import math

import numpy as np

from icenav.geometry.kinematics import CatheterGeometry

G = CatheterGeometry()


def random_q(rng: np.random.Generator, n: int, geometry: CatheterGeometry = G) -> np.ndarray:
    lim = geometry.knob_limit
    lo, hi = geometry.translation_limits
    return np.column_stack(
        [
            rng.uniform(-lim, lim, (n, 2)),
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(lo, hi, n),
        ]
    )

"""Shared helpers of the calibration tests: a small synthetic catheter (per-joint backlash,
dead-zone and a knob-frame distortion) and a tracker that reads it exactly, with dropouts."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from icenav.geometry.kinematics import forward

DEG = math.pi / 180


def distortion(k: np.ndarray) -> np.ndarray:
    c, s = math.cos(6 * DEG), math.sin(6 * DEG)
    r2 = np.sum(k * k, axis=-1, keepdims=True) / (math.pi / 2) ** 2
    return (k @ np.array([[c, -s], [s, c]]).T) * (1.1 - 0.1 * r2)


class SyntheticCatheter:
    """Motor knobs -> per-joint backlash (half-width r) + dead-zone d -> distortion -> FK."""

    def __init__(
        self, r: tuple[float, float, float] = (0, 0, 0), d: float = 0.0, roll_per_bend: float = 0.0
    ) -> None:
        self.r = r
        self.d = d
        self.roll_per_bend = roll_per_bend
        self.p = [0.0, 0.0, 0.0]
        self.moves = 0

    def move(self, q: ArrayLike) -> None:
        q = np.asarray(q, dtype=np.float64)
        for j in range(3):
            w = self.r[j] + (self.roll_per_bend * math.hypot(self.p[0], self.p[1]) if j == 2 else 0)
            self.p[j] = min(max(self.p[j], q[j] - w), q[j] + w)
        self.q = q
        self.moves += 1

    def pose(self) -> np.ndarray:
        eff = np.array(
            [np.sign(v) * max(abs(v) - self.d, 0.0) for v in self.p[:2]], dtype=np.float64
        )
        k = distortion(eff[None, :])[0]
        return forward(np.array([k[0], k[1], self.p[2], 0.0]), check=False)


class Tracker:
    """Reads the synthetic catheter; returns None for the attempts listed in ``misses``."""

    def __init__(self, cath: SyntheticCatheter, misses: set[int] | None = None) -> None:
        self.cath = cath
        self.misses = misses or set()
        self.calls = 0

    def measure_tip2base(self, n_average: int = 1) -> np.ndarray | None:
        self.calls += 1
        if self.calls in self.misses:
            return None
        return self.cath.pose()

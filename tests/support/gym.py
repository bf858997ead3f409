"""Plant families for the gymnasium environments' tests (the twin's plug-in convention:
``factory(seed, vessel) -> (plant, tracker)``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.geometry.kinematics import forward


@dataclass(frozen=True)
class KinematicState:
    """What the environments read of a plant's state."""

    tip2base: Array
    """(4, 4) tip pose (mm)."""
    contact_force_n: float = 0.0
    """Contact force on the anatomy (N)."""


class KinematicPlant:
    """A catheter that is exactly the constant-curvature model (no elasticity, no play)
    and, past ``wall_mm`` of translation, presses on a wall with ``stiffness_n_per_mm``."""

    def __init__(self, wall_mm: float = np.inf, stiffness_n_per_mm: float = 0.0) -> None:
        self.wall_mm = wall_mm
        self.stiffness_n_per_mm = stiffness_n_per_mm
        self.q = np.zeros(4)

    def reset(self, q_motor: ArrayLike | None = None) -> None:
        self.q = np.zeros(4) if q_motor is None else np.asarray(q_motor, dtype=np.float64)

    def move(self, q_motor: ArrayLike) -> Array:
        self.q = np.asarray(q_motor, dtype=np.float64)
        return forward(self.q)

    @property
    def state(self) -> KinematicState:
        push = max(0.0, abs(float(self.q[3])) - self.wall_mm)
        return KinematicState(forward(self.q), self.stiffness_n_per_mm * push)


def kinematic_factory(seed: int, vessel: str) -> tuple[KinematicPlant, None]:
    """The model itself as the plant (no tracker)."""
    return KinematicPlant(), None


def walled_factory(seed: int, vessel: str) -> tuple[KinematicPlant, None]:
    """The model with a wall beyond 5 mm of translation (0.2 N/mm)."""
    return KinematicPlant(wall_mm=5.0, stiffness_n_per_mm=0.2), None

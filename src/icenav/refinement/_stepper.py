"""The mechanics shared by the refinement stages: a search written as a generator of move /
measure requests, run one set-point per control cycle inside a box around the view."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from icenav._typing import Array
from icenav.errors import NeighbourhoodError

__all__: list[str] = []


@dataclass(frozen=True)
class _Move:
    q: Array


@dataclass(frozen=True)
class _Measure:
    pass


@dataclass(frozen=True)
class _MeasurePose:
    """The pose stage's request: hold and measure."""


@dataclass(frozen=True)
class _WaitExpiration:
    """The pose stage's request: hold until end-expiration (Eq. R3)."""


_Request = _Move | _Measure
"""What the search asks for next: a move to a state, or one beat measured there."""


class _Stepper:
    """Runs a generator of move / measure requests one set-point per control cycle, inside a
    box around ``q_view`` (shared mechanics of the refinement stages)."""

    def __init__(
        self,
        q_view: Array,
        q_start: Array,
        radius: Array,
        max_velocity: Array,
        abort: Callable[[], bool] | None,
        last_dir: Array | None = None,
        label: str = "set-point",
    ) -> None:
        self.q_view = q_view
        self.radius = radius
        self.lo = q_view - radius
        self.hi = q_view + radius
        self.max_velocity = max_velocity
        self.abort = abort
        self.cmd = q_start.copy()
        self.last_dir = np.zeros(4) if last_dir is None else last_dir.copy()
        self.label = label
        self.queue: list[Array] = []
        self.elapsed = 0.0
        self.n_cmd = 0
        self.max_off = np.zeros(4)

    def send(self, q: Array) -> Array:
        off = np.abs(q - self.q_view)
        if np.any(off > self.radius * (1 + 1e-9) + 1e-12):
            j = int(np.argmax(off / self.radius))
            raise NeighbourhoodError(
                f"{self.label} {q.tolist()} is {off[j]:.4g} from the view on joint {j}, "
                f"outside the radius {self.radius[j]:.4g} (rad, rad, rad, mm)"
            )
        moved = np.sign(q - self.cmd)
        self.last_dir = np.where(moved != 0, moved, self.last_dir)
        self.max_off = np.maximum(self.max_off, off)
        self.cmd = q.copy()
        self.n_cmd += 1
        return q.copy()

    def queue_moves(self, targets: Sequence[Array], dt: float) -> None:
        v = self.max_velocity * dt
        for target in targets:
            base = self.queue[-1] if self.queue else self.cmd
            delta = target - base
            n = max(1, math.ceil(float(np.max(np.abs(delta) / v)) - 1e-9))
            f = np.arange(1, n + 1)[:, None] / n
            pts = base + f * delta
            pts[-1] = target
            self.queue.extend(list(pts))

"""Returns that stay safe: the contact force the operator's own trace produced at each
recorded state, and the limit a return along the roadmap must keep (beyond the paper).

A return replays travelled states, which is safe only while the anatomy is where it was.
When the patient moved, the same motor states push the catheter into a wall. With a
contact-force channel on the robot (a load cell at the sheath, tendon tensions, or drive
currents: :class:`ForceSensor`, None when the robot has none), the roadmap's recorder keeps,
per vertex, the largest force read while the *operator* drove through it
(:class:`ForceMap`; states a return or a refinement commanded are not the operator's trace
and are not recorded). Along a return (Eq. F1), at path point ``i`` between vertices
``v_i`` and ``v_(i+1)``, with ``F_rec = max(F_rec(v_i), F_rec(v_(i+1)))`` and ``F_rec(v)``
the largest force recorded within epsilon of ``v`` (the operator passed those states at
other moments of the beat and the breath)::

    F_measured  <=  F_rec + margin_n + margin_fraction * F_rec                    (F1)

else the return stops, says so (the task fails with the reason) and the robot holds.
Vertices without a recorded force (never driven by the operator with the sensor on) take
the nearest recorded value along the path; a path with none has no check. Without a force
channel there is no check at all (documented in ``docs/view-recovery.md``).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.errors import ConfigurationError, ShapeError
from icenav.recovery.roadmap import Roadmap

__all__ = [
    "DEFAULT_MARGIN_FRACTION",
    "DEFAULT_MARGIN_N",
    "ForceMap",
    "ForceSensor",
    "force_excess",
    "force_limit",
]

DEFAULT_MARGIN_N = 0.1
"""Absolute margin of Eq. (F1) (N)."""
DEFAULT_MARGIN_FRACTION = 1.0
"""Relative margin of Eq. (F1): the contact force at the same motor state varies with the
heart beat, breathing and the shaft's lost motion roughly in proportion to it (on the twin
in vivo a state the operator passed at 3.3 N read up to 5.7 N on a later return). Measured
false alarms and what a shift adds: ``docs/view-recovery.md``."""


class ForceSensor(Protocol):
    """A robot's contact-force channel (a real robot may estimate it from the drive currents,
    the tendon tensions or a load cell at the sheath)."""

    def contact_force_n(self) -> float | None:
        """Total contact force on the catheter now (N), None when unavailable."""
        ...


class ForceMap:
    """Per roadmap vertex, the largest contact force the operator's trace produced there (N).

    Parameters
    ----------
    capacity : int
        Initial number of vertex slots (grown by doubling).
    """

    def __init__(self, capacity: int = 1024) -> None:
        self._f = np.full(max(16, int(capacity)), np.nan)
        self._n = 0

    @property
    def n_recorded(self) -> int:
        """Vertices with a recorded force."""
        return int(np.count_nonzero(np.isfinite(self._f[: self._n])))

    def record(self, vertex: int, force_n: float | None) -> None:
        """Note ``force_n`` (N) read at ``vertex`` while the operator drove (ignored when the
        vertex is -1, not recorded, or the force is None)."""
        if vertex < 0 or force_n is None:
            return
        f = float(force_n)
        if not (math.isfinite(f) and f >= 0.0):
            raise ConfigurationError(f"a contact force must be finite and >= 0 N, got {force_n}")
        if vertex >= len(self._f):
            grown = np.full(max(2 * len(self._f), vertex + 1), np.nan)
            grown[: len(self._f)] = self._f
            self._f = grown
        old = self._f[vertex]
        self._f[vertex] = f if not np.isfinite(old) else max(float(old), f)
        self._n = max(self._n, vertex + 1)

    def at(self, vertices: ArrayLike) -> Array:
        """Recorded force (N) at each vertex id (NaN where none)."""
        ids = np.asarray(vertices, np.int64)
        out = np.full(ids.shape, np.nan)
        ok = (ids >= 0) & (ids < self._n)
        out[ok] = self._f[ids[ok]]
        return out

    def profile(
        self, roadmap: Roadmap, path: ArrayLike, radius: float | None = None
    ) -> Array | None:
        """The recorded force (N) at each state of a planned ``path`` (n, 4): the largest
        recorded at the vertices within ``radius`` of it (metric units; default the
        roadmap's epsilon: the operator passed them at other moments of the beat and the
        breath), gaps filled with the nearest recorded value along the path; None when no
        state of the path has one (no check)."""
        p = np.asarray(path, np.float64)
        if p.ndim != 2 or p.shape[1] != 4:
            raise ShapeError(f"path must have shape (n, 4), got {p.shape}")
        r = roadmap.epsilon if radius is None else float(radius)
        f = np.full(len(p), np.nan)
        for i, q in enumerate(p):
            ids, _ = roadmap.neighbours(q, r)
            vals = self.at(ids)
            if np.isfinite(vals).any():
                f[i] = float(np.nanmax(vals))
        known = np.flatnonzero(np.isfinite(f))
        if not len(known):
            return None
        nearest = known[np.abs(np.arange(len(p))[:, None] - known[None, :]).argmin(axis=1)]
        out: Array = f[nearest]
        return out


def force_limit(
    profile: Array,
    index: int,
    margin_n: float = DEFAULT_MARGIN_N,
    margin_fraction: float = DEFAULT_MARGIN_FRACTION,
) -> tuple[float, float]:
    """(recorded force, limit) of Eq. (F1) between path states ``index`` and ``index + 1``
    (N)."""
    i = min(max(int(index), 0), len(profile) - 1)
    j = min(i + 1, len(profile) - 1)
    rec = max(float(profile[i]), float(profile[j]))
    return rec, rec + float(margin_n) + float(margin_fraction) * rec


def force_excess(
    profile: Array,
    index: int,
    force_n: float,
    margin_n: float = DEFAULT_MARGIN_N,
    margin_fraction: float = DEFAULT_MARGIN_FRACTION,
) -> float:
    """How far ``force_n`` exceeds the limit of Eq. (F1) between path states ``index`` and
    ``index + 1`` (N; <= 0: within)."""
    return float(force_n) - force_limit(profile, index, margin_n, margin_fraction)[1]

"""How a roadmap measures motor states, its settings, and the arrival direction of joints.

:class:`RoadmapMetric` maps a motor state ``q = (phi1, phi2, phi3, d4)`` (rad, rad, rad, mm)
to metric coordinates ``x = scale * q`` (1 mm == 1 deg by default, the paper's metric);
:class:`RoadmapConfig` holds a :class:`icenav.recovery.roadmap.Roadmap`'s settings;
:func:`direction_tracker` gives the side from which each joint arrived (backlash).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_positive
from icenav.errors import ConfigurationError

__all__ = [
    "DirectionTracker",
    "RoadmapConfig",
    "RoadmapMetric",
    "approach_ids",
    "direction_tracker",
]

_DEG_PER_RAD = 180.0 / math.pi


@dataclass(frozen=True)
class RoadmapMetric:
    """How joint motions are weighed: metric units per degree of knob / roll, per mm.

    The distance between two motor states is ``|scale * (q_a - q_b)|`` (Euclidean) with
    ``scale = (kw*180/pi, kw*180/pi, rw*180/pi, tw)``. The paper's metric (1 mm == 1 deg,
    for the knobs and, as we read it, for roll too) is the default.
    """

    knob_weight: float = 1.0
    """Metric units per degree of either knob (phi1, phi2)."""
    roll_weight: float = 1.0
    """Metric units per degree of bulk rotation (phi3)."""
    translation_weight: float = 1.0
    """Metric units per millimetre of translation (d4)."""

    def __post_init__(self) -> None:
        check_positive(self.knob_weight, "knob_weight", "metric units/deg")
        check_positive(self.roll_weight, "roll_weight", "metric units/deg")
        check_positive(self.translation_weight, "translation_weight", "metric units/mm")

    @property
    def scale(self) -> Array:
        """(4,) metric units per motor unit (per rad, rad, rad, mm)."""
        kw = self.knob_weight * _DEG_PER_RAD
        return np.array([kw, kw, self.roll_weight * _DEG_PER_RAD, self.translation_weight])

    def distance(self, q_a: ArrayLike, q_b: ArrayLike) -> Array:
        """Distance(s) between motor states, shape (...,), in metric units."""
        d = (np.asarray(q_a, np.float64) - np.asarray(q_b, np.float64)) * self.scale
        return np.asarray(np.sqrt(np.sum(d * d, axis=-1)))


@dataclass(frozen=True)
class RoadmapConfig:
    """Settings of a :class:`Roadmap` (all distances in metric units, see RoadmapMetric)."""

    epsilon: float = 1.0
    """Density parameter of Algorithm 1: vertices closer than this are connected."""
    merge_radius: float | None = None
    """A state within this distance of an existing vertex is merged into it (not a new
    vertex); ``None`` means ``epsilon / 4``. Must be < epsilon."""
    metric: RoadmapMetric = field(default_factory=RoadmapMetric)
    """Weights of the joints in the distance."""
    direction_threshold: float = 2.0
    """A joint motion larger than this (in that joint's metric units) sets the joint's
    arrival direction; smaller reversals are ignored (noise, dither). The recorded approach
    of a view reaches back until each joint moved twice this towards it, so it should be of
    the order of the transmission's backlash (on the twin's catheter, 2 gave 4-10x smaller
    return errors than no approach, 5 (with approach_length 40) about 15-100x)."""
    approach_length: float = 20.0
    """Longest recorded trace (path length) kept as a view's same-direction approach."""
    max_vertices: int | None = 250_000
    """Vertex budget (None: unbounded). From 80 % of it on, a state merges into any vertex
    within epsilon (coarse merging); from ``max_vertices - view_reserve`` (90 %) on, a
    state farther than epsilon from every vertex is not recorded (the trace is broken
    there) until a view is saved out there: then the stretch travelled since the roadmap
    was left is recorded from the reserve, so the view stays reachable. See
    ``docs/view-recovery.md`` ("Vertex budget")."""
    tree_cache: int = 8
    """Shortest-path trees kept (least recently used dropped), each 12 bytes a vertex."""

    def __post_init__(self) -> None:
        eps = check_positive(self.epsilon, "epsilon", "metric units (1 mm == 1 deg)")
        if self.max_vertices is not None and (
            isinstance(self.max_vertices, bool)
            or not isinstance(self.max_vertices, int | np.integer)
            or self.max_vertices < 1000
        ):
            raise ConfigurationError(
                f"max_vertices must be None or an integer >= 1000 vertices, got "
                f"{self.max_vertices!r}"
            )
        if (
            isinstance(self.tree_cache, bool)
            or not isinstance(self.tree_cache, int | np.integer)
            or not 1 <= self.tree_cache <= 1024
        ):
            raise ConfigurationError(
                f"tree_cache must be an integer in [1, 1024] trees, got {self.tree_cache!r}"
            )
        if self.merge_radius is not None:
            r = check_positive(self.merge_radius, "merge_radius", "metric units")
            if r >= eps:
                raise ConfigurationError(
                    f"merge_radius must be < epsilon = {eps} metric units, got {r}"
                )
        check_positive(self.direction_threshold, "direction_threshold", "metric units")
        check_positive(self.approach_length, "approach_length", "metric units")

    @property
    def resolution(self) -> float:
        """The merge radius in use (metric units)."""
        return self.epsilon / 4.0 if self.merge_radius is None else float(self.merge_radius)

    @property
    def view_reserve(self) -> int:
        """Vertex slots kept for views (and the excursion trails that lead to them) at the
        end of the budget (10 %, at least 64)."""
        if self.max_vertices is None:
            return 0
        return max(64, int(self.max_vertices) // 10)


def direction_tracker(
    path: ArrayLike, threshold: ArrayLike, initial: Sequence[int] = (0, 0, 0, 0)
) -> tuple[int, int, int, int]:
    """Arrival direction of each joint after moving along ``path``.

    Parameters
    ----------
    path : array-like, shape (n, 4)
        Motor states (rad, rad, rad, mm), in order.
    threshold : array-like, shape (4,)
        Per joint, the smallest reversal (motor units) that changes the direction.
    initial : 4 ints in (-1, 0, 1)
        Direction before the path.

    Returns
    -------
    direction : tuple of 4 ints in (-1, 0, 1)
        Sign of the last significant motion of each joint.
    """
    p = np.asarray(path, np.float64)
    thr = np.asarray(threshold, np.float64)
    tracker = DirectionTracker(thr, p[0], initial)
    for q in p[1:]:
        tracker.update(q)
    return tracker.direction


class DirectionTracker:
    """Per joint: sign of the last motion exceeding a threshold (a backlash-side tracker)."""

    def __init__(self, threshold: Array, q0: Array, initial: Sequence[int] = (0, 0, 0, 0)):
        self.threshold = [float(t) for t in threshold]
        self.anchor = [float(v) for v in q0]
        self.dirs = [int(d) for d in initial]

    def update(self, q: Array | list[float]) -> None:
        for j in range(4):
            v = float(q[j])
            delta = v - self.anchor[j]
            d = self.dirs[j]
            if d != 0 and delta * d >= 0.0:
                self.anchor[j] = v  # still moving (or resting) the same way
            elif abs(delta) > self.threshold[j]:
                self.dirs[j] = 1 if delta > 0 else -1
                self.anchor[j] = v

    @property
    def direction(self) -> tuple[int, int, int, int]:
        d = self.dirs
        return (d[0], d[1], d[2], d[3])


def approach_ids(
    trace: NDArray[np.int32],
    q: Array,
    x: Array,
    direction: Sequence[int],
    threshold: Array,
    approach_length: float,
    epsilon: float,
    long_edges: set[tuple[int, int]],
) -> list[int]:
    """A view's recorded approach: the trace vertices that led to the last one, oldest
    first, ending at it.

    Walks back along ``trace`` (vertex ids, the view's last) until every joint with an
    arrival ``direction`` has moved at least twice its ``threshold`` (motor units) towards
    the view, or until ``approach_length`` (metric units); stops where the trace broke (a
    step longer than ``epsilon`` that is not a travelled edge of ``long_edges``). ``q``,
    ``x``: (n, 4) motor states and metric coordinates of the vertices.
    """
    vid = int(trace[-1])
    d = np.array(direction, np.float64)
    need = d != 0
    q_view = q[vid]
    ids = [vid]
    length = 0.0
    reached = np.zeros(4, bool)
    for k in range(len(trace) - 2, -1, -1):
        if not np.any(need & ~reached):
            break
        u = int(trace[k])
        step = float(np.sqrt(np.sum((x[u] - x[ids[-1]]) ** 2)))
        if length + step > approach_length:
            break
        if step > epsilon and (min(u, ids[-1]), max(u, ids[-1])) not in long_edges:
            break  # the trace broke here (restart, unrecorded stretch): not travelled
        length += step
        ids.append(u)
        reached |= (q_view - q[u]) * d >= 2.0 * threshold
    ids.reverse()
    return ids

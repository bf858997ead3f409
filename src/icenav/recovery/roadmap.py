"""Incremental roadmap of visited motor states and exact shortest-path planning over it.

The paper's Algorithm 1 (Section III-D): every new operator state ``q_n`` becomes a vertex
and is connected to every vertex within ``epsilon``; a return to a saved view is a discrete
A* search over this graph, so the catheter only passes through states the operator has
already visited. What we add (see ``docs/view-recovery.md``):

* The metric. The paper assumes 1 mm == 1 deg. We map a motor state ``q = (phi1, phi2,
  phi3, d4)`` (rad, rad, rad, mm) to *metric coordinates* ``x = scale * q`` with
  ``scale = (kw * 180/pi, kw * 180/pi, rw * 180/pi, tw)`` (a frozen :class:`RoadmapMetric`,
  all weights 1 by default: one degree of knob, one degree of roll and one millimetre of
  translation each count as one metric unit) and use the Euclidean distance in ``x``.
  Roll is a multi-turn motor angle and is not wrapped (360 deg apart is a different motor
  state: the shaft has wound up).
* Consecutive trace states are always connected (the operator travelled between them, even
  when a fast move jumps more than ``epsilon``).
* Near-duplicate states (within ``merge_radius``, default ``epsilon / 4``) are merged into
  the existing vertex, so dwelling at a view does not pile up vertices.
* Neighbour search by spatial hashing on a grid of cell size ``4 * epsilon`` (an
  ``epsilon``-ball touches at most 2 cells per axis, about 5 on average in 4-D), not a scan
  of every vertex.
* Vertices and edges live in numpy arrays grown by doubling; a CSR matrix is built lazily
  when planning, and the shortest-path tree to each goal (``scipy.sparse.csgraph.dijkstra``
  from the goal) is cached and, when the graph grows, repaired with the new edges only
  (adding edges can only shorten distances). A pure-Python A* with the Euclidean
  heuristic over the same CSR arrays is available (``method="astar"``) and returns paths
  exactly as short (the heuristic is consistent: edge weights are Euclidean distances).
* A vertex budget (``RoadmapConfig.max_vertices``, default 250,000) bounds memory over a
  long procedure: coarse merging from 80 % of it, no new territory recorded from 90 %
  except the excursions that lead to a saved view or to the start of a return; nothing is
  ever dropped, so views stay exact and their paths intact (``docs/view-recovery.md``).
* Each view remembers the direction from which every joint arrived; ``plan(...,
  approach=True)`` ends by replaying the recorded trace that led to the view, so the
  transmission's backlash is taken up the same way as when the view was saved.
"""

from __future__ import annotations

import array
import atexit
import heapq
import itertools
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.csgraph import dijkstra

from icenav._typing import Array
from icenav._validation import check_joint_state, check_positive
from icenav.errors import (
    ConfigurationError,
    GoalUnreachableError,
    PlanningError,
    RoadmapFullError,
    ShapeError,
)
from icenav.recovery.views import View

__all__ = [
    "Roadmap",
    "RoadmapConfig",
    "RoadmapFullError",
    "RoadmapMetric",
    "direction_tracker",
    "warm_up_planner",
]

_DEG_PER_RAD = 180.0 / math.pi
_EXCURSION_MAX = 2048
"""Longest excursion trail kept while the vertex budget is closed (states more than
epsilon apart, so at least 2048 metric units of travel)."""

IntArray = NDArray[np.int64]


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
    tracker = _DirectionTracker(thr, p[0], initial)
    for q in p[1:]:
        tracker.update(q)
    return tracker.direction


class _DirectionTracker:
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


class Roadmap:
    """Incremental roadmap over motor joint states (Algorithm 1 plus the additions above).

    Parameters
    ----------
    epsilon : float
        Density parameter (metric units, 1 mm == 1 deg); ignored when ``config`` is given.
    config : RoadmapConfig, optional
        All settings.
    capacity : int
        Initial number of vertex slots (grown by doubling).
    """

    def __init__(
        self, epsilon: float = 1.0, *, config: RoadmapConfig | None = None, capacity: int = 1024
    ) -> None:
        self._config = config if config is not None else RoadmapConfig(epsilon=epsilon)
        cfg = self._config
        self._eps = float(cfg.epsilon)
        self._res = float(cfg.resolution)
        self._cell = 4.0 * self._eps
        self._scale = cfg.metric.scale
        self._scale_list = [float(s) for s in self._scale]
        cap = max(16, int(capacity))
        self._q = np.empty((cap, 4))
        self._x = np.empty((cap, 4))
        self._n = 0
        self._eu = np.empty(4 * cap, np.int32)  # int32 ids: 16 bytes an edge with w
        self._ev = np.empty(4 * cap, np.int32)
        self._ew = np.empty(4 * cap)
        self._m = 0
        self._long_edges: set[tuple[int, int]] = set()
        # cell -> vertex ids; array.array rather than list: 8 bytes an id, no int objects,
        # and not a container the garbage collector has to traverse
        self._grid: dict[tuple[int, int, int, int], array.array[int]] = {}
        self._trace = np.empty(cap, np.int32)
        self._t = 0
        self._current = -1
        self._cur_x: list[float] = []  # metric coordinates of the current vertex
        self._prev_list: list[float] | None = None
        self._tracker: _DirectionTracker | None = None
        self._thr = cfg.direction_threshold / self._scale
        self._version = 0
        self._csr: sp.csr_matrix | None = None  # edges (u, v) as stored: one direction
        self._csr_t: sp.csr_matrix | None = None  # its transpose (the other direction)
        self._csr_version = -1
        self._csr_m = 0  # edges [0, _csr_m) are in the CSR
        self._delta: sp.csr_matrix | None = None  # symmetric CSR of edges [_csr_m, m)
        self._delta_key = (-1, -1, -1)  # (_csr_m, m, n) the delta was built for
        self._trees: dict[int, _Tree] = {}  # least recently used first
        # the vertex budget (see RoadmapConfig.max_vertices)
        big = np.iinfo(np.int64).max
        mv = cfg.max_vertices
        self._max_n = big if mv is None else int(mv)
        self._closed_from = big if mv is None else int(mv) - cfg.view_reserve
        self._coarse_from = big if mv is None else min(self._closed_from, int(0.8 * int(mv)))
        self._n_unrecorded = 0
        self._exit = -1  # vertex where an unrecorded excursion left the roadmap (-1: none)
        self._excursion: list[list[float]] = []  # its states, > epsilon apart
        self._excursion_x: list[float] = []
        self._n_isolated_views = 0

    # --- properties -------------------------------------------------------------------

    @property
    def config(self) -> RoadmapConfig:
        """The settings."""
        return self._config

    @property
    def epsilon(self) -> float:
        """Density parameter (metric units)."""
        return self._eps

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return self._n

    @property
    def n_edges(self) -> int:
        """Number of (undirected) edges."""
        return self._m

    @property
    def n_trace(self) -> int:
        """Length of the recorded vertex trace."""
        return self._t

    @property
    def version(self) -> int:
        """Incremented whenever a vertex or an edge is added."""
        return self._version

    @property
    def current_vertex(self) -> int:
        """Vertex of the latest state (-1 before the first state, and while the latest state
        was not recorded: see :attr:`recording`)."""
        return self._current

    @property
    def recording(self) -> bool:
        """Whether the latest state was recorded (False when the vertex budget is closed
        and the state lies farther than epsilon from every vertex)."""
        return self._current >= 0

    @property
    def n_unrecorded(self) -> int:
        """States not recorded because the vertex budget was closed (see RoadmapConfig)."""
        return self._n_unrecorded

    @property
    def n_isolated_views(self) -> int:
        """Views saved (or :meth:`anchor` calls made) out of recorded territory whose
        excursion could not be recorded (longer than the trail kept, or no room left in the
        budget): no path leads to them."""
        return self._n_isolated_views

    @property
    def merge_radius_now(self) -> float:
        """The merge radius in use for the next state (metric units): the configured one,
        or epsilon once 80 % of the vertex budget is used."""
        return self._eps if self._n >= self._coarse_from else self._res

    @property
    def current_state(self) -> Array | None:
        """(4,) the latest state passed to :meth:`add` (motor units), or None."""
        return None if self._prev_list is None else np.array(self._prev_list)

    @property
    def arrival_direction(self) -> tuple[int, int, int, int]:
        """Sign of the last significant motion of each joint (0: none yet)."""
        return (0, 0, 0, 0) if self._tracker is None else self._tracker.direction

    @property
    def direction_threshold_motor(self) -> Array:
        """(4,) the direction threshold per joint in motor units (rad, rad, rad, mm)."""
        return self._thr.copy()

    def vertices(self, start: int = 0, stop: int | None = None) -> Array:
        """(stop - start, 4) motor states of vertices ``start..stop-1`` (default: to the
        end; read-only view).

        Rows below a count read earlier never change (the arrays are append-only), so
        another thread may read ``vertices(a, b)`` with ``b <= n_vertices`` read before,
        while this roadmap grows (the store's writer thread does).
        """
        q = self._q  # read once: a concurrent growth replaces the array, not its rows
        v = q[start : self._n if stop is None else stop]
        v.flags.writeable = False
        return v

    def edges(self, start: int = 0, stop: int | None = None) -> tuple[IntArray, Array]:
        """Edges ``start..stop-1`` (default: to the end): (k, 2) vertex id pairs and (k,)
        lengths (metric units). Safe from another thread as :meth:`vertices` is."""
        m = self._m if stop is None else stop
        eu, ev, ew = self._eu, self._ev, self._ew
        uv = np.stack([eu[start:m], ev[start:m]], axis=1).astype(np.int64)
        return uv, ew[start:m].copy()

    def trace(self, start: int = 0, stop: int | None = None) -> IntArray:
        """Vertex ids visited in order (consecutive duplicates removed), ``start..stop-1``
        (default: to the end). Safe from another thread as :meth:`vertices` is."""
        tr = self._trace
        return tr[start : self._t if stop is None else stop].astype(np.int64)

    def counts(self) -> tuple[int, int, int]:
        """(n_vertices, n_edges, n_trace) read together (for a consistent snapshot)."""
        return self._n, self._m, self._t

    def metric_coordinates(self, q: ArrayLike) -> Array:
        """Metric coordinates ``x = scale * q`` of motor state(s), shape (..., 4)."""
        return np.asarray(q, np.float64) * self._scale

    # --- construction (Algorithm 1) -----------------------------------------------------

    def add(self, q: ArrayLike, *, force_vertex: bool = False, check: bool = True) -> int:
        """Record the operator's current motor state; return the vertex that holds it.

        Algorithm 1, lines 5-13: a state equal to the previous one is ignored; otherwise it
        becomes a new vertex connected to every vertex within ``epsilon``, unless it lies
        within ``merge_radius`` of an existing vertex (then it is merged into that vertex).
        Either way, the vertex of the previous state and this one are connected.

        Vertex budget (``config.max_vertices``): from 90 % of it on, the merge radius is
        epsilon; once only the view reserve is left, a state farther than epsilon from
        every vertex is not recorded and -1 is returned (see :attr:`recording`).

        Parameters
        ----------
        q : array-like, shape (4,)
            Motor joint state (phi1 rad, phi2 rad, phi3 rad, d4 mm).
        force_vertex : bool
            Make ``q`` itself a vertex (used when a view is saved, so the view's state is
            recorded exactly), unless a vertex with exactly these coordinates exists; it
            may use the view reserve of the budget (RoadmapFullError when none is left).
        check : bool
            Validate ``q``; ``False`` for hot loops.
        """
        if check:
            qa = check_joint_state(q, name="q")
            if qa.shape != (4,):
                raise ShapeError(f"add() takes one state of shape (4,), got {qa.shape}")
            ql = qa.tolist()
        else:
            ql = np.asarray(q, np.float64).tolist()
        if not force_vertex and ql == self._prev_list:
            return self._current  # Algorithm 1, line 6: q_before == q_n
        if self._tracker is None:
            self._tracker = _DirectionTracker(self._thr, np.array(ql))
        else:
            self._tracker.update(ql)
        self._prev_list = ql
        sc = self._scale_list
        xs = [ql[0] * sc[0], ql[1] * sc[1], ql[2] * sc[2], ql[3] * sc[3]]
        cur = self._current
        vid = -1
        merge_r = self._eps if self._n >= self._coarse_from else self._res
        if force_vertex:
            ids, d = self._query(xs, self._res)
            exact = ids[d == 0.0] if len(ids) else ids
            if len(exact):
                vid = int(exact[0])
            elif cur < 0 and self._exit >= 0:
                # a view out of recorded territory (budget closed): record the stretch
                # travelled since the roadmap was left, so the view stays reachable
                self._record_excursion()
                cur = self._current
                if cur >= 0 and self._q[cur].tolist() == ql:
                    vid = cur  # the trail ended exactly at the view's state
            if vid < 0 and self._n >= self._max_n:
                raise RoadmapFullError(
                    f"the roadmap holds its budget of {self._max_n} vertices "
                    "(RoadmapConfig.max_vertices): a new state cannot be recorded as a view"
                )
        else:
            if cur >= 0:
                xc = self._cur_x
                dc = math.sqrt(
                    (xs[0] - xc[0]) ** 2
                    + (xs[1] - xc[1]) ** 2
                    + (xs[2] - xc[2]) ** 2
                    + (xs[3] - xc[3]) ** 2
                )
                if dc <= merge_r:
                    vid = cur
            if vid < 0:
                near_ids, near_d = self._query(xs, self._eps)
                if len(near_ids):
                    i = int(np.argmin(near_d))
                    if near_d[i] <= merge_r:
                        vid = int(near_ids[i])
                if vid < 0:
                    if self._n >= self._closed_from:
                        # budget closed: farther than epsilon from every vertex, the state
                        # is not recorded, and the trace breaks (no edge claims the
                        # unrecorded stretch was travelled)
                        self._note_excursion(ql, xs, cur)
                        self._current = -1
                        self._n_unrecorded += 1
                        return -1
                    vid = self._new_vertex(ql, xs, near_ids, near_d)
        if vid < 0:
            ids, d = self._query(xs, self._eps)
            vid = self._new_vertex(ql, xs, ids, d)
        if vid != cur:
            new_x = self._x[vid].tolist()
            if cur >= 0:  # trace continuity: the operator travelled cur -> vid
                ox = self._cur_x
                w = math.sqrt(
                    (new_x[0] - ox[0]) ** 2
                    + (new_x[1] - ox[1]) ** 2
                    + (new_x[2] - ox[2]) ** 2
                    + (new_x[3] - ox[3]) ** 2
                )
                if w > self._eps:  # else connected already: the later vertex was connected
                    self._connect_long(cur, vid, w)  # to the earlier one on insertion
            self._append_trace(vid)
            self._cur_x = new_x
        self._current = vid
        if self._exit >= 0:  # back in recorded territory: the excursion is over
            self._exit = -1
            self._excursion = []
        return vid

    def anchor(self) -> bool:
        """Make the latest state a recorded vertex if it is not (the budget was closed and
        the operator is out of recorded territory), with the stretch travelled since the
        roadmap was left, from the view reserve, so that a return can start here. Return
        whether the latest state is now connected to the roadmap (False: no state yet, the
        reserve is used up, or the excursion was too long to keep: then
        :attr:`n_isolated_views` counts it and a return from here is refused)."""
        if self._current >= 0:
            return True
        if self._prev_list is None:
            return False
        before = self._n_isolated_views
        try:
            self.add(self._prev_list, force_vertex=True)
        except RoadmapFullError:
            return False
        return self._current >= 0 and self._n_isolated_views == before

    def _note_excursion(self, ql: list[float], xs: list[float], cur: int) -> None:
        """Remember an unrecorded state (budget closed) in the excursion trail: states more
        than epsilon apart since the roadmap was left at vertex ``_exit``, at most
        ``_EXCURSION_MAX`` of them (longer excursions are forgotten: a view saved there has
        no recorded path)."""
        if cur >= 0:  # leaving the roadmap now, from vertex cur
            self._exit = cur
            self._excursion = []
        elif self._exit < 0:
            return  # no anchor (an earlier excursion was too long, or the trace broke)
        trail = self._excursion
        if trail:
            lx = self._excursion_x
            d2 = (
                (xs[0] - lx[0]) ** 2
                + (xs[1] - lx[1]) ** 2
                + (xs[2] - lx[2]) ** 2
                + (xs[3] - lx[3]) ** 2
            )
            if d2 <= self._eps * self._eps:
                return
        if len(trail) >= _EXCURSION_MAX:
            self._exit = -1  # too long to keep
            self._excursion = []
            return
        trail.append(ql)
        self._excursion_x = xs

    def _record_excursion(self) -> None:
        """Record the excursion trail as vertices (from the view reserve), connected from
        the vertex where the roadmap was left, as if the budget had been open."""
        trail = self._excursion
        if self._exit < 0 or self._n + len(trail) + 1 > self._max_n:
            self._n_isolated_views += 1  # no room (or no anchor): the view has no path
            return
        cur = self._exit
        cur_x = self._x[cur].tolist()
        sc = self._scale_list
        for ql in trail:
            xs = [ql[0] * sc[0], ql[1] * sc[1], ql[2] * sc[2], ql[3] * sc[3]]
            ids, d = self._query(xs, self._eps)
            vid = -1
            if len(ids):  # the trail may cross itself: merge as coarse merging does
                i = int(np.argmin(d))
                vid = int(ids[i])
            if vid < 0:
                vid = self._new_vertex(ql, xs, ids, d)
            if vid != cur:
                new_x = self._x[vid].tolist()
                w = math.sqrt(sum((a - b) ** 2 for a, b in zip(new_x, cur_x, strict=True)))
                if w > self._eps:
                    self._connect_long(cur, vid, w)
                self._append_trace(vid)
                cur, cur_x = vid, new_x
        self._current = cur
        self._cur_x = cur_x
        self._exit = -1
        self._excursion = []

    def _cell_ranges(self, xs: list[float], radius: float) -> list[tuple[int, ...]]:
        c = self._cell
        out = []
        for v in xs:
            lo = math.floor((v - radius) / c)
            hi = math.floor((v + radius) / c)
            out.append((lo,) if lo == hi else tuple(range(lo, hi + 1)))
        return out

    def _query(self, xs: list[float], radius: float) -> tuple[IntArray, Array]:
        """Vertex ids within ``radius`` of metric point ``xs`` and their distances."""
        grid = self._grid
        cand: list[int] = []
        for key in itertools.product(*self._cell_ranges(xs, radius)):
            lst = grid.get(key)  # type: ignore[arg-type]
            if lst:
                cand.extend(lst)
        if not cand:
            return np.empty(0, np.int64), np.empty(0)
        ids = np.array(cand, np.int64)
        diff = self._x[ids]
        diff -= xs
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        keep = d <= radius
        if keep.all():
            return ids, d
        return ids[keep], d[keep]

    def _new_vertex(self, qa: list[float], xs: list[float], ids: IntArray, d: Array) -> int:
        """Append vertex ``qa`` (metric ``xs``) and connect it to ``ids`` (its neighbours
        within epsilon, Algorithm 1 lines 7-8, at distances ``d``)."""
        n = self._n
        if n == len(self._q):
            self._q = _grow(self._q)
            self._x = _grow(self._x)
        self._q[n] = qa
        self._x[n] = xs
        self._n = n + 1
        c = self._cell
        key = (
            math.floor(xs[0] / c),
            math.floor(xs[1] / c),
            math.floor(xs[2] / c),
            math.floor(xs[3] / c),
        )
        lst = self._grid.get(key)
        if lst is None:
            self._grid[key] = array.array("q", (n,))
        else:
            lst.append(n)
        k = len(ids)
        if k:  # Algorithm 1, line 12: add_edge(q_i, q_n) for each neighbour
            self._reserve_edges(k)
            m = self._m
            self._eu[m : m + k] = ids
            self._ev[m : m + k] = n
            self._ew[m : m + k] = d
            self._m = m + k
        self._version += 1
        return n

    def _connect_long(self, a: int, b: int, w: float) -> None:
        """Connect two vertices farther apart than epsilon (a fast move of the trace) at
        length ``w``, unless already connected."""
        key = (a, b) if a < b else (b, a)
        if key in self._long_edges:
            return
        self._long_edges.add(key)
        self._reserve_edges(1)
        m = self._m
        self._eu[m], self._ev[m], self._ew[m] = key[0], key[1], w
        self._m = m + 1
        self._version += 1

    def _reserve_edges(self, k: int) -> None:
        need = self._m + k
        if need > len(self._eu):
            size = max(need, 2 * len(self._eu))
            self._eu = _grow(self._eu, size)
            self._ev = _grow(self._ev, size)
            self._ew = _grow(self._ew, size)

    def _append_trace(self, vid: int) -> None:
        if self._t == len(self._trace):
            self._trace = _grow(self._trace)
        self._trace[self._t] = vid
        self._t += 1

    # --- queries ----------------------------------------------------------------------------

    def neighbours(self, q: ArrayLike, radius: float | None = None) -> tuple[IntArray, Array]:
        """Vertex ids within ``radius`` (default epsilon, metric units) of motor state ``q``
        and their distances, nearest first."""
        r = self._eps if radius is None else float(radius)
        xs = [float(v) for v in self.metric_coordinates(check_joint_state(q))]
        if r <= self._cell / 2:
            ids, d = self._query(xs, r)
        else:
            d_all = np.sqrt(np.sum((self._x[: self._n] - np.array(xs)) ** 2, axis=1))
            ids = np.nonzero(d_all <= r)[0].astype(np.int64)
            d = d_all[ids]
        order = np.argsort(d, kind="stable")
        return ids[order], d[order]

    def nearest(self, q: ArrayLike) -> tuple[int, float]:
        """Nearest vertex to motor state ``q`` and its distance (metric units)."""
        if self._n == 0:
            raise PlanningError("the roadmap is empty: no state has been recorded")
        ids, d = self.neighbours(q, self._eps)
        if len(ids):
            return int(ids[0]), float(d[0])
        x = self.metric_coordinates(check_joint_state(q))
        d_all = np.sqrt(np.sum((self._x[: self._n] - x) ** 2, axis=1))
        i = int(np.argmin(d_all))
        return i, float(d_all[i])

    def vertex_of(self, q: ArrayLike) -> int:
        """Id of the vertex holding exactly motor state ``q``; PlanningError if none."""
        qa = check_joint_state(q)
        i, _ = self.nearest(qa)
        if not np.array_equal(self._q[i], qa):
            ids, _ = self.neighbours(qa, self._res)
            hits = [int(j) for j in ids if np.array_equal(self._q[j], qa)]
            if not hits:
                raise PlanningError(f"state {qa.tolist()} is not a recorded roadmap vertex")
            i = hits[0]
        return i

    # --- views -----------------------------------------------------------------------------

    def make_view(
        self,
        name: str,
        *,
        created_s: float,
        q: ArrayLike | None = None,
        tip2base: ArrayLike | None = None,
        thumbnail: NDArray[np.uint8] | None = None,
        notes: str = "",
    ) -> View:
        """Save the current state (or ``q``, the state the robot is at now, which is recorded
        first and must lie within epsilon of the last recorded state) as a view.

        Algorithm 1, line 15 (V.pushback(q_n)); the state is made an exact vertex, and the
        view keeps the arrival direction of every joint and the recorded approach.
        """
        if q is None:
            if self._prev_list is None:
                raise PlanningError("cannot save a view before any state has been recorded")
            q_view = np.array(self._prev_list)
        else:
            q_view = check_joint_state(q)
            if self._prev_list is not None:
                gap = float(self._config.metric.distance(q_view, self._prev_list))
                if gap > self._eps:
                    raise PlanningError(
                        f"the view's state is {gap:.3g} metric units from the last recorded "
                        f"state (more than epsilon = {self._eps:g}): record the motion first"
                    )
        vid = self.add(q_view, force_vertex=True)
        return View(
            name=name,
            q=self._q[vid].copy(),
            vertex=vid,
            created_s=float(created_s),
            arrival_direction=self.arrival_direction,
            approach=tuple(self._approach_ids(vid)),
            tip2base=None if tip2base is None else np.asarray(tip2base, np.float64),
            thumbnail=thumbnail,
            notes=notes,
        )

    def _approach_ids(self, vid: int) -> list[int]:
        """Recorded trace vertices that led to ``vid`` (oldest first, ending at vid).

        Walks back along the trace until every joint with an arrival direction has moved at
        least twice the direction threshold towards the view, or until ``approach_length``.
        """
        if self._t == 0 or self._trace[self._t - 1] != vid:
            return [vid]
        direction = np.array(self.arrival_direction, np.float64)
        need = direction != 0
        q_view = self._q[vid]
        ids = [vid]
        length = 0.0
        reached = np.zeros(4, bool)
        limit = self._config.approach_length
        for k in range(self._t - 2, -1, -1):
            if not np.any(need & ~reached):
                break
            u = int(self._trace[k])
            step = float(np.sqrt(np.sum((self._x[u] - self._x[ids[-1]]) ** 2)))
            if length + step > limit:
                break
            if step > self._eps and (min(u, ids[-1]), max(u, ids[-1])) not in self._long_edges:
                break  # the trace broke here (restart, unrecorded stretch): not travelled
            length += step
            ids.append(u)
            reached |= (q_view - self._q[u]) * direction >= 2.0 * self._thr
        ids.reverse()
        return ids

    # --- planning ---------------------------------------------------------------------------

    def _half(self) -> sp.csr_matrix:
        """The (n, n) CSR of the edges in one direction (as stored), rebuilt when the graph
        changed; ``scipy.sparse.csgraph`` treats it as undirected (``directed=False``).
        Building it is linear (the edge arrays are nearly sorted by construction)."""
        if self._csr is None or self._csr_version != self._version:
            n, m = self._n, self._m
            u, v, w = self._eu[:m], self._ev[:m], self._ew[:m]
            self._csr = sp.coo_matrix((w, (u, v)), shape=(n, n)).tocsr()
            self._csr_t = None
            self._csr_version = self._version
            self._csr_m = m
            self._delta = None
        return self._csr

    def _both_halves(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """The last built half CSR and its transpose (possibly older than the graph: the
        edges added since are in the delta adjacency)."""
        half = self._csr if self._csr is not None else self._half()
        if self._csr_t is None:
            self._csr_t = half.T.tocsr()
        return half, self._csr_t

    def csr(self) -> sp.csr_matrix:
        """The (n, n) symmetric adjacency matrix (edge lengths, metric units)."""
        half = self._half()
        return (half + half.T).tocsr()

    def _adjacency_delta(self) -> sp.csr_matrix:
        """Symmetric (n, n) CSR of the edges added since the CSR was built (numpy arrays,
        not Python objects: it may hold as many edges as the CSR itself)."""
        key = (self._csr_m, self._m, self._n)
        if self._delta is None or self._delta_key != key:
            lo, m, n = key
            u, v, w = self._eu[lo:m], self._ev[lo:m], self._ew[lo:m]
            self._delta = sp.coo_matrix(
                (np.concatenate([w, w]), (np.concatenate([u, v]), np.concatenate([v, u]))),
                shape=(n, n),
            ).tocsr()
            self._delta_key = key
        return self._delta

    def _tree(self, goal: int) -> tuple[Array, NDArray[np.int32]]:
        """Shortest-path tree to ``goal``: (n,) distances and (n,) predecessors (-9999 at
        the goal and at unreachable vertices).

        The first request runs scipy's Dijkstra from the goal on the CSR; later requests
        repair the cached tree with the edges added since (distances can only decrease when
        edges are added: relax the new edges, then propagate the decreases Dijkstra-style),
        which costs time proportional to the change, not to the graph.
        """
        tree = self._trees.pop(goal, None)
        if tree is None:
            dist, pred = dijkstra(
                self._half(), directed=False, indices=goal, return_predecessors=True
            )
            tree = _Tree(m=self._m, dist=dist, pred=pred.astype(np.int32))
            self._cache_tree(goal, tree)
            return tree.dist, tree.pred
        self._cache_tree(goal, tree)  # now the most recently used
        if tree.m < self._m or len(tree.dist) < self._n:
            self._repair(tree)
        return tree.dist, tree.pred

    def _cache_tree(self, goal: int, tree: _Tree) -> None:
        """Keep ``tree`` as the most recently used; drop the least recently used beyond
        ``config.tree_cache`` (each tree holds 12 bytes a vertex)."""
        self._trees.pop(goal, None)
        self._trees[goal] = tree
        while len(self._trees) > self._config.tree_cache:
            self._trees.pop(next(iter(self._trees)))

    def _repair(self, tree: _Tree) -> None:
        n, m = self._n, self._m
        if len(tree.dist) < n:
            k = len(tree.dist)
            tree.dist = np.concatenate([tree.dist, np.full(n - k, np.inf)])
            tree.pred = np.concatenate([tree.pred, np.full(n - k, -9999, np.int32)])
        dist, pred = tree.dist, tree.pred
        heap: list[tuple[float, int]] = []
        lo = tree.m
        for a, b, w in zip(
            self._eu[lo:m].tolist(),
            self._ev[lo:m].tolist(),
            self._ew[lo:m].tolist(),
            strict=True,
        ):
            da, db = float(dist[a]), float(dist[b])
            if da + w < db:
                dist[b] = da + w
                pred[b] = a
                heapq.heappush(heap, (da + w, b))
            elif db + w < da:
                dist[a] = db + w
                pred[a] = b
                heapq.heappush(heap, (db + w, a))
        if heap:
            if self._csr is None or m - self._csr_m > max(100_000, self._csr_m):
                self._half()  # fold a large delta into the CSR (amortised O(1) per edge)
            neighbours = self._neighbour_function()
            while heap:
                d, u = heapq.heappop(heap)
                if d > dist[u]:
                    continue
                for v, w in neighbours(u):
                    dv = d + w
                    if dv < dist[v]:
                        dist[v] = dv
                        pred[v] = u
                        heapq.heappush(heap, (dv, v))
        tree.m = m

    def _neighbour_function(self) -> Callable[[int], list[tuple[int, float]]]:
        """u -> [(v, w), ...] over the whole current graph: the last built CSR halves plus
        the edges added since."""
        half, other = self._both_halves()
        n_csr = half.shape[0]
        p1, i1, d1 = half.indptr, half.indices, half.data
        p2, i2, d2 = other.indptr, other.indices, other.data
        delta = self._adjacency_delta()
        p3, i3, d3 = delta.indptr, delta.indices, delta.data
        n_delta = delta.shape[0] if delta.nnz else 0

        def neighbours(u: int) -> list[tuple[int, float]]:
            out: list[tuple[int, float]] = []
            if u < n_csr:
                a, b = int(p1[u]), int(p1[u + 1])
                out.extend(zip(i1[a:b].tolist(), d1[a:b].tolist(), strict=True))
                a, b = int(p2[u]), int(p2[u + 1])
                out.extend(zip(i2[a:b].tolist(), d2[a:b].tolist(), strict=True))
            if u < n_delta:
                a, b = int(p3[u]), int(p3[u + 1])
                if b > a:
                    out.extend(zip(i3[a:b].tolist(), d3[a:b].tolist(), strict=True))
            return out

        return neighbours

    def prepare(self, goal: View | int, *, approach: bool = False) -> None:
        """Compute (or repair) the shortest-path tree to ``goal`` now, so that the next
        :meth:`plan` to it is fast (e.g. call it at idle time after a view is saved: the
        first tree costs one full Dijkstra, about a second at 1e6 vertices); ``approach``
        as in :meth:`plan`."""
        gv = self._search_goal(goal, approach)
        if not 0 <= gv < self._n:
            raise PlanningError(f"goal vertex {gv} is not in the roadmap (0..{self._n - 1})")
        self._tree(gv)

    def break_trace(self) -> None:
        """The next state was not reached from the last one (a restart, a re-homed or moved
        robot): :meth:`add` will not connect them as if the operator had travelled between
        them; it connects the next state only to recorded states within epsilon."""
        self._current = -1
        self._prev_list = None
        self._exit = -1
        self._excursion = []

    def _search_goal(self, goal: View | int, approach: bool) -> int:
        """The vertex a plan to ``goal`` searches to: a view's approach start when planning
        with ``approach=True`` (the recorded approach is appended), else the view's."""
        if isinstance(goal, View):
            if approach and len(goal.approach) >= 2:
                return int(goal.approach[0])
            return goal.vertex
        return int(goal)

    def tree_job(
        self, goal: View | int, *, approach: bool = False, isolate: bool = False
    ) -> Callable[[], _PreparedTree]:
        """Snapshot the graph now and return a job that computes the shortest-path tree to
        ``goal`` from the snapshot, safe to run in another thread while :meth:`add` goes on;
        hand its result to :meth:`install_tree` (in the thread that owns the roadmap).

        The snapshot is free (views of the append-only edge arrays: entries below the
        current edge count are never written again); the job builds the CSR and runs the
        Dijkstra (about half a second at 1e6 vertices). ``approach`` as in :meth:`plan`:
        with True, the tree is the one a plan with ``approach=True`` searches (to the start
        of the view's recorded approach).

        ``isolate=True`` runs the Dijkstra in a worker process (one, started at the first
        use): scipy's ``dijkstra`` holds the GIL for its whole run, so in a thread it stalls
        every other thread of the process, the control loop included (measured: a 0.5 s
        stall at 3e5 vertices). The job thread only waits for the answer. If the worker
        cannot be used, the job falls back to the Dijkstra in its own thread.
        """
        gv = self._search_goal(goal, approach)
        if not 0 <= gv < self._n:
            raise PlanningError(f"goal vertex {gv} is not in the roadmap (0..{self._n - 1})")
        n, m = self._n, self._m
        u, v, w = self._eu[:m], self._ev[:m], self._ew[:m]

        def job() -> _PreparedTree:
            half = sp.coo_matrix((w, (u, v)), shape=(n, n)).tocsr()
            dist_pred: tuple[Array, NDArray[np.int32]] | None = None
            if isolate:
                dist_pred = _dijkstra_isolated(half, gv)
            if dist_pred is None:
                dist_pred = _dijkstra_tree(half.indptr, half.indices, half.data, n, gv)
            tree = _Tree(m=m, dist=dist_pred[0], pred=dist_pred[1])
            return _PreparedTree(goal=gv, tree=tree, half=half, half_t=half.T.tocsr())

        return job

    def install_tree(self, goal: View | int, prepared: _PreparedTree) -> None:
        """Cache a tree from :meth:`tree_job` (repaired for later edges at the next plan),
        and its CSR when it is newer than the roadmap's own; a cached tree that already
        covers more edges is kept."""
        allowed = {self._search_goal(goal, False), self._search_goal(goal, True)}
        gv = prepared.goal
        if gv not in allowed:
            raise PlanningError(
                f"the prepared tree is for vertex {gv}, not {' or '.join(map(str, allowed))}"
            )
        tree = prepared.tree
        old = self._trees.get(gv)
        self._cache_tree(gv, tree if old is None or old.m < tree.m else old)
        if self._csr is None or self._csr_m < tree.m:
            self._csr = prepared.half
            self._csr_t = prepared.half_t
            self._csr_m = tree.m
            self._csr_version = -1  # older than the graph: _half() rebuilds when asked
            self._delta = None

    def shortest_path_ids(
        self, start: int, goal: int, method: Literal["tree", "astar"] = "tree"
    ) -> IntArray:
        """Vertex ids of a shortest path from vertex ``start`` to vertex ``goal``.

        ``method="tree"``: Dijkstra from the goal (scipy), cached per goal and repaired
        incrementally as the graph grows; ``"astar"``: A* with the Euclidean heuristic.
        Both are exact.

        Raises
        ------
        GoalUnreachableError
            The goal is not connected to the start.
        """
        n = self._n
        for name, v in (("start", start), ("goal", goal)):
            if not 0 <= v < n:
                raise PlanningError(f"{name} vertex {v} is not in the roadmap (0..{n - 1})")
        if start == goal:
            return np.array([start], np.int64)
        if method == "astar":
            return self._astar(start, goal)
        if method != "tree":
            raise ConfigurationError(f"method must be 'tree' or 'astar', got {method!r}")
        dist, pred = self._tree(goal)
        if not np.isfinite(dist[start]):
            raise GoalUnreachableError(
                f"goal vertex {goal} is not connected to start vertex {start} in the roadmap"
            )
        path = [start]
        v = start
        while v != goal:
            v = int(pred[v])
            path.append(v)
        return np.array(path, np.int64)

    def _astar(self, start: int, goal: int) -> IntArray:
        neighbours = self._neighbour_function()
        x = self._x
        xg = x[goal]
        h_all: dict[int, float] = {}

        def h(v: int) -> float:
            hv = h_all.get(v)
            if hv is None:
                d = x[v] - xg
                hv = float(np.sqrt(d @ d))
                h_all[v] = hv
            return hv

        best = {start: 0.0}
        parent = {start: -1}
        closed: set[int] = set()
        heap = [(h(start), 0.0, start)]
        while heap:
            _, gu, u = heapq.heappop(heap)
            if u in closed:
                continue
            if u == goal:
                path = [u]
                while parent[path[-1]] >= 0:
                    path.append(parent[path[-1]])
                return np.array(path[::-1], np.int64)
            closed.add(u)
            for v, w in neighbours(u):
                gv = gu + w
                if gv < best.get(v, math.inf):
                    best[v] = gv
                    parent[v] = u
                    heapq.heappush(heap, (gv + h(v), gv, v))
        raise GoalUnreachableError(
            f"goal vertex {goal} is not connected to start vertex {start} in the roadmap"
        )

    def plan(
        self,
        start: ArrayLike,
        goal: View | int | ArrayLike,
        *,
        approach: bool = False,
        method: Literal["tree", "astar"] = "tree",
    ) -> Array:
        """Plan a return from the current state to a view (or a recorded state).

        Parameters
        ----------
        start : array-like, shape (4,)
            Current motor state (rad, rad, rad, mm); snapped to its nearest vertex, which
            must lie within epsilon.
        goal : View, int or array-like (4,)
            A saved view, a vertex id, or a recorded motor state.
        approach : bool
            End with the view's recorded approach (the trace that led to it), so every
            joint arrives from the same side as when the view was saved.
        method : "tree" or "astar"
            Exact shortest path by cached Dijkstra tree or by A*.

        Returns
        -------
        path : ndarray, shape (n, 4)
            Motor states: ``path[0]`` is ``start``, ``path[-1]`` is exactly the goal state;
            each step is at most epsilon or an edge the operator travelled.

        Raises
        ------
        PlanningError
            Empty roadmap, start farther than epsilon from the roadmap, goal not recorded.
        GoalUnreachableError
            The goal is not connected to the start.
        """
        q_start = check_joint_state(start, name="start")
        if q_start.shape != (4,):
            raise PlanningError(f"start must have shape (4,), got {q_start.shape}")
        s, d_s = self.nearest(q_start)
        if d_s > self._eps:
            raise PlanningError(
                f"start state is {d_s:.3g} metric units from the nearest recorded state, more "
                f"than epsilon = {self._eps:g} (1 mm == 1 deg): record it first"
            )
        tail: list[int] = []
        if isinstance(goal, View):
            gv = goal.vertex
            if gv >= self._n or not np.array_equal(self._q[gv], goal.q):
                raise PlanningError(
                    f"view {goal.name!r} does not match roadmap vertex {gv}: "
                    "was it saved on another roadmap?"
                )
            if approach and len(goal.approach) >= 2:
                if max(goal.approach) >= self._n or min(goal.approach) < 0:
                    raise PlanningError(
                        f"view {goal.name!r}: its approach refers to vertices not in the roadmap"
                    )
                tail = list(goal.approach[1:])
                gv = goal.approach[0]
        elif isinstance(goal, (int, np.integer)):
            gv = int(goal)
        else:
            gv = self.vertex_of(goal)
        ids = self.shortest_path_ids(s, gv, method)
        if tail:
            ids = np.concatenate([ids, np.array(tail, np.int64)])
        path = self._q[ids].copy()
        if not np.array_equal(path[0], q_start):
            path = np.vstack([q_start[None, :], path])
        return path

    # --- persistence --------------------------------------------------------------------

    @classmethod
    def from_arrays(
        cls,
        vertices: ArrayLike,
        edges: ArrayLike,
        weights: ArrayLike,
        trace: ArrayLike,
        *,
        config: RoadmapConfig | None = None,
    ) -> Roadmap:
        """Rebuild a roadmap (e.g. from the store): vertices (n, 4) motor states, edges
        (m, 2) vertex ids, weights (m,) lengths, trace (t,) vertex ids."""
        q = np.asarray(vertices, np.float64).reshape(-1, 4)
        uv = np.asarray(edges, np.int64).reshape(-1, 2)
        w = np.asarray(weights, np.float64).reshape(-1)
        tr = np.asarray(trace, np.int64).reshape(-1)
        rm = cls(config=config, capacity=max(16, len(q)))
        n = len(q)
        if len(uv) != len(w):
            raise PlanningError(f"{len(uv)} edges but {len(w)} weights")
        if len(uv) and (uv.min() < 0 or uv.max() >= n):
            raise PlanningError("an edge refers to a vertex that does not exist")
        if len(tr) and (tr.min() < 0 or tr.max() >= n):
            raise PlanningError("the trace refers to a vertex that does not exist")
        rm._q[:n] = q
        rm._x[:n] = q * rm._scale
        rm._n = n
        cells = np.floor(rm._x[:n] / rm._cell).astype(np.int64)
        grid: dict[tuple[int, int, int, int], array.array[int]] = {}
        for i, c in enumerate(map(tuple, cells.tolist())):
            lst = grid.get(c)
            if lst is None:
                grid[c] = array.array("q", (i,))
            else:
                lst.append(i)
        rm._grid = grid
        rm._reserve_edges(len(uv))
        rm._eu[: len(uv)] = uv[:, 0]
        rm._ev[: len(uv)] = uv[:, 1]
        rm._ew[: len(uv)] = w
        rm._m = len(uv)
        long = w > rm._eps
        rm._long_edges = {(min(a, b), max(a, b)) for a, b in uv[long].tolist()}
        for v in tr.tolist():
            rm._append_trace(v)
        if len(tr):
            rm._current = int(tr[-1])
            rm._prev_list = rm._q[rm._current].tolist()
            rm._cur_x = rm._x[rm._current].tolist()
            tracker = _DirectionTracker(rm._thr, rm._q[int(tr[0])])
            for v in tr[1:].tolist():
                tracker.update(rm._q[v])
            rm._tracker = tracker
        rm._version = 1
        return rm


@dataclass
class _Tree:
    """A cached shortest-path tree to one goal, valid for edges [0, m)."""

    m: int
    dist: Array
    pred: NDArray[np.int32]


@dataclass
class _PreparedTree:
    """A tree computed off the control thread, with the CSR halves it was computed on."""

    goal: int
    tree: _Tree
    half: sp.csr_matrix
    half_t: sp.csr_matrix


def _dijkstra_tree(
    indptr: NDArray[Any], indices: NDArray[Any], data: Array, n: int, goal: int
) -> tuple[Array, NDArray[np.int32]]:
    """Shortest-path tree to ``goal`` over the undirected graph of a half CSR (the worker
    process runs this too, so it takes plain arrays)."""
    half = sp.csr_matrix((data, indices, indptr), shape=(n, n))
    dist, pred = dijkstra(half, directed=False, indices=goal, return_predecessors=True)
    return np.asarray(dist, np.float64), pred.astype(np.int32)


_WORKER: Any = None  # the planning worker process (concurrent.futures), started lazily
_WORKER_LOCK = threading.Lock()


def _dijkstra_isolated(half: sp.csr_matrix, goal: int) -> tuple[Array, NDArray[np.int32]] | None:
    """:func:`_dijkstra_tree` in the worker process; None when the worker fails (broken,
    killed, cannot start): the caller then runs it in its own thread."""
    global _WORKER
    import concurrent.futures
    import multiprocessing

    try:
        with _WORKER_LOCK:
            if _WORKER is None:
                _WORKER = concurrent.futures.ProcessPoolExecutor(
                    max_workers=1, mp_context=multiprocessing.get_context("spawn")
                )
                atexit.register(_stop_worker)  # before the interpreter tears modules down
            worker = _WORKER
        future = worker.submit(
            _dijkstra_tree, half.indptr, half.indices, half.data, half.shape[0], goal
        )
        result: tuple[Array, NDArray[np.int32]] = future.result()
        return result
    except Exception:  # noqa: BLE001 - BrokenProcessPool, OSError, pickling: fall back
        with _WORKER_LOCK:
            if _WORKER is not None:
                _WORKER.shutdown(wait=False, cancel_futures=True)
            _WORKER = None
        return None


def warm_up_planner() -> bool:
    """Start the planning worker process now and wait until it has run a (trivial) search:
    spawning it imports numpy and scipy, 1-3 s on a busy machine, which would otherwise
    delay the first background plan. True when the worker runs (False: plans will run in
    threads)."""
    empty = sp.csr_matrix((1, 1), dtype=np.float64)
    return _dijkstra_isolated(empty, 0) is not None


def _stop_worker() -> None:
    """Shut the planning worker process down (at exit)."""
    global _WORKER
    with _WORKER_LOCK:
        worker, _WORKER = _WORKER, None
    if worker is not None:
        worker.shutdown(wait=True, cancel_futures=True)


def _grow(a: NDArray[Any], size: int | None = None) -> NDArray[Any]:
    new = np.empty((size if size is not None else 2 * len(a),) + a.shape[1:], a.dtype)
    new[: len(a)] = a
    return new

"""Incremental roadmap of visited motor states and exact shortest-path planning over it.

The paper's Algorithm 1 (Section III-D): every new operator state ``q_n`` becomes a vertex
and is connected to every vertex within ``epsilon``; a return to a saved view is a discrete
A* search over this graph, so the catheter only passes through states the operator has
already visited. What we add (see ``docs/view-recovery.md``):

* The metric (:mod:`icenav.recovery.metric`): ``x = scale * q``, 1 mm == 1 deg by default,
  Euclidean in ``x``; roll is a multi-turn motor angle and is not wrapped.
* Consecutive trace states are always connected (the operator travelled between them, even
  when a fast move jumps more than ``epsilon``).
* Near-duplicate states (within ``merge_radius``, default ``epsilon / 4``) are merged into
  the existing vertex, so dwelling at a view does not pile up vertices.
* Neighbour search by spatial hashing on a grid of cell size ``4 * epsilon`` (an
  ``epsilon``-ball touches at most 2 cells per axis, about 5 on average in 4-D), not a scan
  of every vertex.
* Vertices and edges live in numpy arrays grown by doubling; the planner
  (:mod:`icenav.recovery.planner`) searches them (cached, incrementally repaired Dijkstra
  trees, or A*), exactly.
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
import itertools
import math
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_joint_state
from icenav.errors import (
    ConfigurationError,
    PlanningError,
    RoadmapFullError,
    ShapeError,
)
from icenav.recovery.metric import (
    DirectionTracker,
    RoadmapConfig,
    RoadmapMetric,
    approach_ids,
    direction_tracker,
)
from icenav.recovery.planner import (
    PreparedTree,
    ShortestPathTrees,
    plan_path,
    warm_up_planner,
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

_EXCURSION_MAX = 2048
"""Longest excursion trail kept while the vertex budget is closed (states more than
epsilon apart, so at least 2048 metric units of travel)."""

IntArray = NDArray[np.int64]


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
        self._tracker: DirectionTracker | None = None
        self._thr = cfg.direction_threshold / self._scale
        self._version = 0
        self._planner = ShortestPathTrees(self, cfg.tree_cache)
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

    def edge_views(
        self, start: int = 0, stop: int | None = None
    ) -> tuple[NDArray[np.int32], NDArray[np.int32], Array]:
        """Edges ``start..stop-1`` (default: to the end) as read-only views, no copy: (k,)
        vertex ids u, (k,) ids v, (k,) lengths (metric units). Safe from another thread
        as :meth:`vertices` is (the planner snapshots the graph with it)."""
        m = self._m if stop is None else stop
        out = (self._eu[start:m], self._ev[start:m], self._ew[start:m])
        for a in out:
            a.flags.writeable = False
        return out

    def metric_vertices(self, start: int = 0, stop: int | None = None) -> Array:
        """(k, 4) metric coordinates of vertices ``start..stop-1`` (read-only view)."""
        x = self._x[start : self._n if stop is None else stop]
        x.flags.writeable = False
        return x

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
            self._tracker = DirectionTracker(self._thr, np.array(ql))
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
        em_tip2base: ArrayLike | None = None,
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
            em_tip2base=None if em_tip2base is None else np.asarray(em_tip2base, np.float64),
        )

    def _approach_ids(self, vid: int) -> list[int]:
        """Recorded trace vertices that led to ``vid`` (oldest first, ending at vid)."""
        if self._t == 0 or self._trace[self._t - 1] != vid:
            return [vid]
        return approach_ids(
            self._trace[: self._t], self._q, self._x, self.arrival_direction, self._thr,
            self._config.approach_length, self._eps, self._long_edges,
        )  # fmt: skip

    # --- planning (icenav.recovery.planner) ------------------------------------------------

    def csr(self) -> sp.csr_matrix:
        """The (n, n) symmetric adjacency matrix (edge lengths, metric units)."""
        return self._planner.csr()

    @property
    def cached_tree_goals(self) -> list[int]:
        """Goal vertices with a cached shortest-path tree, least recently used first."""
        return self._planner.cached_goals

    def prepare(self, goal: View | int, *, approach: bool = False) -> None:
        """Compute (or repair) the shortest-path tree to ``goal`` now, so that the next
        :meth:`plan` to it is fast (e.g. call it at idle time after a view is saved: the
        first tree costs one full Dijkstra, about a second at 1e6 vertices); ``approach``
        as in :meth:`plan`."""
        gv = self._search_goal(goal, approach)
        if not 0 <= gv < self._n:
            raise PlanningError(f"goal vertex {gv} is not in the roadmap (0..{self._n - 1})")
        self._planner.tree(gv)

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
    ) -> Callable[[], PreparedTree]:
        """Snapshot the graph now and return a job that computes the shortest-path tree to
        ``goal`` from the snapshot, safe to run in another thread while :meth:`add` goes on;
        hand its result to :meth:`install_tree` (in the thread that owns the roadmap).
        ``approach`` as in :meth:`plan`; ``isolate``: in the worker process (see
        :meth:`icenav.recovery.planner.ShortestPathTrees.tree_job`)."""
        gv = self._search_goal(goal, approach)
        if not 0 <= gv < self._n:
            raise PlanningError(f"goal vertex {gv} is not in the roadmap (0..{self._n - 1})")
        return self._planner.tree_job(gv, isolate=isolate)

    def install_tree(self, goal: View | int, prepared: PreparedTree) -> None:
        """Cache a tree from :meth:`tree_job` (repaired for later edges at the next plan),
        and its CSR when it is newer than the roadmap's own; a cached tree that already
        covers more edges is kept."""
        allowed = {self._search_goal(goal, False), self._search_goal(goal, True)}
        gv = prepared.goal
        if gv not in allowed:
            raise PlanningError(
                f"the prepared tree is for vertex {gv}, not {' or '.join(map(str, allowed))}"
            )
        self._planner.install(prepared)

    def shortest_path_ids(
        self, start: int, goal: int, method: Literal["tree", "astar"] = "tree"
    ) -> IntArray:
        """Vertex ids of a shortest path from vertex ``start`` to vertex ``goal``, exact:
        ``method="tree"`` (cached, repaired Dijkstra tree) or ``"astar"``;
        GoalUnreachableError when they are not connected (:mod:`icenav.recovery.planner`)."""
        n = self._n
        for name, v in (("start", start), ("goal", goal)):
            if not 0 <= v < n:
                raise PlanningError(f"{name} vertex {v} is not in the roadmap (0..{n - 1})")
        if start == goal:
            return np.array([start], np.int64)
        if method == "astar":
            return self._planner.path_by_astar(start, goal)
        if method != "tree":
            raise ConfigurationError(f"method must be 'tree' or 'astar', got {method!r}")
        return self._planner.path_by_tree(start, goal)

    def plan(
        self,
        start: ArrayLike,
        goal: View | int | ArrayLike,
        *,
        approach: bool = False,
        method: Literal["tree", "astar"] = "tree",
    ) -> Array:
        """Plan a return from ``start`` (4,) to a view, a vertex id or a recorded state:
        (n, 4) motor states from ``start`` to exactly the goal state; see
        :func:`icenav.recovery.planner.plan_path` (parameters, errors)."""
        return plan_path(self, start, goal, approach=approach, method=method)

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
            tracker = DirectionTracker(rm._thr, rm._q[int(tr[0])])
            for v in tr[1:].tolist():
                tracker.update(rm._q[v])
            rm._tracker = tracker
        rm._version = 1
        return rm


def _grow(a: NDArray[Any], size: int | None = None) -> NDArray[Any]:
    new = np.empty((size if size is not None else 2 * len(a),) + a.shape[1:], a.dtype)
    new[: len(a)] = a
    return new

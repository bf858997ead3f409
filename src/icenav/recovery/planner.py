"""Exact shortest paths over a growing roadmap graph (the search half of Algorithm 1).

The roadmap (:mod:`icenav.recovery.roadmap`) owns the graph: append-only arrays of vertices
and edges. :class:`ShortestPathTrees` plans over it:

* a CSR matrix of the edges is built lazily when planning (one direction as stored;
  ``scipy.sparse.csgraph`` treats it as undirected), with a delta CSR of the edges added
  since, so that a repair does not rebuild the whole matrix;
* the shortest-path tree to each goal (``scipy.sparse.csgraph.dijkstra`` from the goal) is
  cached (least recently used dropped beyond ``tree_cache``) and, when the graph grows,
  repaired with the new edges only (adding edges can only shorten distances);
* a pure-Python A* with the Euclidean heuristic over the same arrays returns paths exactly
  as short (the heuristic is consistent: edge weights are Euclidean distances);
* :meth:`ShortestPathTrees.tree_job` computes a tree from a snapshot off the control thread,
  optionally in a worker process (scipy's Dijkstra holds the GIL for its whole run).
"""

from __future__ import annotations

import atexit
import heapq
import math
import pickle
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.csgraph import dijkstra

from icenav._typing import Array
from icenav._validation import check_joint_state
from icenav.errors import GoalUnreachableError, PlanningError
from icenav.recovery.plan_worker import PlanWorker, shortest_path_tree
from icenav.recovery.views import View

if TYPE_CHECKING:
    from icenav.recovery.roadmap import Roadmap

__all__ = [
    "PreparedTree",
    "RoadmapGraph",
    "ShortestPathTrees",
    "plan_path",
    "warm_up_planner",
]

IntArray = NDArray[np.int64]


class RoadmapGraph(Protocol):
    """What the planner reads of a roadmap: counts, a version and append-only arrays."""

    @property
    def version(self) -> int:
        """Incremented whenever a vertex or an edge is added."""
        ...

    def counts(self) -> tuple[int, int, int]:
        """(n_vertices, n_edges, n_trace)."""
        ...

    def edge_views(
        self, start: int = 0, stop: int | None = None
    ) -> tuple[NDArray[np.int32], NDArray[np.int32], Array]:
        """Edges ``start..stop-1`` as read-only views: (k,) ids u, (k,) ids v, (k,) lengths."""
        ...

    def metric_vertices(self, start: int = 0, stop: int | None = None) -> Array:
        """(k, 4) metric coordinates of vertices ``start..stop-1`` (read-only view)."""
        ...


@dataclass
class _Tree:
    """A cached shortest-path tree to one goal, valid for edges [0, m)."""

    m: int
    dist: Array
    pred: NDArray[np.int32]


@dataclass
class PreparedTree:
    """A tree computed off the control thread, with the CSR halves it was computed on."""

    goal: int
    tree: _Tree
    half: sp.csr_matrix
    half_t: sp.csr_matrix


class ShortestPathTrees:
    """Shortest-path trees (and A*) over a :class:`RoadmapGraph`.

    Parameters
    ----------
    graph : RoadmapGraph
        The roadmap; read, never written.
    tree_cache : int
        Trees kept (each holds 12 bytes a vertex).
    """

    def __init__(self, graph: RoadmapGraph, tree_cache: int) -> None:
        self._g = graph
        self._tree_cache = int(tree_cache)
        self._csr: sp.csr_matrix | None = None  # edges (u, v) as stored: one direction
        self._csr_t: sp.csr_matrix | None = None  # its transpose (the other direction)
        self._csr_version = -1
        self._csr_m = 0  # edges [0, _csr_m) are in the CSR
        self._delta: sp.csr_matrix | None = None  # symmetric CSR of edges [_csr_m, m)
        self._delta_key = (-1, -1, -1)  # (_csr_m, m, n) the delta was built for
        self._trees: dict[int, _Tree] = {}  # least recently used first

    @property
    def cached_goals(self) -> list[int]:
        """Goal vertices with a cached tree, least recently used first."""
        return list(self._trees)

    def _half(self) -> sp.csr_matrix:
        """The (n, n) CSR of the edges in one direction (as stored), rebuilt when the graph
        changed. Building it is linear (the edge arrays are nearly sorted by construction)."""
        version = self._g.version
        if self._csr is None or self._csr_version != version:
            n, m, _ = self._g.counts()
            u, v, w = self._g.edge_views(0, m)
            self._csr = sp.coo_matrix((w, (u, v)), shape=(n, n)).tocsr()
            self._csr_t = None
            self._csr_version = version
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
        n, m, _ = self._g.counts()
        key = (self._csr_m, m, n)
        if self._delta is None or self._delta_key != key:
            lo = self._csr_m
            u, v, w = self._g.edge_views(lo, m)
            self._delta = sp.coo_matrix(
                (np.concatenate([w, w]), (np.concatenate([u, v]), np.concatenate([v, u]))),
                shape=(n, n),
            ).tocsr()
            self._delta_key = key
        return self._delta

    def tree(self, goal: int) -> tuple[Array, NDArray[np.int32]]:
        """Shortest-path tree to ``goal``: (n,) distances and (n,) predecessors (-9999 at
        the goal and at unreachable vertices).

        The first request runs scipy's Dijkstra from the goal on the CSR; later requests
        repair the cached tree with the edges added since (distances can only decrease when
        edges are added: relax the new edges, then propagate the decreases Dijkstra-style),
        which costs time proportional to the change, not to the graph.
        """
        n, m, _ = self._g.counts()
        tree = self._trees.pop(goal, None)
        if tree is None:
            dist, pred = dijkstra(
                self._half(), directed=False, indices=goal, return_predecessors=True
            )
            tree = _Tree(m=m, dist=dist, pred=pred.astype(np.int32))
            self._cache_tree(goal, tree)
            return tree.dist, tree.pred
        self._cache_tree(goal, tree)  # now the most recently used
        if tree.m < m or len(tree.dist) < n:
            self._repair(tree)
        return tree.dist, tree.pred

    def _cache_tree(self, goal: int, tree: _Tree) -> None:
        """Keep ``tree`` as the most recently used; drop the least recently used beyond
        ``tree_cache``."""
        self._trees.pop(goal, None)
        self._trees[goal] = tree
        while len(self._trees) > self._tree_cache:
            self._trees.pop(next(iter(self._trees)))

    def _repair(self, tree: _Tree) -> None:
        n, m, _ = self._g.counts()
        if len(tree.dist) < n:
            k = len(tree.dist)
            tree.dist = np.concatenate([tree.dist, np.full(n - k, np.inf)])
            tree.pred = np.concatenate([tree.pred, np.full(n - k, -9999, np.int32)])
        dist, pred = tree.dist, tree.pred
        heap: list[tuple[float, int]] = []
        eu, ev, ew = self._g.edge_views(tree.m, m)
        for a, b, w in zip(eu.tolist(), ev.tolist(), ew.tolist(), strict=True):
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

    def tree_job(self, goal: int, *, isolate: bool = False) -> Callable[[], PreparedTree]:
        """Snapshot the graph now and return a job that computes the tree to vertex ``goal``
        from the snapshot, safe to run in another thread while the roadmap grows.

        The snapshot is free (views of the append-only edge arrays: entries below the
        current edge count are never written again); the job builds the CSR and runs the
        Dijkstra (about half a second at 1e6 vertices).

        ``isolate=True`` runs the Dijkstra in a worker process (one, started at the first
        use): scipy's ``dijkstra`` holds the GIL for its whole run, so in a thread it stalls
        every other thread of the process, the control loop included (measured: a 0.5 s
        stall at 3e5 vertices). The job thread only waits for the answer. If the worker
        cannot be used, the job falls back to the Dijkstra in its own thread.
        """
        n, m, _ = self._g.counts()
        u, v, w = self._g.edge_views(0, m)

        def job() -> PreparedTree:
            half = sp.coo_matrix((w, (u, v)), shape=(n, n)).tocsr()
            dist_pred: tuple[Array, NDArray[np.int32]] | None = None
            if isolate:
                dist_pred = _dijkstra_isolated(half, goal)
            if dist_pred is None:
                dist_pred = shortest_path_tree(half.indptr, half.indices, half.data, n, goal)
            tree = _Tree(m=m, dist=dist_pred[0], pred=dist_pred[1])
            return PreparedTree(goal=goal, tree=tree, half=half, half_t=half.T.tocsr())

        return job

    def install(self, prepared: PreparedTree) -> None:
        """Cache a tree from :meth:`tree_job`, and its CSR when it is newer than ours; a
        cached tree that already covers more edges is kept."""
        gv = prepared.goal
        tree = prepared.tree
        old = self._trees.get(gv)
        self._cache_tree(gv, tree if old is None or old.m < tree.m else old)
        if self._csr is None or self._csr_m < tree.m:
            self._csr = prepared.half
            self._csr_t = prepared.half_t
            self._csr_m = tree.m
            self._csr_version = -1  # older than the graph: _half() rebuilds when asked
            self._delta = None

    def path_by_tree(self, start: int, goal: int) -> IntArray:
        """Vertex ids of a shortest path ``start -> goal`` from the cached (repaired) tree.

        Raises
        ------
        GoalUnreachableError
            The goal is not connected to the start.
        """
        dist, pred = self.tree(goal)
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

    def path_by_astar(self, start: int, goal: int) -> IntArray:
        """Vertex ids of a shortest path ``start -> goal`` by A* (Euclidean heuristic in
        metric coordinates).

        Raises
        ------
        GoalUnreachableError
            The goal is not connected to the start.
        """
        neighbours = self._neighbour_function()
        x = self._g.metric_vertices()
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


def plan_path(
    roadmap: Roadmap,
    start: ArrayLike,
    goal: View | int | ArrayLike,
    *,
    approach: bool = False,
    method: Literal["tree", "astar"] = "tree",
) -> Array:
    """Plan a return on ``roadmap`` from the current state to a view (or a recorded state).

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
    eps, n = roadmap.epsilon, roadmap.n_vertices
    if q_start.shape != (4,):
        raise PlanningError(f"start must have shape (4,), got {q_start.shape}")
    s, d_s = roadmap.nearest(q_start)
    if d_s > eps:
        raise PlanningError(
            f"start state is {d_s:.3g} metric units from the nearest recorded state, more "
            f"than epsilon = {eps:g} (1 mm == 1 deg): record it first"
        )
    tail: list[int] = []
    if isinstance(goal, View):
        gv = goal.vertex
        if gv >= n or not np.array_equal(roadmap.vertices(gv, gv + 1)[0], goal.q):
            raise PlanningError(
                f"view {goal.name!r} does not match roadmap vertex {gv}: "
                "was it saved on another roadmap?"
            )
        if approach and len(goal.approach) >= 2:
            if max(goal.approach) >= n or min(goal.approach) < 0:
                raise PlanningError(
                    f"view {goal.name!r}: its approach refers to vertices not in the roadmap"
                )
            tail = list(goal.approach[1:])
            gv = goal.approach[0]
    elif isinstance(goal, (int, np.integer)):
        gv = int(goal)
    else:
        gv = roadmap.vertex_of(goal)
    ids = roadmap.shortest_path_ids(s, gv, method)
    if tail:
        ids = np.concatenate([ids, np.array(tail, np.int64)])
    path = roadmap.vertices()[ids].copy()
    if not np.array_equal(path[0], q_start):
        path = np.vstack([q_start[None, :], path])
    return path


_WORKER: PlanWorker | None = None  # the planning worker process, started lazily
_WORKER_LOCK = threading.Lock()


def _dijkstra_isolated(half: sp.csr_matrix, goal: int) -> tuple[Array, NDArray[np.int32]] | None:
    """:func:`icenav.recovery.plan_worker.shortest_path_tree` in the worker process
    (:class:`~icenav.recovery.plan_worker.PlanWorker`); None when the worker fails (killed,
    cannot start): the caller then runs the search in its own thread, and the next call
    starts a new worker."""
    global _WORKER
    try:
        with _WORKER_LOCK:
            if _WORKER is None:
                _WORKER = PlanWorker()
                atexit.register(_stop_worker)  # before the interpreter tears modules down
            worker = _WORKER
        return worker.tree(half.indptr, half.indices, half.data, half.shape[0], goal)
    except (OSError, PlanningError, pickle.UnpicklingError):
        with _WORKER_LOCK:
            if _WORKER is not None:
                _WORKER.close(wait=False)
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
        worker.close()

"""Roadmap: Algorithm 1 semantics, trace continuity, merging, exact planning, approach."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from icenav.errors import (
    ConfigurationError,
    GoalUnreachableError,
    NonFiniteError,
    PlanningError,
    ShapeError,
)
from icenav.recovery.roadmap import (
    Roadmap,
    RoadmapConfig,
    RoadmapFullError,
    RoadmapMetric,
    direction_tracker,
)

DEG = math.pi / 180


def d4(*values: float) -> list[np.ndarray]:
    """States that move the translation only (1 mm == 1 metric unit)."""
    return [np.array([0.0, 0.0, 0.0, v]) for v in values]


def edge_set(rm: Roadmap) -> set[frozenset[int]]:
    uv, _ = rm.edges()
    return {frozenset(map(int, e)) for e in uv}


def random_trace(rng: np.random.Generator, n: int, jumps: bool = True) -> np.ndarray:
    """A smooth-ish random walk in motor space with dwells and (optionally) fast jumps."""
    step = np.array([0.3 * DEG, 0.3 * DEG, 0.3 * DEG, 0.3])
    out = np.empty((n, 4))
    q = np.zeros(4)
    vel = np.zeros(4)
    for i in range(n):
        r = rng.random()
        if r < 0.1:
            pass  # dwell: same state again
        elif jumps and r < 0.12:
            q = q + rng.normal(0, 3, 4) * step  # a fast move: several epsilons at once
        else:
            vel = 0.8 * vel + 0.2 * rng.normal(0, 1, 4) * step * 3
            q = q + vel
        q = np.clip(q, [-1.5, -1.5, -6, -50], [1.5, 1.5, 6, 50])
        out[i] = q
    return out


def reference_build(trace: np.ndarray, cfg: RoadmapConfig) -> tuple[np.ndarray, set, list]:
    """Brute-force Algorithm 1 with our additions (scan every vertex): the reference."""
    scale = cfg.metric.scale
    verts: list[np.ndarray] = []
    edges: set[frozenset[int]] = set()
    trace_ids: list[int] = []
    prev = None
    cur = -1
    for q in trace:
        if prev is not None and np.array_equal(q, prev):
            continue
        prev = q
        x = q * scale
        vid = -1
        if verts:
            d = np.linalg.norm(np.array(verts) * scale - x, axis=1)
            if cur >= 0 and d[cur] <= cfg.resolution:
                vid = cur
            elif d.min() <= cfg.resolution:
                vid = int(np.argmin(d))
        if vid < 0:
            vid = len(verts)
            if verts:
                for i in np.nonzero(d <= cfg.epsilon)[0]:
                    edges.add(frozenset((int(i), vid)))
            verts.append(q)
        if cur >= 0 and vid != cur:
            edges.add(frozenset((cur, vid)))
        if vid != cur:
            trace_ids.append(vid)
        cur = vid
    return np.array(verts), edges, trace_ids


# --- metric and configuration -----------------------------------------------------------


def test_metric_one_degree_equals_one_millimetre() -> None:
    m = RoadmapMetric()
    assert m.distance([DEG, 0, 0, 0], [0, 0, 0, 0]) == pytest.approx(1.0)
    assert m.distance([0, 0, DEG, 0], [0, 0, 0, 0]) == pytest.approx(1.0)
    assert m.distance([0, 0, 0, 1.0], [0, 0, 0, 0]) == pytest.approx(1.0)
    assert m.distance([3 * DEG, 0, 0, 4.0], [0, 0, 0, 0]) == pytest.approx(5.0)
    w = RoadmapMetric(roll_weight=0.5, translation_weight=2.0)
    assert w.distance([0, 0, 2 * DEG, 0], [0, 0, 0, 0]) == pytest.approx(1.0)
    assert w.distance([0, 0, 0, 1.0], [0, 0, 0, 0]) == pytest.approx(2.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"epsilon": 0.0}, "epsilon"),
        ({"epsilon": float("nan")}, "epsilon"),
        ({"epsilon": 1.0, "merge_radius": 1.0}, "merge_radius must be < epsilon"),
        ({"direction_threshold": -1.0}, "direction_threshold"),
    ],
)
def test_bad_config_is_refused(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigurationError, match=match):
        RoadmapConfig(**kwargs)
    with pytest.raises(ConfigurationError, match="knob_weight"):
        RoadmapMetric(knob_weight=0)


def test_bad_state_is_refused() -> None:
    rm = Roadmap()
    with pytest.raises(NonFiniteError, match="finite"):
        rm.add([0, 0, float("nan"), 0])
    with pytest.raises(ShapeError, match="shape"):
        rm.add([0, 0, 0])
    with pytest.raises(ShapeError, match="one state"):
        rm.add(np.zeros((2, 4)))
    with pytest.raises(PlanningError, match="empty"):
        rm.plan([0, 0, 0, 0], 0)


# --- Algorithm 1 on hand-made traces ----------------------------------------------------------


def test_algorithm1_hand_made_trace() -> None:
    rm = Roadmap(1.0)  # merge radius 0.25
    ids = [rm.add(q) for q in d4(0.0, 0.5, 0.9, 3.0, 3.0, 2.2, 0.1)]
    assert ids == [0, 1, 2, 3, 3, 4, 0]
    assert rm.n_vertices == 5
    expected = {(0, 1), (0, 2), (1, 2), (2, 3), (3, 4), (0, 4)}
    assert edge_set(rm) == {frozenset(e) for e in expected}
    # (2, 3) and (4, 0) are longer than epsilon: trace continuity, not Algorithm 1
    uv, w = rm.edges()
    lengths = {frozenset(map(int, e)): float(x) for e, x in zip(uv, w, strict=True)}
    assert lengths[frozenset((2, 3))] == pytest.approx(2.1)
    assert lengths[frozenset((0, 4))] == pytest.approx(2.2)
    assert rm.trace().tolist() == [0, 1, 2, 3, 4, 0]


def test_repeated_state_is_ignored_and_epsilon_is_inclusive() -> None:
    rm = Roadmap(1.0)
    for q in d4(0.0, 0.0, 0.0, 1.0, 1.0, 2.0):
        rm.add(q)
    assert rm.n_vertices == 3
    assert edge_set(rm) == {frozenset((0, 1)), frozenset((1, 2))}  # dist == eps connects


@pytest.mark.parametrize("seed", range(4))
def test_matches_brute_force_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    trace = random_trace(rng, 1500)
    cfg = RoadmapConfig(epsilon=1.0)
    rm = Roadmap(config=cfg)
    for q in trace:
        rm.add(q)
    verts, edges, trace_ids = reference_build(trace, cfg)
    np.testing.assert_array_equal(rm.vertices(), verts)
    assert edge_set(rm) == edges
    assert rm.n_edges == len(edges)  # no duplicate edges
    assert rm.trace().tolist() == trace_ids
    uv, w = rm.edges()
    np.testing.assert_allclose(w, cfg.metric.distance(verts[uv[:, 0]], verts[uv[:, 1]]))


@pytest.mark.parametrize("seed", range(4))
def test_trace_continuity_and_representation(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    trace = random_trace(rng, 2000)
    rm = Roadmap(1.0)
    cfg = rm.config
    vids = [rm.add(q) for q in trace]
    edges = edge_set(rm)
    for a, b in zip(vids[:-1], vids[1:], strict=True):
        if a != b:
            assert frozenset((a, b)) in edges
    # every recorded state is represented by its vertex within the merge radius
    d = cfg.metric.distance(rm.vertices()[vids], trace)
    assert d.max() <= cfg.resolution + 1e-12
    # the trace has long jumps, and they are edges
    _, w = rm.edges()
    assert w.max() > cfg.epsilon


def test_dwelling_does_not_pile_up_vertices() -> None:
    rng = np.random.default_rng(7)
    rm = Roadmap(1.0)
    q0 = np.array([0.3, -0.2, 0.1, 5.0])
    for _ in range(20_000):  # 200 s at 100 Hz, hand tremor of 0.02 deg / 0.02 mm
        rm.add(q0 + rng.normal(0, [0.02 * DEG, 0.02 * DEG, 0.02 * DEG, 0.02]))
    assert rm.n_vertices <= 3


# --- planning -----------------------------------------------------------------------------


def path_length(rm: Roadmap, ids: np.ndarray) -> float:
    x = rm.metric_coordinates(rm.vertices()[ids])
    return float(np.linalg.norm(np.diff(x, axis=0), axis=1).sum())


@pytest.mark.parametrize("seed", range(8))
def test_astar_and_tree_are_exactly_shortest(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    rm = Roadmap(1.0)
    for q in random_trace(rng, 1200):
        rm.add(q)
    g = rm.csr()
    graph = nx.Graph()
    uv, w = rm.edges()
    graph.add_weighted_edges_from(
        (int(a), int(b), float(c)) for (a, b), c in zip(uv, w, strict=True)
    )
    for _ in range(5):
        s, t = (int(v) for v in rng.integers(0, rm.n_vertices, 2))
        ref = dijkstra(g, directed=False, indices=s)[t]
        ref_nx = nx.dijkstra_path_length(graph, s, t) if s != t else 0.0
        for method in ("astar", "tree"):
            ids = rm.shortest_path_ids(s, t, method)  # type: ignore[arg-type]
            assert ids[0] == s and ids[-1] == t
            for a, b in zip(ids[:-1], ids[1:], strict=True):
                assert g[a, b] > 0, "consecutive path vertices must share an edge"
            assert path_length(rm, ids) == pytest.approx(ref, rel=1e-9, abs=1e-9)
            assert path_length(rm, ids) == pytest.approx(ref_nx, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_repaired_trees_stay_exact_while_the_roadmap_grows(seed: int) -> None:
    rng = np.random.default_rng(250 + seed)
    trace = random_trace(rng, 3000)
    rm = Roadmap(1.0)
    goals = []
    for i, q in enumerate(trace):
        rm.add(q)
        if i in (100, 700):
            goals.append(rm.current_vertex)
        if i > 700 and i % 150 == 0:
            for goal in goals:  # the cached trees are repaired, not recomputed
                ids = rm.shortest_path_ids(rm.current_vertex, goal, "tree")
                fresh = dijkstra(rm.csr(), directed=False, indices=goal)[rm.current_vertex]
                assert path_length(rm, ids) == pytest.approx(fresh, rel=1e-9, abs=1e-9)
                assert ids[0] == rm.current_vertex and ids[-1] == goal
    assert len(rm.cached_tree_goals) == 2
    rm.prepare(0)
    assert len(rm.cached_tree_goals) == 3
    with pytest.raises(PlanningError, match="not in the roadmap"):
        rm.prepare(rm.n_vertices)


def two_islands() -> Roadmap:
    q = np.array([d for d in d4(0.0, 0.5, 1.0, 10.0, 10.5)])
    uv = np.array([[0, 1], [1, 2], [3, 4]])
    w = np.array([0.5, 0.5, 0.5])
    return Roadmap.from_arrays(q, uv, w, np.array([0, 1, 2]))


@pytest.mark.parametrize("method", ["tree", "astar"])
def test_unreachable_goal(method: str) -> None:
    rm = two_islands()
    with pytest.raises(GoalUnreachableError, match="not connected"):
        rm.plan(d4(0.0)[0], 4, method=method)  # type: ignore[arg-type]
    path = rm.plan(d4(0.2)[0], 2, method=method)  # type: ignore[arg-type]
    np.testing.assert_array_equal(path[-1], d4(1.0)[0])


def test_start_far_from_roadmap_and_unknown_goal_are_refused() -> None:
    rm = two_islands()
    with pytest.raises(PlanningError, match="more than epsilon"):
        rm.plan(d4(5.0)[0], 0)
    with pytest.raises(PlanningError, match="not a recorded roadmap vertex"):
        rm.plan(d4(0.0)[0], d4(0.7)[0])
    with pytest.raises(PlanningError, match="not in the roadmap"):
        rm.plan(d4(0.0)[0], 99)
    other = Roadmap(1.0)
    for q in d4(0.0, 0.3, 0.6, 7.0):
        other.add(q)
    foreign = other.make_view("elsewhere", created_s=0.0)
    with pytest.raises(PlanningError, match="another roadmap"):
        rm.plan(d4(0.0)[0], foreign)


def check_path(rm: Roadmap, path: np.ndarray, start: np.ndarray, goal_q: np.ndarray) -> None:
    """The issue's path contract."""
    np.testing.assert_array_equal(path[0], start)
    np.testing.assert_array_equal(path[-1], goal_q)  # exactly the view's state
    verts = rm.vertices()
    eps = rm.epsilon
    metric = rm.config.metric
    # only through recorded states (the start may be off-vertex by <= epsilon)
    lookup = {tuple(v): i for i, v in enumerate(verts.tolist())}
    inner = path if tuple(path[0].tolist()) in lookup else path[1:]
    ids = [lookup[tuple(p)] for p in inner.tolist()]
    edges = edge_set(rm)
    steps = metric.distance(path[:-1], path[1:])
    if len(inner) < len(path):
        assert steps[0] <= eps
        steps = steps[1:]
    for (a, b), s in zip(zip(ids[:-1], ids[1:], strict=True), steps, strict=True):
        assert s <= eps + 1e-12 or frozenset((a, b)) in edges


@pytest.mark.parametrize("seed", range(8))
def test_planned_paths_follow_the_contract(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    rm = Roadmap(1.0)
    trace = random_trace(rng, 1500)
    views = []
    for i, q in enumerate(trace):
        rm.add(q)
        if i % 500 == 250:
            views.append(rm.make_view(f"v{i}", created_s=i / 100))
    # wander on, then return from an off-vertex state within epsilon
    start = rm.current_state + np.array([0.1 * DEG, 0.0, 0.0, 0.1])
    for view in views:
        for approach in (False, True):
            path = rm.plan(start, view, approach=approach)
            check_path(rm, path, start, view.q)


def test_plans_follow_the_roadmap_not_a_straight_line() -> None:
    # an L-shaped trace: the return goes around the corner, never across the diagonal
    rm = Roadmap(1.0)
    for v in np.linspace(0, 10, 101):
        rm.add([0, 0, 0, v])
    for a in np.linspace(0, 10, 101):
        rm.add([a * DEG, 0, 0, 10])
    path = rm.plan([10 * DEG, 0, 0, 10], 0)
    on_l = np.isclose(path[:, 0], 0.0) | np.isclose(path[:, 3], 10.0)
    assert on_l.all()  # only recorded states
    corner = RoadmapMetric().distance(path, [0, 0, 0, 10]).min()
    assert corner <= rm.epsilon  # around the corner (epsilon edges may cut it by < epsilon)


def test_tree_cache_is_invalidated_when_the_graph_changes() -> None:
    rm = Roadmap(1.0)
    for v in np.linspace(0, 20, 41):
        rm.add([0, 0, 0, v])
    for a in np.linspace(0, 20, 41):
        rm.add([a * DEG, 0, 0, 20])
    for v in np.linspace(20, 0, 41):
        rm.add([20 * DEG, 0, 0, v])
    long_way = rm.plan([20 * DEG, 0, 0, 0], 0)
    for a in np.linspace(20, 0, 41):  # a shortcut along the bottom
        rm.add([a * DEG, 0, 0, 0])
    short_way = rm.plan([20 * DEG, 0, 0, 0], 0)
    assert len(short_way) < len(long_way) / 2


def test_from_arrays_round_trip() -> None:
    rng = np.random.default_rng(5)
    rm = Roadmap(1.0)
    for q in random_trace(rng, 1000):
        rm.add(q)
    uv, w = rm.edges()
    back = Roadmap.from_arrays(rm.vertices(), uv, w, rm.trace(), config=rm.config)
    assert back.n_vertices == rm.n_vertices and back.n_edges == rm.n_edges
    assert back.arrival_direction == rm.arrival_direction
    np.testing.assert_array_equal(back.current_state, rm.vertices()[rm.trace()[-1]])
    np.testing.assert_array_equal(back.plan(back.current_state, 0), rm.plan(back.current_state, 0))
    # both keep growing identically
    more = random_trace(np.random.default_rng(6), 300)
    for q in more:
        assert back.add(q) == rm.add(q)
    assert edge_set(back) == edge_set(rm)


# --- arrival direction and approach ------------------------------------------------------


def test_view_state_must_be_where_the_robot_is() -> None:
    rm = Roadmap(1.0)
    with pytest.raises(PlanningError, match="before any state"):
        rm.make_view("a", created_s=0.0)
    for v in np.linspace(0, 5, 11):
        rm.add([0, 0, 0, v])
    with pytest.raises(PlanningError, match="record the motion first"):
        rm.make_view("far", created_s=0.0, q=[0, 0, 0, 0.0])
    view = rm.make_view("here", created_s=0.0, q=[0, 0, 0, 5.1])  # not yet recorded: added
    assert rm.vertex_of([0, 0, 0, 5.1]) == view.vertex == rm.current_vertex
    np.testing.assert_array_equal(view.q, [0, 0, 0, 5.1])  # exact, although within merge radius


def test_direction_tracker_ignores_small_reversals() -> None:
    thr = np.full(4, 0.5)
    path = np.array([[0, 0, 0, 0], [0, 0, 0, 2], [0, 0, 0, 1.7], [0, 0, 0, 1.8]])
    assert direction_tracker(path, thr) == (0, 0, 0, 1)
    path2 = np.vstack([path, [0, 0, 0, 1.0]])
    assert direction_tracker(path2, thr) == (0, 0, 0, -1)


def test_view_remembers_arrival_direction() -> None:
    rm = Roadmap(1.0)
    for v in np.linspace(0, 10, 51):  # d4 increasing, phi1 decreasing
        rm.add([-v * DEG, 0, 0, v])
    for v in np.linspace(10, 9.9, 3):  # a reversal smaller than the threshold
        rm.add([-10 * DEG, 0, 0, v])
    view = rm.make_view("a", created_s=1.0)
    assert view.arrival_direction == (-1, 0, 0, 1)
    assert view.approach[-1] == view.vertex
    assert len(view.approach) >= 2


@pytest.mark.parametrize("seed", range(10))
def test_approach_reproduces_the_arrival_direction(seed: int) -> None:
    rng = np.random.default_rng(400 + seed)
    rm = Roadmap(config=RoadmapConfig(direction_threshold=0.5, approach_length=10.0))
    ramp = np.linspace(0, 1, 40)[:, None]
    arrive = rng.choice([-1.0, 1.0], 4)
    start = np.array([0.2, -0.2, 0.3, 5.0])
    view_q = start + arrive * np.array([5 * DEG, 5 * DEG, 5 * DEG, 5.0])
    for q in start + ramp * (view_q - start):  # arrive at the view from one side
        rm.add(q)
    view = rm.make_view("v", created_s=0.0)
    assert view.arrival_direction == tuple(int(a) for a in arrive)
    for q in random_trace(rng, 600, jumps=False) * 0.3 + view_q:  # wander around it
        rm.add(q)
    thr = rm.direction_threshold_motor
    with_approach = rm.plan(rm.current_state, view, approach=True)
    assert direction_tracker(with_approach, thr) == view.arrival_direction
    # without the approach, these seeded returns arrive from the wrong side of some joint
    without = rm.plan(rm.current_state, view, approach=False)
    assert direction_tracker(without, thr) != view.arrival_direction


def test_tree_job_from_a_snapshot_plans_exactly_after_more_driving() -> None:
    # the tree is computed from a snapshot while the roadmap keeps growing (as the
    # controller does in a background thread after a view is saved); once installed and
    # repaired, plans equal a fresh Dijkstra's
    rng = np.random.default_rng(11)
    rm = Roadmap(epsilon=1.0)
    q = np.zeros(4)
    for _ in range(3000):
        q = q + rng.normal(scale=[0.004, 0.004, 0.004, 0.2])
        rm.add(q)
    view = rm.make_view("v", created_s=0.0)
    job = rm.tree_job(view)
    for _ in range(2000):  # the operator drives on while the job runs
        q = q + rng.normal(scale=[0.004, 0.004, 0.004, 0.2])
        rm.add(q)
    rm.install_tree(view, job())
    fast = rm.plan(q, view)
    fresh = Roadmap.from_arrays(rm.vertices(), *rm.edges(), rm.trace(), config=rm.config).plan(
        q, view.vertex
    )
    metric = rm.config.metric

    def length(path: np.ndarray) -> float:
        return float(np.sum(metric.distance(path[:-1], path[1:])))

    assert length(fast) == pytest.approx(length(fresh), rel=1e-9)
    np.testing.assert_array_equal(fast[-1], view.q)


# --- vertex budget (issue 9: bounded memory over a long procedure) -------------------------


def explore(rng: np.random.Generator, n: int) -> np.ndarray:
    """A smooth random walk (no dwell) held loosely in a box of +-4 metric units per joint
    by a cubic pull: it keeps reaching new joint space and keeps revisiting old."""
    step = np.array([0.4 * DEG, 0.4 * DEG, 0.4 * DEG, 0.4])
    box = np.array([4 * DEG, 4 * DEG, 4 * DEG, 4.0])
    out = np.empty((n, 4))
    q = np.zeros(4)
    vel = np.zeros(4)
    for i in range(n):
        pull = -0.5 * np.clip(q / box, -2, 2) ** 3
        vel = 0.9 * vel + 0.1 * (rng.normal(0, 1, 4) + pull) * step * 3
        q = q + vel
        out[i] = q
    return out


@pytest.mark.parametrize("seed", range(3))
def test_vertex_budget_is_never_exceeded_and_views_stay_exact_and_reachable(seed: int) -> None:
    rng = np.random.default_rng(900 + seed)
    cfg = RoadmapConfig(epsilon=1.0, max_vertices=1000)
    rm = Roadmap(config=cfg)
    reachable, isolated = [], []
    n_out = 0
    for i, q in enumerate(explore(rng, 9000)):
        rm.add(q)
        assert rm.n_vertices <= 1000
        if i % 450 == 449:
            out_there = not rm.recording  # out of recorded territory, budget closed
            before = rm.n_isolated_views
            view = rm.make_view(f"v{i}", created_s=i / 100)
            np.testing.assert_array_equal(rm.vertices()[view.vertex], q)  # exact
            (isolated if rm.n_isolated_views > before else reachable).append(view)
            n_out += out_there and rm.n_isolated_views == before
    assert rm.n_unrecorded > 0, "the walk should have outgrown the budget"
    assert rm.n_vertices >= cfg.max_vertices - cfg.view_reserve  # the budget was used
    assert rm.merge_radius_now == rm.epsilon  # coarse merging beyond 80 %
    assert n_out >= 5, "views saved out of recorded territory, their excursion recorded"
    # vertices added in the coarse phase keep more than epsilon from every older vertex,
    # except views and recorded excursions (from the reserve)
    x = rm.metric_coordinates(rm.vertices())
    view_ids = {v.vertex for v in reachable + isolated}
    for k in range(int(0.8 * 1000), cfg.max_vertices - cfg.view_reserve):
        if k in view_ids:
            continue
        d = np.sqrt(np.sum((x[:k] - x[k]) ** 2, axis=1))
        assert d.min() > rm.epsilon
    for _ in range(400):  # come back into recorded territory
        if rm.recording:
            break
        rm.add(rm.current_state * 0.99)
    assert rm.recording
    start = rm.current_state
    for view in reachable:  # every view with a recorded path: exact, under the contract
        for approach in (False, True):
            path = rm.plan(start, view, approach=approach)
            check_path(rm, path, start, view.q)
    for view in isolated:  # no room left for its excursion: refused, never a shortcut
        with pytest.raises(GoalUnreachableError, match="not connected"):
            rm.plan(start, view)


def test_view_reserve_and_a_full_roadmap() -> None:
    cfg = RoadmapConfig(epsilon=1.0, max_vertices=1000)
    assert cfg.view_reserve == 100
    rm = Roadmap(config=cfg)
    k = 0
    while rm.n_vertices < 1000 - 100:  # ordinary states, 2 epsilon apart along d4
        rm.add(d4(2.0 * k)[0])
        k += 1
    assert rm.add(d4(2.0 * k)[0]) == -1  # closed: farther than epsilon is not recorded
    assert not rm.recording and rm.n_unrecorded == 1
    assert rm.add(d4(2.0 * (k - 1) + 0.6)[0]) == rm.n_vertices - 1  # merged: within epsilon
    assert rm.recording
    while rm.n_vertices < 1000:  # the reserve takes views only
        q = d4(2.0 * (k - 1) + 0.5 + 1e-3 * rm.n_vertices)[0]
        rm.add(q)
        rm.make_view(f"v{rm.n_vertices}", created_s=0.0)
    assert rm.n_vertices == 1000
    same = rm.make_view("again", created_s=0.0)  # the state is a vertex already: fine
    assert same.vertex == rm.current_vertex
    rm.add(d4(2.0 * (k - 1) + 0.75)[0])
    with pytest.raises(RoadmapFullError, match="budget of 1000 vertices"):
        rm.make_view("one too many", created_s=0.0)
    assert rm.n_vertices == 1000


def test_unbounded_roadmap_and_bad_budgets() -> None:
    rm = Roadmap(config=RoadmapConfig(max_vertices=None))
    for k in range(3000):
        rm.add(d4(2.0 * k)[0])
    assert rm.n_vertices == 3000 and rm.n_unrecorded == 0
    with pytest.raises(ConfigurationError, match="max_vertices must be None or an integer"):
        RoadmapConfig(max_vertices=999)
    with pytest.raises(ConfigurationError, match="max_vertices"):
        RoadmapConfig(max_vertices=2.5e5)  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match=r"tree_cache must be an integer in \[1, 1024\]"):
        RoadmapConfig(tree_cache=0)


def test_tree_cache_keeps_the_most_recently_used_trees() -> None:
    rng = np.random.default_rng(5)
    rm = Roadmap(config=RoadmapConfig(tree_cache=3))
    for q in random_trace(rng, 1500, jumps=False):
        rm.add(q)
    goals = [0, 50, 100, 150]
    for g in goals:
        rm.shortest_path_ids(rm.current_vertex, g)
    assert rm.cached_tree_goals == [50, 100, 150]  # the least recently used (0) was dropped
    rm.shortest_path_ids(rm.current_vertex, 50)  # used again: now the most recent
    rm.install_tree(0, rm.tree_job(0)())
    assert rm.cached_tree_goals == [150, 50, 0]
    ids = rm.shortest_path_ids(rm.current_vertex, 0)
    fresh = dijkstra(rm.csr(), directed=False, indices=0)[rm.current_vertex]
    assert path_length(rm, ids) == pytest.approx(fresh, rel=1e-12)


def test_approach_stops_where_the_trace_broke() -> None:
    rm = Roadmap(1.0)
    for v in np.linspace(0.0, 3.0, 13):
        rm.add(d4(v)[0])
    rm.break_trace()  # e.g. a restart: the next state was not reached from the last one
    for v in np.linspace(10.0, 10.5, 3):
        rm.add(d4(v)[0])
    view = rm.make_view("after the break", created_s=0.0)
    q_app = rm.vertices()[list(view.approach)]
    assert np.all(q_app[:, 3] >= 10.0)  # never reaches back across the break
    for q in d4(9.0, 8.0, 7.0, 6.0, 5.0, 4.0, 3.0):  # now connect the islands
        rm.add(q)
    path = rm.plan(rm.current_state, view, approach=True)
    check_path(rm, path, rm.current_state, view.q)


def test_rows_below_counts_read_earlier_are_stable() -> None:
    rng = np.random.default_rng(8)
    rm = Roadmap(1.0, capacity=16)
    trace = random_trace(rng, 2000)
    for q in trace[:300]:
        rm.add(q)
    nv, ne, nt = rm.counts()
    v0, (uv0, w0), t0 = rm.vertices(0, nv).copy(), rm.edges(0, ne), rm.trace(0, nt)
    for q in trace[300:]:  # grows the arrays (capacity doubles several times)
        rm.add(q)
    np.testing.assert_array_equal(rm.vertices(0, nv), v0)
    uv1, w1 = rm.edges(0, ne)
    np.testing.assert_array_equal(uv1, uv0)
    np.testing.assert_array_equal(w1, w0)
    np.testing.assert_array_equal(rm.trace(0, nt), t0)
    assert rm.edges()[0].dtype == np.int64 and rm.trace().dtype == np.int64


def test_tree_job_in_the_worker_process_equals_the_one_in_a_thread() -> None:
    rng = np.random.default_rng(11)
    rm = Roadmap(1.0)
    for q in random_trace(rng, 3000):
        rm.add(q)
    view = rm.make_view("v", created_s=0.0)
    for q in random_trace(rng, 500):
        rm.add(q)
    local = rm.tree_job(view)()
    isolated = rm.tree_job(view, isolate=True)()  # scipy's Dijkstra in another process
    np.testing.assert_array_equal(isolated.tree.dist, local.tree.dist)
    np.testing.assert_array_equal(isolated.tree.pred, local.tree.pred)
    rm.install_tree(view, isolated)
    path = rm.plan(rm.current_state, view)
    check_path(rm, path, rm.current_state, view.q)


def test_anchor_records_the_excursion_so_a_return_can_start_out_there() -> None:
    cfg = RoadmapConfig(epsilon=1.0, max_vertices=1000)
    rm = Roadmap(config=cfg)
    k = 0
    while rm.n_vertices < 1000 - cfg.view_reserve:  # fill to the closed stage along d4
        rm.add(d4(0.3 * k)[0])
        k += 1
    home = rm.make_view("home", created_s=0.0)
    end = 0.3 * (k - 1)
    out = [np.array([0.01 * i * DEG, 0.0, 0.0, end]) for i in range(1, 400)]  # knob phi1
    for q in out:
        assert rm.add(q) == -1 or rm.recording  # leaves recorded territory: not recorded
    assert not rm.recording
    with pytest.raises(PlanningError, match="more than epsilon"):
        rm.plan(out[-1], home)
    n0 = rm.n_vertices
    assert rm.anchor() is True and rm.recording
    assert rm.n_vertices - n0 <= 5  # the trail: states > epsilon apart, 4 deg of travel
    path = rm.plan(out[-1], home, approach=True)
    check_path(rm, path, out[-1], home.q)
    assert rm.anchor() is True  # recording already: nothing to do
    assert rm.n_isolated_views == 0

"""The soak: a long simulated procedure, run faster than real time, measured.

A scripted operator drives the digital twin through the controller at 100 Hz for
``hours`` of simulated time (4 h = 1.44 million states), with the session recorded in an
SQLite store, saving a view every ``view_every_s`` and returning to a random saved view
every ``return_every_s``. Measured: cycle compute time, plan time of each return, memory
(RSS through ``resource``; Python heap through ``tracemalloc`` when asked, which slows the
run), the sizes of everything that could grow (controller deques, roadmap, pending store
batch), and at the end the store is reopened and compared with the live roadmap and views.

::

    python -m icenav.apps.soak --hours 4            # the full soak (make soak)
    python -m icenav.apps.soak --minutes 30 --json out.json
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import resource
import sys
import tempfile
import threading
import time
import tracemalloc
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icenav.errors import ConfigurationError

__all__ = ["SoakConfig", "SoakReport", "main", "run_soak"]

CYCLE_TARGET_S = 0.005
"""Target for the 99th percentile of the cycle compute time (s): half the 100 Hz
period (store commits with fsync included), so the loop keeps its rate."""
PLAN_TARGET_S = 0.05
"""Target for the longest planning work inside one control cycle (s): on a large roadmap
the search runs in a thread, and the cycle that installs its result repairs and walks the
tree; meanwhile the loop (watchdog, limits; not the e-stop, which acts from the caller's
thread) pauses."""


@dataclass(frozen=True)
class SoakConfig:
    """Settings of a soak run."""

    duration_s: float = 4 * 3600.0
    """Simulated duration (s)."""
    rate_hz: float = 100.0
    """Control rate (Hz)."""
    view_every_s: float = 120.0
    """Save a view this often (simulated s)."""
    return_every_s: float = 180.0
    """Return to a random saved view this often (simulated s)."""
    seed: int = 0
    """Seeds the operator's motions and the choice of views."""
    trace_memory: bool = False
    """Measure the Python heap with tracemalloc (slower)."""
    box_scale: float = 1.0
    """Size of the region the operator explores, as a fraction of the default box
    (+-1.2 rad knobs, +-pi rad roll, +-30 mm translation)."""
    max_vertices: int | None = 250_000
    """Vertex budget of the session's roadmap (``RoadmapConfig.max_vertices``; None:
    unbounded, as before the budget)."""
    gc_policy: bool = True
    """Apply the controller's GC policy (``Controller.settle_gc``: freeze, no automatic
    full collection, full collections between cycles), as the real-time loop does."""
    heap_top: int = 0
    """With ``trace_memory``: print this many largest heap sites (tracemalloc, by line) to
    stderr at the end of the run."""

    def __post_init__(self) -> None:
        if int(self.heap_top) < 0:
            raise ConfigurationError(f"heap_top must be >= 0 sites, got {self.heap_top}")
        for name in ("duration_s", "rate_hz", "view_every_s", "return_every_s", "box_scale"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                unit = {"rate_hz": "Hz", "box_scale": "(fraction)"}.get(name, "s")
                raise ConfigurationError(f"{name} must be finite and > 0 {unit}, got {value}")


@dataclass(frozen=True)
class SoakReport:
    """What a soak run measured."""

    states: int
    """Control cycles run (states recorded)."""
    simulated_s: float
    """Simulated time (s)."""
    wall_s: float
    """Wall-clock time of the run (s)."""
    cycle_p50_ms: float
    """Median cycle compute time (ms), store included."""
    cycle_p99_ms: float
    """99th percentile of the cycle compute time (ms)."""
    cycle_max_ms: float
    """Longest cycle (ms)."""
    cycle_p99_no_plan_ms: float
    """99th percentile of the cycles that did not plan a return (ms)."""
    cycle_max_no_plan_ms: float
    """Longest cycle that did not plan a return (ms)."""
    cycle_max_save_ms: float
    """Longest cycle that saved a view (ms; the view is committed to the store at once)."""
    cycle_max_other_ms: float
    """Longest cycle that neither planned nor saved (ms)."""
    plan_max_ms: float
    """Longest plan of a return to a view (ms)."""
    plan_mean_ms: float
    """Mean plan time (ms)."""
    views_saved: int
    """Views saved."""
    returns_done: int
    """Returns that reached their view."""
    returns_failed: int
    """Returns refused or aborted."""
    returns_unfinished: int
    """Returns still under way when the run ended."""
    failure_messages: tuple[str, ...]
    """The controller's message for each failed return."""
    max_return_error: float
    """Largest joint error at the end of a return (rad or mm)."""
    roadmap_vertices: int
    """Roadmap size at the end (vertices)."""
    roadmap_edges: int
    """Roadmap size at the end (edges)."""
    roadmap_unrecorded: int
    """States not recorded because the vertex budget was closed."""
    isolated_views: int
    """Views saved out of recorded territory whose excursion could not be recorded (no
    path leads to them; returns to them are refused)."""
    rss_start_mb: float
    """Peak RSS after the first tenth of the run (MB)."""
    rss_end_mb: float
    """Peak RSS at the end (MB)."""
    heap_start_mb: float
    """Python heap after the first tenth (MB; 0 without trace_memory)."""
    heap_end_mb: float
    """Python heap at the end (MB; 0 without trace_memory)."""
    max_deque_len: int
    """Longest controller deque (cycle_times, cycle_starts) at the end."""
    store_consistent: bool
    """The reopened store equals the live roadmap and views."""
    faults: int
    """Cycles that ended in FAULT or ESTOP (should be 0)."""
    gc_collections: tuple[int, int, int]
    """Garbage collections run during the soak, per generation (0, 1, 2 = full)."""
    gc_max_ms: tuple[float, float, float]
    """Longest garbage collection per generation (ms; any thread: a collection holds the
    GIL, so it stalls the control thread too)."""
    commit_max_ms: float
    """Longest store commit (ms, on whichever thread committed)."""
    commit_in_cycle_max_ms: float
    """Longest time a single control cycle spent committing to the store (ms; 0 when all
    commits run on the store's writer thread)."""
    plan_in_loop_max_ms: float
    """Longest planning work (``Roadmap.plan`` with its tree repair, ``install_tree``)
    inside one control cycle (ms): the cycle that asks for a return, or the later one in
    which a path planned in a thread is installed."""
    longest_cycles: tuple[tuple[float, float, float, float, float, str], ...]
    """The 5 longest cycles: (cycle ms, its control-thread CPU ms, of it in garbage
    collection ms, in store commits ms, in planning ms, kind "plan" / "save" / "other")."""
    cycle_cpu_p99_ms: float
    """99th percentile of the control thread's CPU time per cycle (ms): what the cycle
    computed itself, without waiting for the GIL or for a core."""
    cycle_cpu_max_ms: float
    """Largest CPU time of one cycle on the control thread (ms). A cycle much longer than
    its CPU time waited: for another thread holding the GIL, or for a busy machine."""
    full_gc_between_cycles_max_ms: float
    """Longest full collection run between cycles by the GC policy (ms; 0 if none)."""
    rss_now_end_mb: float
    """Resident set size at the end (MB, current rather than peak)."""
    rss_samples: tuple[tuple[float, float, int], ...]
    """(simulated s, current RSS MB, roadmap vertices) at 20 points of the run."""

    @property
    def cycle_within_target(self) -> bool:
        """p99 of the cycles that do not plan within :data:`CYCLE_TARGET_S`."""
        return self.cycle_p99_no_plan_ms <= CYCLE_TARGET_S * 1e3

    @property
    def plan_within_target(self) -> bool:
        """Longest planning work inside a control cycle within :data:`PLAN_TARGET_S`."""
        return max(self.plan_max_ms, self.plan_in_loop_max_ms) <= PLAN_TARGET_S * 1e3


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _rss_now_mb() -> float:
    """Current (not peak) resident set size (MB), from /proc (Linux); the peak elsewhere."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            pages = int(f.read().split()[1])
        return pages * resource.getpagesize() / 2**20
    except (OSError, ValueError, IndexError):
        return _rss_mb()


class _Probe:
    """Times what can stall a control cycle: garbage collections (``gc.callbacks``, any
    thread: a collection holds the GIL) and store commits (wrapped), as running totals
    that the soak reads before and after each cycle."""

    def __init__(self) -> None:
        self.gc_s = 0.0
        self.gc_max_s = [0.0, 0.0, 0.0]
        self.gc_count = [0, 0, 0]
        self.commit_s = 0.0
        """Commit time spent on the thread that built the probe (the control thread)."""
        self.commit_max_s = 0.0
        """Longest commit, any thread (s)."""
        self.commits = 0
        self.plan_s = 0.0
        """Time spent planning on the control thread (s)."""
        self._owner = threading.get_ident()
        self._t0 = 0.0

    def gc_callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        d = time.perf_counter() - self._t0
        g = int(info.get("generation", 0))
        self.gc_s += d
        self.gc_count[g] += 1
        self.gc_max_s[g] = max(self.gc_max_s[g], d)

    def wrap_planning(self, roadmap: object) -> None:
        """Time the roadmap's planning calls made on the probe's thread (the control
        thread): plan (with its tree repair) and install_tree."""
        for name in ("plan", "install_tree"):
            fn = getattr(roadmap, name)

            def timed(*args: Any, _fn: Any = fn, **kwargs: Any) -> Any:
                if threading.get_ident() != self._owner:
                    return _fn(*args, **kwargs)
                t0 = time.perf_counter()
                try:
                    return _fn(*args, **kwargs)
                finally:
                    self.plan_s += time.perf_counter() - t0

            setattr(roadmap, name, timed)

    def wrap_commit(self, store: object) -> None:
        commit = store.commit  # type: ignore[attr-defined]

        def timed() -> None:
            t0 = time.perf_counter()
            try:
                commit()
            finally:
                d = time.perf_counter() - t0
                if threading.get_ident() == self._owner:
                    self.commit_s += d
                self.commits += 1
                self.commit_max_s = max(self.commit_max_s, d)

        store.commit = timed  # type: ignore[attr-defined]


def run_soak(config: SoakConfig, session: str | Path | None = None) -> SoakReport:
    """Run the soak; ``session`` is the SQLite file (a temporary one when None)."""
    from icenav.apps.wiring import make_sim_controller
    from icenav.control.controller import ControllerConfig
    from icenav.control.state import ControllerState, Mode
    from icenav.persistence.store import SessionStore
    from icenav.recovery.roadmap import RoadmapConfig, warm_up_planner

    tmp = None
    if session is None:
        tmp = tempfile.TemporaryDirectory(prefix="icenav-soak-")
        session = Path(tmp.name) / "soak.icenav"
    rng = np.random.default_rng(config.seed)
    sim_t = [0.0]
    built = make_sim_controller(
        imaging=False,
        session=session,
        clock=lambda: sim_t[0],
        config=ControllerConfig(rate_hz=config.rate_hz),
        roadmap_config=RoadmapConfig(max_vertices=config.max_vertices),
    )
    ctrl = built.controller
    dt = ctrl.config.dt
    n_total = int(round(config.duration_s / dt))
    every_view = max(1, int(round(config.view_every_s / dt)))
    every_return = max(1, int(round(config.return_every_s / dt)))
    # the operator explores a box: knobs +-1.2 rad, roll +-pi, translation +-30 mm
    box = np.array([1.2, 1.2, math.pi, 30.0]) * config.box_scale
    vmax = np.asarray(ctrl.config.max_velocity) * 0.4
    velocity = np.zeros(4)
    cycle_ms = np.empty(n_total)
    plan_ms: list[float] = []
    returns_done = returns_failed = returns_unfinished = faults = views = 0
    save_cycles = np.zeros(n_total, bool)
    max_return_error = 0.0
    failures: list[str] = []
    plan_cycles = np.zeros(n_total, bool)
    rss_start = heap_start = 0.0
    gc_ms = np.zeros(n_total)
    cpu_ms = np.zeros(n_total)
    planning_ms = np.zeros(n_total)
    commit_ms = np.zeros(n_total)
    probe = _Probe()
    if built.store is not None:
        probe.wrap_commit(built.store)
    probe.wrap_planning(ctrl.roadmap)
    rss_samples: list[tuple[float, float, int]] = []
    every_sample = max(1, n_total // 20)

    def timed_step(k: int) -> ControllerState:
        g0, c0, p0 = probe.gc_s, probe.commit_s, probe.plan_s
        t0 = time.perf_counter()
        c0_cpu = time.thread_time()
        sim_t[0] += dt
        st = ctrl.step()
        cycle_ms[k] = (time.perf_counter() - t0) * 1e3
        cpu_ms[k] = (time.thread_time() - c0_cpu) * 1e3
        gc_ms[k] = (probe.gc_s - g0) * 1e3
        commit_ms[k] = (probe.commit_s - c0) * 1e3
        planning_ms[k] = (probe.plan_s - p0) * 1e3
        if config.gc_policy:  # between cycles, as the real-time loop does in its idle time
            t1 = time.perf_counter()
            if ctrl.collect_garbage_if_due():
                between_gc_ms.append((time.perf_counter() - t1) * 1e3)
        if k % every_sample == every_sample - 1:
            rss_samples.append((sim_t[0], _rss_now_mb(), ctrl.roadmap.n_vertices))
        return st

    between_gc_ms: list[float] = []
    if ctrl.config.plan_in_process:
        # as Controller.start() does: the worker is spawned before the procedure, so the
        # first return does not hold (in simulated time) while it imports scipy
        warm_up_planner()
    if config.gc_policy:
        ctrl.settle_gc()
    gc.callbacks.append(probe.gc_callback)
    if config.trace_memory:
        tracemalloc.start()
    wall0 = time.perf_counter()
    i = 0
    try:
        while i < n_total:
            if rss_start == 0.0 and i >= n_total // 10:
                rss_start = _rss_mb()
                heap_start = (
                    tracemalloc.get_traced_memory()[0] / 2**20 if config.trace_memory else 0
                )
            if i % every_return == every_return - 1 and len(ctrl.views) > 0:
                names = ctrl.views.names()
                name = names[int(rng.integers(len(names)))]
                ctrl.goto_view(name)
                state = timed_step(i)  # the plan (or its hand-off to a thread) runs here
                plan_ms.append(cycle_ms[i])
                plan_cycles[i] = True
                i += 1
                while i < n_total and state.mode is Mode.GOTO_VIEW:
                    state = timed_step(i)
                    i += 1
                if state.mode is Mode.GOTO_VIEW:  # cut short by the end of the run
                    returns_unfinished += 1
                elif state.mode is Mode.IDLE and "done" in state.message:
                    returns_done += 1
                    err = float(np.max(np.abs(state.q_motor - ctrl.views.get(name).q)))
                    max_return_error = max(max_return_error, err)
                else:
                    returns_failed += 1
                    failures.append(f"t={state.time:.1f} s, {name!r}: {state.message}")
                continue
            if i % every_view == every_view - 1:
                ctrl.save_view(f"soak view {views + 1}")
                views += 1
                save_cycles[i] = True
            # a smooth random walk inside the box (Ornstein-Uhlenbeck on the velocity)
            q = ctrl.snapshot().q_motor
            pull = -0.5 * np.clip(q / box, -2, 2) ** 3
            velocity = 0.98 * velocity + 0.02 * (rng.normal(0, 1, 4) + pull) * 3
            velocity = np.clip(velocity, -1, 1)
            ctrl.jog(velocity * vmax, "knob")
            state = timed_step(i)
            if state.mode in (Mode.FAULT, Mode.ESTOP):
                faults += 1
                ctrl.reset_fault()
            i += 1
        wall = time.perf_counter() - wall0
        heap_end = tracemalloc.get_traced_memory()[0] / 2**20 if config.trace_memory else 0.0
        rss_end = _rss_mb()
        rss_now_end = _rss_now_mb()
        max_deque = max(len(ctrl.cycle_times), len(ctrl.cycle_starts))
        live_v = ctrl.roadmap.vertices()
        live_e = ctrl.roadmap.edges()
        live_t = ctrl.roadmap.trace()
        unrecorded = ctrl.roadmap.n_unrecorded
        isolated = ctrl.roadmap.n_isolated_views
        live_views = [(v.name, v.q.copy()) for v in ctrl.views]
        if config.trace_memory and config.heap_top:
            top = tracemalloc.take_snapshot().statistics("lineno")[: config.heap_top]
            for stat in top:
                print(
                    f"heap: {stat.size / 2**20:8.1f} MB {stat.count:9d} blocks  "
                    f"{stat.traceback[0]}",
                    file=sys.stderr,
                )
    finally:
        gc.callbacks.remove(probe.gc_callback)
        ctrl.release_gc()
        if config.trace_memory:
            tracemalloc.stop()
        built.close()
    with SessionStore(session, read_only=True) as store:
        rm = store.load_roadmap()
        stored_views = [(v.name, v.q) for v in store.load_views()]
        e = rm.edges()
        consistent = (
            np.array_equal(rm.vertices(), live_v)
            and np.array_equal(rm.trace(), live_t)
            and {tuple(p) for p in e[0].tolist()} == {tuple(p) for p in live_e[0].tolist()}
            and [n for n, _ in stored_views] == [n for n, _ in live_views]
            and all(
                np.array_equal(a[1], b[1]) for a, b in zip(stored_views, live_views, strict=False)
            )
        )
    if tmp is not None:
        tmp.cleanup()
    plans = np.asarray(plan_ms) if plan_ms else np.zeros(1)
    return SoakReport(
        states=n_total,
        simulated_s=n_total * dt,
        wall_s=wall,
        cycle_p50_ms=float(np.percentile(cycle_ms, 50)),
        cycle_p99_ms=float(np.percentile(cycle_ms, 99)),
        cycle_max_ms=float(cycle_ms.max()),
        cycle_p99_no_plan_ms=float(np.percentile(cycle_ms[~plan_cycles], 99)),
        cycle_max_no_plan_ms=float(cycle_ms[~plan_cycles].max()),
        cycle_max_save_ms=float(cycle_ms[save_cycles].max()) if save_cycles.any() else 0.0,
        cycle_max_other_ms=float(cycle_ms[~(plan_cycles | save_cycles)].max()),
        plan_max_ms=float(plans.max()),
        plan_mean_ms=float(plans.mean()),
        views_saved=views,
        returns_done=returns_done,
        returns_failed=returns_failed,
        returns_unfinished=returns_unfinished,
        failure_messages=tuple(failures),
        max_return_error=max_return_error,
        roadmap_vertices=int(live_v.shape[0]),
        roadmap_edges=int(live_e[0].shape[0]),
        roadmap_unrecorded=unrecorded,
        isolated_views=isolated,
        rss_start_mb=rss_start,
        rss_end_mb=rss_end,
        heap_start_mb=float(heap_start),
        heap_end_mb=float(heap_end),
        max_deque_len=max_deque,
        store_consistent=bool(consistent),
        faults=faults,
        gc_collections=(probe.gc_count[0], probe.gc_count[1], probe.gc_count[2]),
        gc_max_ms=(probe.gc_max_s[0] * 1e3, probe.gc_max_s[1] * 1e3, probe.gc_max_s[2] * 1e3),
        commit_max_ms=probe.commit_max_s * 1e3,
        commit_in_cycle_max_ms=float(commit_ms.max()),
        plan_in_loop_max_ms=float(planning_ms.max()),
        longest_cycles=tuple(
            (
                float(cycle_ms[k]),
                float(cpu_ms[k]),
                float(gc_ms[k]),
                float(commit_ms[k]),
                float(planning_ms[k]),
                "plan" if plan_cycles[k] else "save" if save_cycles[k] else "other",
            )
            for k in np.argsort(cycle_ms)[::-1][:5].tolist()
        ),
        cycle_cpu_p99_ms=float(np.percentile(cpu_ms, 99)),
        cycle_cpu_max_ms=float(cpu_ms.max()),
        full_gc_between_cycles_max_ms=max(between_gc_ms, default=0.0),
        rss_now_end_mb=rss_now_end,
        rss_samples=tuple(rss_samples),
    )


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m icenav.apps.soak [--hours H | --minutes M] [--json FILE] [--session FILE]``."""
    p = argparse.ArgumentParser(
        prog="python -m icenav.apps.soak", description=__doc__.split("\n")[0]
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--hours", type=float, default=None, help="simulated hours (default 4)")
    g.add_argument("--minutes", type=float, default=None, help="simulated minutes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--session", type=Path, default=None, help="SQLite file (default: temp)")
    p.add_argument("--json", type=Path, default=None, help="write the report as JSON")
    p.add_argument("--trace-memory", action="store_true", help="tracemalloc (slower)")
    p.add_argument("--no-gc-policy", action="store_true", help="leave Python's default GC policy")
    p.add_argument(
        "--max-vertices",
        type=int,
        default=250_000,
        help="vertex budget of the roadmap (0: unbounded)",
    )
    p.add_argument(
        "--heap-top", type=int, default=0, help="with --trace-memory: print the N largest sites"
    )
    p.add_argument(
        "--box-scale", type=float, default=1.0, help="explored region, fraction of the default"
    )
    args = p.parse_args(argv)
    seconds = 4 * 3600.0
    if args.hours is not None:
        seconds = args.hours * 3600.0
    elif args.minutes is not None:
        seconds = args.minutes * 60.0
    if not (math.isfinite(seconds) and seconds > 0):
        p.error(f"the duration must be > 0, got {seconds} s")
    if args.session is not None and args.session.exists():
        p.error(f"--session {args.session} exists: the soak needs a fresh file")
    report = run_soak(
        SoakConfig(
            duration_s=seconds,
            seed=args.seed,
            trace_memory=args.trace_memory,
            heap_top=max(0, args.heap_top),
            gc_policy=not args.no_gc_policy,
            max_vertices=args.max_vertices if args.max_vertices > 0 else None,
            box_scale=args.box_scale,
        ),
        args.session,
    )
    d = asdict(report)
    d["cycle_within_target"] = report.cycle_within_target
    d["plan_within_target"] = report.plan_within_target
    for k, v in d.items():
        print(f"{k:>22}: {v:.4g}" if isinstance(v, float) else f"{k:>22}: {v}")
    if args.json is not None:
        args.json.write_text(json.dumps(d, indent=1) + "\n", encoding="utf-8")
    ok = (
        report.store_consistent
        and report.faults == 0
        and report.cycle_within_target
        and report.plan_within_target
    )
    print("soak: " + ("all within targets" if ok else "FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""The soak, shortened to 10 simulated minutes (the full 4 h is `make soak`).

Baselines, in the same run: the controller's cycle without a session store (the same
operator for 30 simulated seconds), to show what recording costs per cycle; and the soak's
operator on the twin driven by the rebuilt controller and by the controller before the
rebuild (``benchmarks/_baseline_controller.py``), interleaved, to show the rebuild is no
slower.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.common import Result
from icenav.apps.soak import CYCLE_TARGET_S, PLAN_TARGET_S, SoakConfig, run_soak


def _cycle_without_store(seconds: float = 30.0) -> float:
    from icenav.apps.wiring import make_sim_controller

    t = [0.0]
    built = make_sim_controller(imaging=False, clock=lambda: t[0])
    ctrl = built.controller
    rng = np.random.default_rng(0)
    times = []
    v = np.zeros(4)
    for _ in range(int(seconds * ctrl.config.rate_hz)):
        v = np.clip(0.98 * v + 0.05 * rng.normal(0, 1, 4), -1, 1)
        ctrl.jog(v * [0.4, 0.4, 0.6, 4.0], "knob")
        t[0] += ctrl.config.dt
        t0 = time.perf_counter()
        ctrl.step()
        times.append(time.perf_counter() - t0)
    built.close()
    return float(np.percentile(times, 99)) * 1e3


def _old_and_new(seconds: float = 20.0) -> tuple[float, float]:
    """Median cycle (ms) of the soak's operator on the twin (seed 100, no store, no image)
    under the old and the new controller, in alternating 2 s blocks."""
    from benchmarks._baseline_controller import Controller as OldController
    from icenav.control.controller import Controller, ControllerConfig
    from icenav.devices.sim_robot import SimulatedRobot
    from icenav.sim import CatheterPlant

    ctrls = []
    for cls in (OldController, Controller):
        robot = SimulatedRobot(CatheterPlant(seed=100), on_excess="clip")
        robot.record_commands = False
        ctrls.append(cls(robot, ControllerConfig()))
    rng = np.random.default_rng(0)
    times: list[list[float]] = [[], []]
    v = np.zeros(4)
    for _ in range(int(seconds / 2.0)):
        for k, ctrl in enumerate(ctrls):
            for _ in range(200):
                v = np.clip(0.98 * v + 0.05 * rng.normal(0, 1, 4), -1, 1)
                ctrl.jog(v * [0.4, 0.4, 0.6, 4.0], "knob")
                t0 = time.perf_counter()
                ctrl.step()
                times[k].append(time.perf_counter() - t0)
    return float(np.median(times[0])) * 1e3, float(np.median(times[1])) * 1e3


def main() -> list[Result]:
    r = run_soak(SoakConfig(duration_s=600.0, view_every_s=60.0, return_every_s=90.0))
    base = _cycle_without_store()
    old_ms, new_ms = _old_and_new()
    return [
        Result(
            "soak operator on the twin, median cycle (rebuilt controller)",
            new_ms,
            "ms",
            old_ms,
            "the controller before the rebuild, same run",
            "ratio >= 1 (no slower)",
            new_ms <= old_ms * 1.05,
        ),
        Result(
            "soak 10 min: cycle p99 (no plan)",
            r.cycle_p99_no_plan_ms,
            "ms",
            base,
            "same operator, no store (p99)",
            f"<= {CYCLE_TARGET_S * 1e3:g} ms",
            r.cycle_within_target,
        ),
        Result("soak 10 min: cycle max (no plan)", r.cycle_max_no_plan_ms, "ms"),
        Result(
            "soak 10 min: plan max (the cycle asking for a return)",
            r.plan_max_ms,
            "ms",
            target=f"<= {PLAN_TARGET_S * 1e3:g} ms",
            met=r.plan_within_target,
        ),
        Result("soak 10 min: planning inside a cycle, max", r.plan_in_loop_max_ms, "ms"),
        Result("soak 10 min: control-thread CPU per cycle, p99", r.cycle_cpu_p99_ms, "ms"),
        Result("soak 10 min: commit on the control thread, max", r.commit_in_cycle_max_ms, "ms"),
        Result("soak 10 min: full GC between cycles, max", r.full_gc_between_cycles_max_ms, "ms"),
        Result("soak 10 min: speed-up over real time", r.simulated_s / r.wall_s, "x"),
        Result("soak 10 min: RSS growth after 1 min", r.rss_end_mb - r.rss_start_mb, "MB"),
        Result("soak 10 min: roadmap vertices", float(r.roadmap_vertices), "vertices"),
        Result(
            "soak 10 min: store consistent",
            float(r.store_consistent),
            "bool",
            met=r.store_consistent,
        ),
    ]

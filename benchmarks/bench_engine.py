"""Population engines: 10 catheters of the spin evaluation on Ray against one process.

Each job is :func:`icenav.eval.spin.evaluate_catheter` of one development catheter (seeds
100-109; the held-out 110-119 are not touched): the paper's dense and 5-point calibrations
in the straight vessel, then the 20 / 40 / 60 deg spins (360 samples) uncompensated, with
the dense and with the simplified map. Measured in the same run: the local engine in one
process (the baseline), the local process pool with 2 processes, and Ray on a local instance
with 2 CPUs on the loopback address (its start-up timed apart and reported, then included
in the ratio that counts). Target (issue 20): Ray >= 1.6x faster than one process on
2 cores, with records identical to the local engine's. On a machine shared with other work
the ratio falls with the load (the load average is printed).

``ICENAV_BENCH_CATHETERS=N`` changes the number of catheters (default 10).
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict
from typing import Any

from benchmarks.common import Result
from icenav.eval.engine import run_jobs
from icenav.eval.spin import evaluate_catheter

TARGET_SPEEDUP = 1.6
CONDITIONS = ("none", "dense", "simplified")


def catheter_records(seed: int) -> list[dict[str, Any]]:
    """One catheter's spin records (the job; module level so workers import it)."""
    run = evaluate_catheter(seed, ("straight",), conditions=CONDITIONS)
    return [asdict(r) for r in run.records]


def main() -> list[Result]:
    n = int(os.environ.get("ICENAV_BENCH_CATHETERS", "10"))
    seeds = list(range(100, 100 + n))
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    one = run_jobs(catheter_records, seeds, jobs=1, progress=False)
    one_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    pool = run_jobs(catheter_records, seeds, jobs=2, progress=False)
    pool_s = time.perf_counter() - t0
    import ray

    t0 = time.perf_counter()
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        configure_logging=False,
        log_to_driver=False,
        _node_ip_address="127.0.0.1",
    )
    init_s = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        on_ray = run_jobs(catheter_records, seeds, engine="ray", progress=False)
        ray_s = time.perf_counter() - t0
    finally:
        ray.shutdown()
    load1 = os.getloadavg()[0]
    identical = on_ray == one and pool == one
    speedup = one_s / (ray_s + init_s)
    load = f"load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores"
    return [
        Result(
            f"{n} catheters on Ray (2 CPUs), start-up included; {load}",
            ray_s + init_s,
            "s",
            baseline=one_s,
            baseline_name="local engine, one process",
            target=f">= {TARGET_SPEEDUP}x",
            met=speedup >= TARGET_SPEEDUP,
        ),
        Result(
            f"{n} catheters on Ray, start-up ({init_s:.1f} s) excluded",
            ray_s,
            "s",
            baseline=one_s,
            baseline_name="local engine, one process",
        ),
        Result(
            f"{n} catheters in the local pool (2 processes)",
            pool_s,
            "s",
            baseline=one_s,
            baseline_name="local engine, one process",
        ),
        Result(
            "records identical on the three engines (1 = yes)",
            float(identical),
            "",
            target="identical",
            met=identical,
        ),
    ]


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())

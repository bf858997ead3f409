"""Control loop: cycle compute time of the rebuilt controller against the old one (same run),
and period jitter of the real-time loop at 100 Hz and 500 Hz.

Ratio: the old controller (``benchmarks/_baseline_controller.py``, the pre-rebuild code kept
verbatim but for moved imports) and the new one step the same jogging operator on the
simulated robot, interleaved in blocks so that machine load hits both alike; the result is
the median cycle of each. Also measured: the real-time loop at 100 and 500 Hz (2 s each).

What differs in the work: the new controller decides every jog as a command (a ticket, the
authorization, the event log: about 5 us more per jog than the old field write), and its
published state computes the model's backbone (50 points for drawing, about 36 us) only when
a reader first asks for it, where the old one drew it every cycle; the console reads it a few
times per second. Both use today's kinematics.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks._baseline_controller import Controller as OldController
from benchmarks.common import Result
from icenav.control.controller import Controller, ControllerConfig
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot


def _make(cls: Any) -> Any:
    robot = SimulatedRobot(IdealPlant())
    robot.record_commands = False
    return cls(robot, ControllerConfig())


def stepped_cycle_times(blocks: int = 20, per_block: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """Median-ready cycle times (s) of the old and the new controller, interleaved."""
    old, new = _make(OldController), _make(Controller)
    rng = np.random.default_rng(0)
    times: dict[str, list[float]] = {"old": [], "new": []}
    v = np.zeros(4)
    for _ in range(blocks):
        for name, ctrl in (("old", old), ("new", new)):
            for _ in range(per_block):
                v = np.clip(0.98 * v + 0.05 * rng.normal(0, 1, 4), -1, 1)
                ctrl.jog(v * [0.4, 0.4, 0.6, 4.0], "knob")
                t0 = time.perf_counter()
                ctrl.step()
                times[name].append(time.perf_counter() - t0)
                if abs(ctrl.snapshot().q_motor[0]) > 1.2:  # stay inside the limits
                    v[0] = -np.sign(ctrl.snapshot().q_motor[0])
    return np.array(times["old"]), np.array(times["new"])


def run_rate(rate_hz: float, seconds: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    robot = SimulatedRobot(IdealPlant())
    robot.record_commands = False
    ctrl = Controller(robot, ControllerConfig(rate_hz=rate_hz))
    ctrl.start()
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        ctrl.jog([0.2, -0.1, 0.3, 1.0], "knob")
        time.sleep(0.02)
    ctrl.shutdown()
    compute = np.array(ctrl.cycle_times)[5:]
    periods = np.diff(np.array(ctrl.cycle_starts))[5:]
    return compute, periods


def main() -> list[Result]:
    old, new = stepped_cycle_times()
    results = [
        Result(
            "stepped cycle (jogging), median; p99 "
            f"{np.percentile(new, 99) * 1e6:.0f} us (old {np.percentile(old, 99) * 1e6:.0f} us)",
            float(np.median(new)) * 1e6,
            "us",
            float(np.median(old)) * 1e6,
            "the controller before the rebuild, same run",
            target="ratio >= 1 (no slower)",
            met=float(np.median(new)) <= float(np.median(old)) * 1.05,
        )
    ]
    for rate in (100.0, 500.0):
        compute, periods = run_rate(rate)
        p99 = float(np.percentile(compute, 99))
        jitter = float(np.std(periods - 1.0 / rate))
        results.append(
            Result(
                f"{rate:.0f} Hz real-time loop: cycle compute, median (p99 {p99 * 1e6:.0f} us)",
                float(np.median(compute)) * 1e6,
                "us",
                target=f"p99 < period {1e6 / rate:.0f} us",
                met=p99 < 1.0 / rate,
            )
        )
        worst = 1e6 * (periods.max() - 1 / rate)
        results.append(
            Result(
                f"{rate:.0f} Hz: period jitter (sd), worst late {worst:.0f} us",
                jitter * 1e6,
                "us",
            )
        )
    return results

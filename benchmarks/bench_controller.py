"""Control loop: cycle compute time and period jitter at 100 Hz and 500 Hz (issue 7).

The controller runs in its real-time thread on the simulated robot for 2 s at each rate,
jogging in knob mode. Baseline, in the same run: the bare robot I/O of one cycle (read the
encoders, command a position) without the controller's logic.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.common import Result, time_per_call
from icenav.control.controller import Controller, ControllerConfig
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot


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
    robot = SimulatedRobot(IdealPlant())
    robot.enable()
    robot.record_commands = False
    q = np.zeros(4)

    def bare() -> None:
        robot.read_state()
        robot.command_position(q)

    base = time_per_call(bare)
    results = []
    for rate in (100.0, 500.0):
        compute, periods = run_rate(rate)
        p99 = float(np.percentile(compute, 99))
        jitter = float(np.std(periods - 1.0 / rate))
        results.append(
            Result(
                f"{rate:.0f} Hz: cycle compute time, median (p99 {p99 * 1e6:.0f} us)",
                float(np.median(compute)) * 1e6,
                "us",
                base * 1e6,
                "bare robot read + command",
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

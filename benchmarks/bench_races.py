"""The race harness at length: 1,000,000 cycles with e-stops every 0-2 ms from another thread
while short go-to-view tasks start and end (``make test`` runs 100,000:
tests/reliability/test_races.py). Reports cycles, e-stops, deaths and moves after an e-stop
(both must be 0). Baseline, same run: the same cycles without the e-stopper and the script
(the cost of the races on the cycle)."""

from __future__ import annotations

import time

from tests.support.races import EventLog, drive_away_and_save, make_controller, run_random

from benchmarks.common import Result

CYCLES = 1_000_000


def main() -> list[Result]:
    log = EventLog()
    ctrl = make_controller(log)
    drive_away_and_save(ctrl)
    t0 = time.perf_counter()
    report = run_random(ctrl, log, CYCLES, seed=7)
    raced = (time.perf_counter() - t0) / CYCLES
    quiet = make_controller(EventLog())
    drive_away_and_save(quiet)
    t0 = time.perf_counter()
    for _ in range(100_000):
        quiet.step()
    base = (time.perf_counter() - t0) / 100_000
    ok = report.deaths == 0 and report.violations == 0 and report.cycle_gaps == 0
    return [
        Result(
            f"race harness: {report}",
            raced * 1e6,
            "us/cycle",
            base * 1e6,
            "the same cycle without e-stops",
            target="deaths 0, moves after an e-stop 0, final reset takes effect",
            met=ok and report.final_mode == "idle",
        )
    ]

"""The race harness of the control core: e-stops injected at every pre-emption point of a
cycle (deterministic), and e-stops from another thread every 0-2 ms while short go-to-view
tasks start and end (seeded random), on the real SimulatedRobot or emulated CANopen drives.

Invariants checked (``docs/safety.md``, "The control core under interleavings"):

- no cycle raises (an exception in a cycle would be caught and end in FAULT: counted as a
  *death* unless the fault was injected on purpose);
- the loop never stops advancing (every cycle's number is one more than the last);
- the robot never moves between an e-stop and the next reset (an event log, appended in the
  order things happen: a position command the robot accepted after ``estop()`` returned and
  before the robot was reset is a violation);
- a reset always takes effect (every reset asked after the latest e-stop ends the halt; a
  reset refused because an e-stop came after it is followed by one that is not).

Used by ``tests/reliability/test_races.py`` (100,000 random cycles) and
``benchmarks/bench_races.py`` (1,000,000).
"""

from __future__ import annotations

import logging
import random
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from icenav.control.commands import Outcome, Ticket
from icenav.control.config import ControllerConfig
from icenav.control.controller import Controller
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.errors import CommandTimeoutError


class EventLog:
    """Events in the order they happen (list.append is atomic under the GIL)."""

    def __init__(self) -> None:
        self.events: list[str] = []

    def add(self, what: str) -> None:
        self.events.append(what)

    def violations(self) -> int:
        """Position commands accepted after an e-stop returned and before the robot's
        next reset."""
        bad = 0
        stopped = False
        for e in self.events:
            if e == "estop_returned":
                stopped = True
            elif e == "robot_reset":
                stopped = False
            elif e == "command" and stopped:
                bad += 1
        return bad


class LoggedRobot(SimulatedRobot):
    """The real SimulatedRobot, logging accepted commands and resets, with optional hooks
    called before and after each call (the deterministic injections)."""

    def __init__(self, log: EventLog, hook: Callable[[str], None] | None = None) -> None:
        super().__init__(IdealPlant())
        self.record_commands = False
        self.log = log
        self.hook = hook

    def _at(self, point: str) -> None:
        if self.hook is not None:
            self.hook(point)

    def read_state(self) -> Any:
        self._at("read_state")
        return super().read_state()

    def command_position(self, q_motor: Any) -> None:
        self._at("command.before")
        super().command_position(q_motor)
        self.log.add("command")
        self._at("command.after")

    def stop(self) -> None:
        self._at("stop")
        super().stop()

    def reset_fault(self) -> None:
        self._at("reset_fault.before")
        super().reset_fault()
        self.log.add("robot_reset")
        self._at("reset_fault.after")

    def enable(self) -> None:
        self._at("enable.before")
        super().enable()
        self._at("enable.after")


class _Deaths(logging.Handler):
    """Counts the cycles that ended in an exception (the controller logs each at ERROR)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.texts: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.getMessage().startswith("control cycle"):
            self.texts.append(record.getMessage())


@dataclass
class HarnessReport:
    """What one random run did and found."""

    cycles: int = 0
    estops: int = 0
    resets_done: int = 0
    resets_refused_after_estop: int = 0
    resets_other: list[str] = field(default_factory=list)
    gotos_started: int = 0
    gotos_done: int = 0
    deaths: int = 0
    injected_faults: int = 0
    cycle_gaps: int = 0
    violations: int = 0
    final_mode: str = ""

    def __str__(self) -> str:
        return (
            f"{self.cycles} cycles, {self.estops} e-stops, {self.gotos_started} tasks started "
            f"({self.gotos_done} done), resets {self.resets_done} done / "
            f"{self.resets_refused_after_estop} refused (an e-stop came after) / "
            f"{len(self.resets_other)} failed (injected), {self.injected_faults} injected "
            f"faults, deaths {self.deaths}, violations {self.violations}, gaps "
            f"{self.cycle_gaps}, final mode {self.final_mode}"
        )


def drive_away_and_save(ctrl: Controller, steps: int = 30) -> None:
    """Save view "a" here, jog away, save "b" (stepped by hand, before any thread starts)."""
    ctrl.save_view("a")
    ctrl.step()
    for _ in range(steps):
        ctrl.jog([0.5, -0.3, 0.4, 2.0], "knob")
        ctrl.step()
    ctrl.save_view("b")
    ctrl.step()


def make_controller(log: EventLog, hook: Callable[[str], None] | None = None) -> Controller:
    """A controller on a logged SimulatedRobot (clock: the controller's own time)."""
    robot = LoggedRobot(log, hook)
    ctrl: Controller

    def clock() -> float:
        return ctrl.time

    ctrl = Controller(robot, ControllerConfig(rate_hz=500.0, publish_every=5), clock=clock)
    return ctrl


def run_random(
    ctrl: Controller,
    log: EventLog,
    cycles: int,
    seed: int,
    *,
    tick: Callable[[], None] | None = None,
    expected_faults: Callable[[str], bool] = lambda text: False,
    task: str = "goto",
) -> HarnessReport:
    """Step ``ctrl`` ``cycles`` times on one thread as fast as it goes, while an e-stopper
    thread e-stops every 0-2 ms (seeded) and a script thread starts short tasks (go to view
    "a" / "b", or spins) and resets after each e-stop; then a last reset, or a Stop if a task
    still runs. ``tick`` runs after each cycle (emulated drives); ``expected_faults(text)``
    says which cycle exceptions were injected on purpose (a raising adapter / tracker)."""
    report = HarnessReport()
    deaths = _Deaths()
    logger = logging.getLogger("icenav.control")
    logger.addHandler(deaths)
    rng = random.Random(seed)
    done = threading.Event()
    first_cycle = threading.Event()
    # The harness's own bookkeeping is ordered with one lock: an e-stop and its
    # "estop_returned" entry, and the asking of a reset, never interleave. Without it a reset
    # asked after ``estop()`` returned (a legitimate one: it clears that e-stop) could be
    # logged before the e-stopper thread got round to logging "estop_returned", and the
    # commands after that reset would be miscounted as violations. The controller's threads
    # (the loop, the e-stop's own steps) are not ordered by this lock.
    books = threading.Lock()

    def estopper() -> None:
        r = random.Random(seed + 1)
        first_cycle.wait()
        while not done.wait(r.uniform(0.0, 0.002)):
            with books:
                ctrl.estop("estopper")
                log.add("estop_returned")
            report.estops += 1

    def settle(ticket: Ticket) -> None:
        """Wait for the ticket's end (a task ends done, or failed by an e-stop)."""
        while not done.is_set():
            try:
                result = ticket.final(timeout=0.05)
            except CommandTimeoutError:
                continue
            _count(report, ticket, result.outcome, result.reason)
            return

    def script() -> None:
        names = ("a", "b")
        k = 0
        first_cycle.wait()
        while not done.is_set():
            if ctrl.machine.halted:
                with books:
                    reset = ctrl.reset_fault()
                settle(reset)
            else:
                k += 1
                ticket = ctrl.goto_view(names[k % 2]) if task == "goto" else ctrl.start_spin()
                if rng.random() < 0.05:
                    ctrl.stop()
                settle(ticket)

    threads = [threading.Thread(target=estopper), threading.Thread(target=script)]
    # switch threads every 0.1 ms (Python's default is 5 ms): on an idle machine a cycle
    # takes tens of microseconds, and the e-stopper and the script must meet the loop often
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    for t in threads:
        t.start()
    last = ctrl.cycle
    try:
        for i in range(cycles):
            ctrl.step()
            if i == 0:
                first_cycle.set()
            if ctrl.cycle != last + 1:
                report.cycle_gaps += 1
            last = ctrl.cycle
            if tick is not None:
                tick()
            report.cycles += 1
    finally:
        done.set()
        first_cycle.set()
        for t in threads:
            t.join(timeout=30.0)
        sys.setswitchinterval(switch)
        logger.removeHandler(deaths)
    # the run ends as an operator ends one, with nobody pressing E-STOP: a last reset if the
    # loop is halted (it must take effect), else Stop for a task the script started just
    # before the end (it must end it)
    final = ctrl.reset_fault() if ctrl.machine.halted else ctrl.stop()
    for _ in range(50):
        ctrl.step()
        if tick is not None:
            tick()
        if final.finished:
            break
    result = final.final(timeout=5.0)
    _count(report, final, result.outcome, result.reason)
    report.final_mode = ctrl.machine.mode.value
    report.injected_faults = sum(1 for t in deaths.texts if expected_faults(t))
    report.deaths = len(deaths.texts) - report.injected_faults
    report.violations = log.violations()
    return report


def _count(report: HarnessReport, ticket: Ticket, outcome: Outcome, reason: str) -> None:
    name = ticket.command.name
    if name == "reset":
        if outcome is Outcome.DONE or outcome is Outcome.ACCEPTED:
            report.resets_done += 1
        elif "an e-stop came after" in reason:
            report.resets_refused_after_estop += 1
        elif outcome is Outcome.FAILED:
            report.resets_other.append(reason)  # the robot could not be reset (injected)
        elif "nothing to reset" not in reason:
            report.resets_other.append(reason)
    elif name in ("go_to_view", "spin"):  # final outcomes: done, failed (e-stop), refused
        report.gotos_started += outcome is not Outcome.REFUSED
        report.gotos_done += outcome is Outcome.DONE


def still_since(values: list[np.ndarray]) -> bool:
    """No joint changed over these readings."""
    return bool(np.all(np.ptp(np.asarray(values), axis=0) == 0.0))


__all__ = [
    "EventLog",
    "HarnessReport",
    "LoggedRobot",
    "drive_away_and_save",
    "make_controller",
    "run_random",
    "still_since",
]

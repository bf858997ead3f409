"""The on-screen jog's dead-man: repeats while holds keep coming, stops on release, pauses
(a zero jog at once) when they stop and moves again only when they resume; two buttons
held at once trip it until a release; a repeat and a release that meet never leave a jog
running (a fake clock, a lock that says when a thread waits on it: no sleeps)."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from icenav.console import ConsoleConfig
from icenav.console.jog import JogRepeater
from icenav.errors import ConfigurationError

AP_PLUS, RL_MINUS = (0, 1), (1, -1)


class Recorder:
    """What the repeater sent, in order: "jog <button>" and "zero"."""

    def __init__(self) -> None:
        self.sent: list[str] = []
        self.trips: list[str] = []

    def send(self, button: tuple[int, int]) -> tuple[Callable[[], None], Callable[[], None]]:
        return (lambda: self.sent.append(f"jog {button}"), lambda: self.sent.append("zero"))


def test_repeats_while_held_and_a_lost_release_stops_at_the_deadman() -> None:
    now = [0.0]
    rec = Recorder()
    rep = JogRepeater(
        20.0, deadman_s=0.5, clock=lambda: now[0], on_trip=lambda k, why, _: rec.trips.append(why)
    )
    assert rep.hold("browser-1", AP_PLUS, *rec.send(AP_PLUS))
    assert rec.sent == ["jog (0, 1)"]  # the press sends at once
    for t in (0.1, 0.3, 0.5):  # no hold for up to 0.5 s: still repeated
        now[0] = t
        assert rep.tick() == 1
    now[0] = 0.45
    assert rep.hold("browser-1", AP_PLUS, *rec.send(AP_PLUS))  # renews, sends nothing itself
    now[0] = 0.9
    assert rep.tick() == 1 and len(rec.sent) == 5
    now[0] = 0.96  # 0.51 s after the last hold: the release was lost; the dead-man stops it
    assert rep.tick() == 0 and rec.sent[-1] == "zero" and rep.held() == set()
    assert rec.trips == ["no hold for 0.51 s"]
    assert rep.events[-1].detail == "no hold for 0.51 s; 2 holds, longest gap 0.45 s"
    for t in (1.0, 5.0, 60.0):  # and nothing moves it again while no hold comes
        now[0] = t
        assert rep.tick() == 0
    assert rec.sent.count("zero") == 1 and len(rec.sent) == 6
    # the page's holds resume (it was starved, the button is still held): it moves again
    assert rep.hold("browser-1", AP_PLUS, *rec.send(AP_PLUS)) and rec.sent[-1] == "jog (0, 1)"
    assert [e.what for e in rep.events] == ["press", "pause", "resume"]
    assert rep.release("browser-1") and rec.sent[-1] == "zero"
    assert rep.tick() == 0 and not rep.release("browser-1")


def test_a_late_hold_that_finds_its_deadman_passed_stops_the_jog_before_resuming() -> None:
    now = [0.0]
    rec = Recorder()
    rep = JogRepeater(20.0, deadman_s=0.5, clock=lambda: now[0])
    rep.hold("b", AP_PLUS, *rec.send(AP_PLUS))
    now[0] = 0.8  # the repeater thread starved: the gap is seen at the hold
    assert rep.hold("b", AP_PLUS, *rec.send(AP_PLUS))
    assert rec.sent == ["jog (0, 1)", "zero", "jog (0, 1)"]
    assert [e.what for e in rep.events] == ["press", "pause", "resume"]


def test_two_buttons_held_by_one_browser_stop_the_jog() -> None:
    now = [0.0]
    rec = Recorder()
    rep = JogRepeater(20.0, deadman_s=0.5, clock=lambda: now[0])
    rep.hold("b", AP_PLUS, *rec.send(AP_PLUS))
    now[0] = 0.05
    assert not rep.hold("b", RL_MINUS, *rec.send(RL_MINUS))  # a second finger / a shift
    assert rec.sent == ["jog (0, 1)", "zero"] and rep.tick() == 0
    assert not rep.hold("b", AP_PLUS, *rec.send(AP_PLUS))  # latched until released
    assert "two jog buttons" in rep.events[-2].detail and rep.tripped() == {"b"}
    assert not rep.release("b") and rep.hold("b", AP_PLUS, *rec.send(AP_PLUS))
    # another browser's jog is its own
    assert rep.hold("c", RL_MINUS, *rec.send(RL_MINUS)) and rep.held() == {"b", "c"}


class WaitSignallingLock:
    """A re-entrant lock that sets ``waiting`` when a thread has to wait for it."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self.waiting = threading.Event()

    def __enter__(self) -> WaitSignallingLock:
        if not self._lock.acquire(blocking=False):
            self.waiting.set()
            self._lock.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self._lock.release()


def test_a_release_that_meets_a_repeat_in_flight_ends_with_the_zero_jog() -> None:
    """The repeat thread is inside its send when the release comes: the release waits
    for it, then sends the zero jog; nothing is sent after (before the fix, the repeat's
    send ran outside the lock and could follow the zero jog: a jog restarted for one
    controller watchdog period after the operator let go)."""
    sent: list[str] = []
    in_send, go_on = threading.Event(), threading.Event()

    def repeat_send() -> None:
        if sent:  # the press itself sent the first; the tick's send is held up here
            in_send.set()
            assert go_on.wait(10.0)
        sent.append("jog")

    rep = JogRepeater(20.0, deadman_s=0.5, clock=lambda: 0.0)
    lock = WaitSignallingLock()
    rep._lock = lock  # type: ignore[assignment]
    rep.hold("b", AP_PLUS, repeat_send, lambda: sent.append("zero"))
    ticker = threading.Thread(target=rep.tick)
    ticker.start()
    assert in_send.wait(10.0)
    releaser = threading.Thread(target=rep.release, args=("b",))
    releaser.start()
    assert lock.waiting.wait(10.0)  # the release waits for the repeat in flight
    go_on.set()
    ticker.join(10.0)
    releaser.join(10.0)
    assert sent == ["jog", "jog", "zero"]
    assert rep.tick() == 0 and sent[-1] == "zero"


def test_deadman_time_is_validated() -> None:
    assert ConsoleConfig().jog_deadman_s == 0.5
    for bad in (0.05, 1.5, float("nan"), True, "0.5"):
        with pytest.raises(ConfigurationError, match=r"jog_deadman_s must be in \[0.1, 1.0\] s"):
            ConsoleConfig(jog_deadman_s=bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigurationError, match="two hold periods"):
        JogRepeater(10.0, deadman_s=0.2)  # holds every 0.1 s: two periods = the dead-man
    with pytest.raises(ConfigurationError, match="repeat rate"):
        JogRepeater(0.0)

"""The on-screen jog repeater: repeats while holds keep coming within the grace, stops on
release or after the grace (a fake clock: no sleeps)."""

from __future__ import annotations

import pytest

from icenav.console.jog import JogRepeater
from icenav.errors import ConfigurationError


def test_repeats_within_the_grace_and_stops_on_release_or_after_it() -> None:
    now = [0.0]
    sent: list[str] = []
    rep = JogRepeater(20.0, grace_s=0.5, clock=lambda: now[0])
    rep.hold("browser-1", lambda: sent.append("a"))
    assert sent == ["a"]  # the hold itself sends at once
    for t in (0.1, 0.3, 0.5):  # browser gaps of 0.5 s: still repeated
        now[0] = t
        assert rep.tick() == 1
    now[0] = 0.45
    rep.hold("browser-1", lambda: sent.append("b"))  # a late hold renews the grace
    now[0] = 0.9
    assert rep.tick() == 1 and sent[-1] == "b"
    now[0] = 0.96  # 0.51 s after the last hold: dropped
    assert rep.tick() == 0 and rep.held() == set()
    rep.hold("browser-2", lambda: sent.append("c"))
    assert rep.release("browser-2") and not rep.release("browser-2")
    assert rep.tick() == 0
    with pytest.raises(ConfigurationError, match="grace"):
        JogRepeater(20.0, grace_s=0.0)

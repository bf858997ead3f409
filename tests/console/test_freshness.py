"""The stale-state indicator's parts: the threshold's validation, the age on an injected
clock, the banner's words, the publish-period check (no server, no sleeps)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from icenav.console import ConsoleConfig
from icenav.console.freshness import StateFreshness, check_publish_period, stale_banner_html
from icenav.control.config import ControllerConfig
from icenav.errors import ConfigurationError
from tests.support.clock import Clock
from tests.support.console import make_state


def test_the_default_threshold_is_half_a_second() -> None:
    assert ConsoleConfig().stale_after_s == 0.5
    assert ConsoleConfig(0.1).stale_after_s == 0.1 and ConsoleConfig(10).stale_after_s == 10


@pytest.mark.parametrize("value", [0.0, 0.09, -1.0, 10.5, math.nan, math.inf, "0.5", None, True])
def test_a_threshold_outside_its_range_is_refused_naming_value_unit_and_range(
    value: object,
) -> None:
    with pytest.raises(ConfigurationError, match=r"stale_after_s must be in \[0.1, 10.0\] s, got"):
        ConsoleConfig(value)  # type: ignore[arg-type]


def test_the_age_counts_from_the_newest_state_seen() -> None:
    clock = Clock()
    fresh = StateFreshness(0.5, clock)
    assert fresh.age_s() is None and fresh.stale_age_s() is None  # nothing seen: waiting
    a, b = make_state(cycle=1), make_state(cycle=2)
    clock.t = 10.0
    fresh.saw(a)
    fresh.saw(None)  # an empty mailbox is no state
    clock.t = 10.5
    assert fresh.age_s() == pytest.approx(0.5) and fresh.stale_age_s() is None  # not beyond
    fresh.saw(a)  # the same state again (the snapshot of the last draw) is not new
    clock.t = 10.7
    assert fresh.stale_age_s() == pytest.approx(0.7)
    fresh.saw(b)
    assert fresh.age_s() == 0.0 and fresh.stale_age_s() is None


def test_the_banner_gives_the_age_and_escapes_nothing_it_should_not() -> None:
    text = stale_banner_html(1.26)
    assert "No state from the controller for 1.3 s: the robot&#x27;s state is unknown" in text
    assert 'class="icenav-banner icenav-stale"' in text and "E-STOP" in text


def test_a_threshold_the_controllers_publishing_would_cross_is_refused() -> None:
    check_publish_period(SimpleNamespace(config=ControllerConfig()), 0.5)  # 0.01 s: fine
    check_publish_period(object(), 0.1)  # no config (a double, a proxy): not checked
    slow = SimpleNamespace(config=ControllerConfig(rate_hz=100.0, publish_every=50))
    with pytest.raises(ConfigurationError, match=r"publish period \(50 cycles at 100.0 Hz"):
        check_publish_period(slow, 0.5)
    check_publish_period(slow, 0.6)

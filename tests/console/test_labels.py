"""Human words on the console: no internal names, times in readable units, the banner."""

from __future__ import annotations

import numpy as np

from icenav.console.labels import (
    MODE_LABELS,
    ago_text,
    client_label,
    duration_text,
    halt_banner,
    humanize,
    safety_markdown,
)
from icenav.control.state import Mode
from tests.support.console import make_state


def test_clients_and_messages_in_words() -> None:
    assert client_label("browser-8") == "browser #8"
    assert client_label("browser-8", me="browser-8") == "you (browser #8)"
    assert client_label("gamepad") == "the gamepad"
    assert client_label("igtl-127.0.0.1:5000") == "3D Slicer at 127.0.0.1:5000"
    assert client_label(None) == "nobody"
    text = humanize("five_point calibration by browser-12; dense+hysteresis next")
    assert text == "5-point calibration by browser #12; dense + hysteresis next"
    assert set(MODE_LABELS) == set(Mode)
    assert not any("_" in label for label in MODE_LABELS.values())


def test_durations_and_ages_in_readable_units() -> None:
    assert duration_text(0.42) == "0.4 s"
    assert duration_text(42.0) == "42 s"
    assert duration_text(185.0) == "3 min 05 s"
    assert duration_text(3725.0) == "1 h 02 min"
    assert ago_text(1000.0, 1030.0) == "just now"
    assert ago_text(1000.0, 1000.0 + 5 * 60 + 3) == "5 min ago"
    assert ago_text(1000.0, 1000.0 + 7300) == "2 h ago"


def test_safety_line_and_banner() -> None:
    line = safety_markdown(make_state(control_owner="gamepad"), "connected")
    assert "Holding still" in line and "the gamepad" in line and "dead-man **held**" in line
    assert "not connected" in safety_markdown(make_state(), "disconnected")
    assert "none configured" in safety_markdown(make_state())
    assert halt_banner(make_state(mode=Mode.KNOB)) is None
    banner = halt_banner(make_state(mode=Mode.ESTOP, message="EMERGENCY STOP by browser-1"))
    assert banner is not None
    assert banner.cause == "EMERGENCY STOP by browser #1" and "Reset fault" in banner.action
    fault = halt_banner(make_state(mode=Mode.FAULT, q=np.zeros(4), message=""))
    assert fault is not None and fault.cause == "not reported" and "FAULT" in fault.title


def test_client_text_cannot_inject_html_into_the_page() -> None:
    """viser renders raw HTML in markdown: a view name typed by any client with control
    (a browser, 3D Slicer) reaches every browser's page escaped."""
    from icenav.console.panels import status_markdown, summary_markdown

    evil = "<img src=x onerror=alert(1)>"
    state = make_state(message=f"view '{evil}' saved", control_owner=f"igtl-{evil}")
    for text in (
        summary_markdown(state),
        status_markdown(state),
        safety_markdown(state),
        halt_banner(make_state(mode=Mode.ESTOP, message=evil)).html(),  # type: ignore[union-attr]
    ):
        assert "<img" not in text and "&lt;img" in text, text

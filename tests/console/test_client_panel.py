"""One browser's controls (no browser): disabled while halted or not holding control, the
view list with thumbnails, empty and duplicate names refused with a message."""

from __future__ import annotations

import numpy as np

from icenav.console import Console
from icenav.control.state import ImageFrame, Mode, ViewSummary
from tests.support.console import FakeClient, RecordingController, make_state


def _console() -> tuple[Console, RecordingController, object]:
    ctl = RecordingController()
    console = Console(ctl, port=0)
    console._on_connect(FakeClient(1))
    return console, ctl, console._panels[1]


def test_every_motion_control_is_disabled_in_estop_and_fault() -> None:
    console, ctl, panel = _console()
    views = (ViewSummary("home", np.zeros(4), 0.0, True),)
    ctl.view_images["home"] = ImageFrame(np.full((40, 30), 90, np.uint8), 0.0)
    panel.update(make_state(views=views, control_owner=panel.name), console._jog_rates)
    panel.draw_view_list(views, ctl.view_image, console._goto_button(panel))
    controls = panel.all_motion_controls()
    assert len(controls) > 10 and not any(h.disabled for h in controls)
    (thumb, go) = panel.view_rows["home"]
    assert str(thumb.label).startswith("home: saved") and go.label == "Go to home"
    for mode in (Mode.ESTOP, Mode.FAULT):
        halted = make_state(mode=mode, views=views, control_owner=panel.name)
        panel.update(halted, console._jog_rates)
        assert all(h.disabled for h in panel.all_motion_controls()), mode
        panel.update(make_state(views=views, control_owner=panel.name), console._jog_rates)
        assert not any(h.disabled for h in panel.all_motion_controls())
    panel.update(make_state(views=views, control_owner="gamepad"), console._jog_rates)
    assert all(h.disabled for h in panel.all_motion_controls())  # not the holder


def test_empty_and_duplicate_view_names_are_refused_with_a_message() -> None:
    console, ctl, panel = _console()
    panel.update(make_state(views=(ViewSummary("home", np.zeros(4), 0.0),)), console._jog_rates)
    for name, why in (("   ", "type a name"), ("home", "a view named **home** exists")):
        panel.view_name.value = name
        panel.save.click()
        assert why in panel.feedback_text
    assert not [c for c in ctl.calls if c[0] == "save_view"]
    panel.view_name.value = "apex"
    panel.save.click()
    assert ctl.wait_for_call("save_view")[0] == ("apex",)
    assert panel.feedback_text == ""  # accepted: the refusal is gone


def test_a_click_on_a_view_marker_selects_it_in_that_browser_only() -> None:
    console, ctl, panel = _console()
    console._on_connect(FakeClient(2))
    other = console._panels[2]
    views = (ViewSummary("home", np.zeros(4), 0.0), ViewSummary("septum", np.zeros(4), 0.0))
    for p in (panel, other):
        p.update(make_state(views=views), console._jog_rates)
    assert panel.views.value == other.views.value == "septum"  # the newest is selected
    console._view_marker_clicked("home", 1)
    assert panel.views.value == "home" and other.views.value == "septum"
    console._view_marker_clicked("gone", 1)  # not (or no longer) a saved view: ignored
    assert panel.views.value == "home"


def test_refine_view_sends_the_selected_view_to_the_controller() -> None:
    """The product's refinement (Controller.refine_view) from the console: the selected
    view; nothing without one."""
    console, ctl, panel = _console()
    panel.refine.click()  # no saved view selected: nothing sent
    views = (ViewSummary("home", np.zeros(4), 0.0), ViewSummary("septum", np.zeros(4), 0.0))
    panel.update(make_state(views=views, control_owner=panel.name), console._jog_rates)
    panel.views.value = "septum"
    panel.refine.click()
    assert ctl.wait_for_call("refine_view")[0] == ("septum",)
    assert [c[1] for c in ctl.calls if c[0] == "refine_view"] == [("septum",)]
    assert panel.refine in panel.all_motion_controls()  # disabled in ESTOP / FAULT

"""What the console is told of the returns' checks (``force_check_text``)."""

from __future__ import annotations

import numpy as np

from icenav.control.publish import force_check_text, pending_question
from icenav.recovery.drift import REST_WINDOW_S
from icenav.recovery.force import ForceRecord


def _rest(forces: ForceRecord, scatter_mm: float, seed: int = 0) -> None:
    """The operator's stop and the still tip's readings, scattered where no phase explains
    it (mm), with an ECG phase."""
    rng = np.random.default_rng(seed)
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 40.0]
    forces.note_motion(pose, True, np.zeros(4), 0.0)
    for t in np.arange(0.02, REST_WINDOW_S, 0.02):
        pose = pose.copy()
        pose[:3, 3] = [0.0, 0.0, 40.0] + rng.normal(0.0, scatter_mm, 3)
        forces.note_still(float(t), pose, lambda t: (None, float(t % 0.8) / 0.8))


def test_the_status_says_where_the_tip_drift_check_cannot_tell() -> None:
    forces = ForceRecord()
    assert force_check_text(False, forces, True).endswith(
        "tip-drift check on (tracker, armed at your next drive: the last motion was not yours)"
    )
    assert force_check_text(False, forces, False) == "off: no force channel"
    _rest(forces, 0.2)  # a quiet tip: the check can tell
    assert force_check_text(True, forces, True) == (
        "on (no force recorded yet); tip-drift check on (tracker)"
    )
    _rest(forces, 4.0)  # a tip that strays by itself as far as a shift would move it
    text = force_check_text(True, forces, True)
    assert "cannot tell here: the still tip strays" in text and "asks you to confirm" in text
    assert "cannot tell" not in force_check_text(True, forces, True, drift_limit_mm=50.0)


def test_an_open_question_is_shown_with_the_seconds_left_until_it_expires() -> None:
    """Eq. (F6)'s question: shown from the press that asked it while the loop is idle, with
    the time left; gone once it expires, while a task runs, and once a return took it."""
    from icenav.recovery.drift import CONFIRM_S

    forces = ForceRecord()
    assert pending_question(forces, lambda: 0.0, True) == ""  # no rest: nothing to ask
    _rest(forces, 4.0)
    rest = forces.rest
    assert rest is not None
    assert pending_question(forces, lambda: 10.0, True) == ""  # nothing asked yet
    rest.ask(10.0)
    text = pending_question(forces, lambda: 14.2, True)
    assert f"({CONFIRM_S - 4.2:.0f} s left)" in text and "press the return again" in text
    assert pending_question(forces, lambda: 14.2, False) == ""  # a task runs
    assert pending_question(forces, lambda: 10.0 + CONFIRM_S + 0.1, True) == ""  # expired
    assert rest.confirmed(20.0)
    rest.answered()  # a return took the confirmation: the next one asks again
    assert not rest.confirmed(20.0) and pending_question(forces, lambda: 20.0, True) == ""

"""Tests of the console's panel logic (no browser, no server)."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from icenav.console.panels import (
    JOG_AXES,
    MODE_CHOICES,
    JointHistory,
    LatestSlot,
    client_name,
    control_view,
    display_factors,
    display_pixel_map,
    gray_to_rgb,
    jog_command,
    joint_table_markdown,
    mode_from_choice,
    mode_options,
    progress_percent,
    status_markdown,
    summary_markdown,
    views_markdown,
)
from icenav.control.state import ControllerState, Mode, ViewSummary
from icenav.control.teleop import JoystickMapping
from icenav.devices.robot import RobotStatus
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import forward


def _state(**kw: object) -> ControllerState:
    q = np.array([math.radians(30), math.radians(-15), math.radians(90), 12.5])
    base: dict[str, object] = dict(
        time=3.25,
        cycle=325,
        mode=Mode.KNOB,
        robot_status=RobotStatus.ENABLED,
        q_motor=q,
        q_model=q * 0.9,
        tip2base_model=forward(q),
    )
    base.update(kw)
    return ControllerState(**base)  # type: ignore[arg-type]


def test_jog_command_knob_mode_uses_the_gamepad_full_stick_rates() -> None:
    m = JoystickMapping(knob_rate=0.5, roll_rate=0.7, translation_rate=3.0, tip_speed=8.0)
    expected = (0.5, 0.5, 0.7, 3.0)
    for axis in range(4):
        for sign in (-1, 1):
            vel, frame = jog_command(Mode.KNOB, axis, sign, m)
            assert frame == "knob" and vel.shape == (4,)
            want = np.zeros(4)
            want[axis] = sign * expected[axis]
            np.testing.assert_array_equal(vel, want)


def test_jog_command_tip_mode_moves_tip_axes_and_rolls_about_z() -> None:
    m = JoystickMapping(roll_rate=0.7, tip_speed=8.0)
    for axis in range(3):
        twist, frame = jog_command(Mode.TIP, axis, -1, m)
        assert frame == "tip" and twist.shape == (6,)
        assert twist[axis] == -8.0 and np.count_nonzero(twist) == 1
    twist, _ = jog_command(Mode.TIP, 3, 1, m)
    np.testing.assert_array_equal(twist, [0, 0, 0, 0, 0, 0.7])
    assert len(JOG_AXES[Mode.TIP]) == len(JOG_AXES[Mode.KNOB]) == 4


def test_jog_command_rejects_bad_input() -> None:
    with pytest.raises(ConfigurationError, match="axis must be 0, 1, 2 or 3, got 4"):
        jog_command(Mode.KNOB, 4, 1)
    with pytest.raises(ConfigurationError, match="sign must be"):
        jog_command(Mode.KNOB, 0, 0)
    with pytest.raises(ConfigurationError, match="KNOB or TIP, not GOTO_VIEW"):
        jog_command(Mode.GOTO_VIEW, 0, 1)


def test_mode_choices_round_trip() -> None:
    for label, mode in MODE_CHOICES.items():
        assert mode_from_choice(label) is mode
    assert set(MODE_CHOICES.values()) == {Mode.IDLE, Mode.KNOB, Mode.TIP}
    with pytest.raises(ConfigurationError, match="'Spin'"):
        mode_from_choice("Spin")


def test_control_view_for_each_owner() -> None:
    me = client_name(3)
    assert me == "browser-3"
    mine = control_view(me, me)
    assert mine.can_control and not mine.can_take and "You have control" in mine.text
    free = control_view(None, me)
    assert not free.can_control and free.can_take and "View only" in free.text
    pad = control_view("gamepad", me)
    assert not pad.can_control and not pad.can_take and "gamepad" in pad.text
    other = control_view("browser-1", me)
    assert not other.can_control and not other.can_take and "browser #1" in other.text
    assert "browser-" not in mine.text + other.text  # no internal names on the page


def test_joint_table_shows_degrees_and_mm() -> None:
    q = np.array([math.radians(30), math.radians(-15), math.radians(90), 12.5])
    md = joint_table_markdown(q, q * 2)
    assert "| phi1 (deg) | 30.0 | 60.0 |" in md
    assert "| phi2 (deg) | -15.0 | -30.0 |" in md
    assert "| phi3 (deg) | 90.0 | 180.0 |" in md
    assert "| d4 (mm) | 12.5 | 25.0 |" in md
    with pytest.raises(ShapeError, match=r"q_motor must have shape \(4,\)"):
        joint_table_markdown(np.zeros(3), q)


def test_status_markdown_shows_mode_fault_tracker_roadmap_owner() -> None:
    md = status_markdown(
        _state(
            tracker_status="MISSING",
            n_vertices=1234,
            n_edges=2000,
            control_owner="gamepad",
            compensation_enabled=True,
        )
    )
    for text in (
        "Jogging the knobs",
        "enabled",
        "sensor not seen",
        "1234 vertices",
        "2000 edges",
        "the gamepad",
        "on",
    ):
        assert text in md
    fault = status_markdown(
        _state(mode=Mode.ESTOP, robot_status=RobotStatus.ESTOP, message="e-stop by browser-2")
    )
    assert "**EMERGENCY STOP:** e-stop by browser #2" in fault
    assert "nobody" in fault
    long_run = status_markdown(_state(time=3725.0))
    assert "Running for** 1 h 02 min" in long_run


def test_summary_line_names_mode_and_message() -> None:
    assert summary_markdown(_state()) == "**Jogging the knobs**"
    saved = summary_markdown(_state(message="view 'a' saved"))
    assert saved == "**Jogging the knobs**: view 'a' saved"
    # a stale message dropped by the console (message=""): the mode alone
    assert summary_markdown(_state(message="jog refused"), "") == "**Jogging the knobs**"
    fault = summary_markdown(_state(mode=Mode.FAULT, message="drive 2 fault 0x2310"), "")
    assert "**FAULT: robot stopped**: drive 2 fault 0x2310" in fault  # the cause stays
    # an open question stays in front of a stale or newer message while it can be answered
    asked = _state(message="view 'a' saved", question="press the return again")
    assert summary_markdown(asked, "") == (
        "**Jogging the knobs**: **Waiting for you:** press the return again"
    )


def test_mode_dropdown_names_the_running_automatic_mode() -> None:
    options, value = mode_options(Mode.IDLE)
    assert options == tuple(MODE_CHOICES) and MODE_CHOICES[value] is Mode.IDLE
    options, value = mode_options(Mode.SPINNING)
    assert value == "Spinning the image 360°" and options[-1] == value
    assert mode_options(Mode.ESTOP)[1] == "EMERGENCY STOP"


def test_views_markdown_lists_views() -> None:
    assert "No saved views" in views_markdown(())
    v = ViewSummary("apex", np.array([math.radians(10), 0, math.radians(-20), 3.0]), 0.0)
    md = views_markdown((v,))
    assert "**apex**" in md and "10 / 0 / -20 deg, 3.0 mm" in md


def test_progress_percent() -> None:
    assert progress_percent(None) is None
    assert progress_percent(float("nan")) is None
    assert progress_percent(0.25) == 25.0
    assert progress_percent(1.5) == 100.0
    assert progress_percent(-0.1) == 0.0


def test_gray_to_rgb_replicates_channels_and_decimates() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (300, 1000), dtype=np.uint8)
    rgb = gray_to_rgb(img, max_width=400)
    assert rgb.dtype == np.uint8 and rgb.shape == (100, 334, 3)  # factor ceil(1000/400) = 3
    np.testing.assert_array_equal(rgb[..., 0], img[::3, ::3])
    np.testing.assert_array_equal(rgb[..., 1], rgb[..., 2])
    small = gray_to_rgb(img[:10, :20])
    assert small.shape == (10, 20, 3)
    big = gray_to_rgb(img[:10, :20], max_width=640, min_width=300)
    assert big.shape == (150, 300, 3)  # x15, nearest pixel
    np.testing.assert_array_equal(big[::15, ::15, 0], img[:10, :20])
    capped = gray_to_rgb(img[:10, :200], max_width=500, min_width=900)
    assert capped.shape == (20, 400, 3)  # x2: x4 or x5 would pass max_width
    assert gray_to_rgb(img[:10, :256], min_width=300).shape == (10, 256, 3)  # x1 is nearest
    assert gray_to_rgb(img[:10, :160], min_width=300).shape == (20, 320, 3)  # x2 is nearest
    with pytest.raises(ShapeError, match=r"\(H, W\)"):
        gray_to_rgb(np.zeros((2, 2, 2), np.uint8))
    with pytest.raises(ConfigurationError, match="max_width"):
        gray_to_rgb(img, max_width=0)


@pytest.mark.parametrize(
    ("width", "max_w", "min_w"),
    [(1000, 400, 0), (20, 640, 300), (160, 640, 300), (256, 640, 300), (7, 640, 0)],
)
def test_display_pixel_map_points_at_the_pixel_shown(width: int, max_w: int, min_w: int) -> None:
    # an image whose value is its column index (< 256 columns shown exactly via % 256)
    img = np.tile(np.arange(width, dtype=np.int64) % 256, (4, 1)).astype(np.uint8)
    shown = gray_to_rgb(img, max_w, min_w)[0, :, 0]
    down, up = display_factors(width, max_w, min_w)
    m = display_pixel_map(down, up)
    for i_shown in range(shown.size):
        i_orig = (m @ np.array([i_shown, 0, 0, 1.0]))[0]
        # the displayed pixel's centre lies inside the original pixel it shows
        assert int(np.floor(i_orig + 0.5)) % 256 == shown[i_shown]
        assert abs(i_orig - round(i_orig)) <= 0.5


def test_joint_history_keeps_the_window_and_converts_units() -> None:
    h = JointHistory(window_s=10.0)
    assert all(len(a) == 0 for a in h.uplot_data())
    for k in range(2001):  # 20 s at 100 Hz
        t = 0.01 * k
        h.append(t, [math.radians(t), 0.0, -math.radians(2 * t), t / 2])
    t_rel, p1, p2, p3, d4 = h.uplot_data()
    assert t_rel[-1] == 0.0 and t_rel[0] >= -10.0 - 1e-9 and t_rel[0] < -9.9
    assert len(h) == len(t_rel) == len(p1) == len(d4)
    t_abs = t_rel + 20.0
    np.testing.assert_allclose(p1, t_abs, atol=1e-9)
    np.testing.assert_allclose(p3, -2 * t_abs, atol=1e-9)
    np.testing.assert_allclose(d4, t_abs / 2, atol=1e-9)
    assert not p2.any()
    h.append(0.0, np.zeros(4))  # time went back: new session
    assert len(h) == 1
    with pytest.raises(ConfigurationError, match="window_s"):
        JointHistory(0.0)


def test_latest_slot_coalesces_and_never_loses_the_newest() -> None:
    slot = LatestSlot()
    assert slot.take() is None
    states = [_state(cycle=i) for i in range(5)]
    for s in states:
        slot.offer(s)
    assert slot.take() is states[-1]
    assert slot.take() is None
    assert slot.offered == 5 and slot.taken == 1

    # a producer thread and a consumer: the consumer sees increasing cycles and the last one
    n = 2000
    seen: list[int] = []
    done = threading.Event()
    many = [_state(cycle=i) for i in range(n)]

    def produce() -> None:
        for s in many:
            slot.offer(s)
        done.set()

    th = threading.Thread(target=produce)
    th.start()
    while not done.is_set() or seen[-1:] != [n - 1]:
        got = slot.take()
        if got is not None:
            seen.append(got.cycle)
    th.join()
    assert seen == sorted(seen) and seen[-1] == n - 1
    assert slot.offered == 5 + n

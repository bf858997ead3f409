"""The displayed ICE picture: depth scale where the rows say, marker side, gain, ECG shape."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.console.display import (
    SCALE_MARGIN_PX,
    DisplaySettings,
    check_display_settings,
    ecg_mv,
    image_geometry,
    imaged_depth_cm,
    render_display,
)
from icenav.errors import ConfigurationError

PX = 0.5  # mm per pixel
# row j -> depth x = (j + 0.5) px along tip x; column i -> tip z = (i + 0.5 - 32) px
IJK2TIP = np.array([[0, PX, 0, 0.5 * PX], [0, 0, 1, 0], [PX, 0, 0, (0.5 - 32) * PX], [0, 0, 0, 1]])


def _image() -> np.ndarray:
    img = np.zeros((200, 64), np.uint8)
    img[:160] = 100  # echoes down to 80 mm, nothing below
    return img


def test_geometry_depth_per_row_and_marker_side() -> None:
    geo = image_geometry(IJK2TIP, (200, 64))
    assert geo is not None and geo.distal_right  # columns run towards +z (distal)
    np.testing.assert_allclose(geo.row_depth_mm[[0, 19]], [0.25 * np.hypot(1, 1), 9.75], atol=0.3)
    flipped = IJK2TIP.copy()
    flipped[2, 0] = -PX
    assert not image_geometry(flipped, (200, 64)).distal_right  # type: ignore[union-attr]
    assert image_geometry(np.eye(4), (200, 64)) is None
    assert imaged_depth_cm(_image(), IJK2TIP) == pytest.approx(7.975, abs=0.01)


def test_picture_cuts_blank_rows_draws_scale_and_applies_gain() -> None:
    out = render_display(_image(), IJK2TIP, 256)
    assert out.shape == (160 * 4, 256 + SCALE_MARGIN_PX, 3)  # blank rows below 8 cm cut
    # a tick at each cm: the margin's column 4 is lit at row (20 * cm - 0.5) * 4 for cm = 1..7
    lit = np.flatnonzero(out[:, 256 + 4].max(axis=1) > 200)
    for cm in range(1, 8):
        assert np.min(np.abs(lit - (20 * cm - 0.5) * 4)) <= 2, cm
    brighter = render_display(_image(), IJK2TIP, 256, DisplaySettings(gain_db=11.0))
    assert brighter[300, 100, 0] == 151  # +11 dB = +51 grey levels over 55 dB
    shallow = render_display(_image(), IJK2TIP, 256, DisplaySettings(depth_cm=4.0))
    assert shallow.shape[0] == 80 * 4
    with_ecg = render_display(_image(), IJK2TIP, 256, ecg=(np.linspace(-3, 0, 50), np.zeros(50)))
    assert with_ecg.shape[0] > out.shape[0]
    with pytest.raises(ConfigurationError, match="gain must be in"):
        check_display_settings(DisplaySettings(gain_db=40.0))


def test_heart_rate_from_the_phase_across_the_r_wave() -> None:
    from icenav.console.display import heart_rate_bpm

    def phase(t: float) -> float:
        return (t / 0.8) % 1.0  # 75 beats/min

    for t in (0.3, 0.81, 1.6):  # 0.81 s: just after an R wave (the phase wrapped)
        assert heart_rate_bpm(phase, t) == pytest.approx(75.0)


def test_ecg_has_its_r_wave_at_phase_zero() -> None:
    phase = np.linspace(0, 1, 1001)
    mv = ecg_mv(phase)
    assert mv.max() == pytest.approx(1.2, abs=0.03)  # the R wave, less the Q and S overlap
    assert phase[np.argmax(mv)] < 0.01 or phase[np.argmax(mv)] > 0.99
    t_wave = mv[(phase > 0.2) & (phase < 0.3)].max()  # T wave at theta = pi/2
    assert 0.2 < t_wave < 0.8 and mv[(phase > 0.03) & (phase < 0.06)].min() < 0  # S wave

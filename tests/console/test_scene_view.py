"""The scene's ICE fan (transparent outside the sector) and anatomy labels."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.console.scene_view import FAN_OPACITY, as_scene_labels, fan_rgba
from icenav.errors import ConfigurationError


def test_fan_is_transparent_outside_the_sector_even_over_dark_blood() -> None:
    img = np.zeros((4, 7), np.uint8)
    img[1, 2:5] = [50, 0, 60]  # anechoic blood (0) inside the sector stays opaque
    img[3, 0] = 9
    img[3, 6] = 9
    rgba = fan_rgba(img)
    alpha = rgba[..., 3]
    assert rgba.shape == (4, 7, 4)
    assert (alpha[0] == 0).all() and (alpha[2] == 0).all()
    np.testing.assert_array_equal(alpha[1], [0, 0, *[round(255 * FAN_OPACITY)] * 3, 0, 0])
    assert (alpha[3] > 0).all()


def test_labels_from_landmarks_or_tuples() -> None:
    from types import SimpleNamespace

    lm = SimpleNamespace(key="ra", label="RA", name="right atrium", point=(1.0, 2.0, 3.0))
    a, d = as_scene_labels([lm, ("dir-A", "A", "anterior", (0.0, 1.0, 0.0))])
    assert a.label == "RA" and not a.is_direction and d.is_direction
    with pytest.raises(ConfigurationError, match="3 finite values"):
        as_scene_labels([("x", "X", "x", (1.0, np.nan, 0.0))])

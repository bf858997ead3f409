"""Refinement by measured re-approach, Eq. (R2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.refinement.retry import RetryConfig, retry_return, weighted_error


def _at(x_mm: float, rot_deg: float = 0.0) -> np.ndarray:
    out = np.eye(4)
    out[0, 3] = x_mm
    c, s = math.cos(math.radians(rot_deg)), math.sin(math.radians(rot_deg))
    out[:2, :2] = [[c, -s], [s, c]]
    return out


class _Draws:
    """Each re-approach lands the tip at the next of ``offsets`` (mm along x)."""

    def __init__(self, offsets: list[float]) -> None:
        self.offsets = offsets
        self.k = 0
        self.moves = 0

    def measure(self) -> np.ndarray:
        return _at(self.offsets[self.k])

    def reapproach(self) -> None:
        self.moves += 1
        self.k += 1


def test_weighted_error_adds_the_rotation_in_mm() -> None:
    e, p, r = weighted_error(_at(0.0), _at(0.3, 1.0), 25.0)
    assert r == pytest.approx(1.0)
    assert e == pytest.approx(p + 25.0 * math.radians(1.0))


@pytest.mark.parametrize(
    ("offsets", "moves", "last", "worse"),
    [
        ([0.2], 0, 0.2, False),  # good at once: nothing moves
        ([1.5, 0.4], 1, 0.4, False),  # one re-approach fixes it
        ([1.5, 1.2, 1.1], 2, 1.1, False),  # the budget: two re-approaches, then stop
        ([0.9, 2.0, 1.6, 0.7], 3, 0.7, False),  # ended worse: one more re-approach
        ([0.9, 2.0, 1.6, 1.8], 3, 1.8, True),  # ... which may still be worse: said so
    ],
)
def test_it_re_approaches_while_off_and_never_more_than_its_budget(
    offsets: list[float], moves: int, last: float, worse: bool
) -> None:
    draws = _Draws(offsets)
    res = retry_return(_at(0.0), draws.measure, draws.reapproach)
    assert res.moves == draws.moves == moves
    assert res.position_mm[-1] == pytest.approx(last)
    assert res.ended_worse is worse
    assert len(res.errors_mm) == moves + 1


def test_abort_and_a_missing_pose_stop_it() -> None:
    draws = _Draws([2.0, 2.0, 2.0])
    res = retry_return(_at(0.0), draws.measure, draws.reapproach, abort=lambda: True)
    assert res.aborted and res.moves == 0
    res = retry_return(_at(0.0), lambda: None, draws.reapproach)
    assert res.moves == 0 and res.errors_mm == ()
    with pytest.raises(ConfigurationError):
        RetryConfig(max_retries=-1)

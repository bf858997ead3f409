"""The operator's contact forces per roadmap vertex and the limit of a return, Eq. (F1)."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.recovery.force import ForceMap, force_excess, force_limit
from icenav.recovery.roadmap import Roadmap


def test_the_map_keeps_the_largest_force_per_vertex_and_fills_gaps_along_a_path() -> None:
    rm = Roadmap(epsilon=1.0)
    forces = ForceMap(capacity=2)
    qs = np.zeros((6, 4))
    qs[:, 3] = np.arange(6) * 0.9  # mm: a straight trace, one vertex per state
    for i, q in enumerate(qs):
        v = rm.add(q)
        forces.record(v, None if i == 4 else 0.1 * i)
    forces.record(rm.vertex_of(qs[2]), 0.05)  # a lower reading later: the larger stays
    forces.record(-1, 3.0)  # not recorded: ignored
    assert forces.n_recorded == 5
    np.testing.assert_allclose(forces.at([0, 2, 4, 99]), [0.0, 0.2, np.nan, np.nan])
    profile = forces.profile(rm, qs[::-1], radius=0.5)  # each state's own vertex
    assert profile is not None
    np.testing.assert_allclose(profile, [0.5, 0.5, 0.3, 0.2, 0.1, 0.0])  # state 4 from 5
    near = forces.profile(rm, qs[::-1])  # the largest within epsilon (1 mm here)
    np.testing.assert_allclose(near, [0.5, 0.5, 0.3, 0.3, 0.2, 0.1])
    assert ForceMap().profile(rm, qs) is None  # nothing recorded: no check
    with pytest.raises(ConfigurationError):
        forces.record(0, -0.1)


def test_the_limit_is_the_larger_end_of_the_segment_plus_the_margin() -> None:
    profile = np.array([0.1, 0.4, 0.2])
    assert force_excess(profile, 0, 0.6, 0.25, 0.0) == pytest.approx(-0.05)
    assert force_excess(profile, 1, 0.7, 0.25, 0.0) == pytest.approx(0.05)
    assert force_excess(profile, 2, 0.5, 0.25, 0.0) == pytest.approx(0.05)  # the end: itself
    assert force_limit(profile, 1, 0.05, 0.5) == pytest.approx((0.4, 0.65))

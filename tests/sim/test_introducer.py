"""Shaft stick-slip: lost motion within [F_k / k, F_s / k], reversals, the friction disc,
ageing, a breathing wall and settling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.sim import introducer
from icenav.sim.introducer import ShaftFriction, ShaftParams

P = ShaftParams(
    axial_stiffness_n_per_mm=1.0,
    torsional_stiffness_nmm_per_rad=10.0,
    static_friction_n=0.4,
    kinetic_friction_n=0.2,
)


def _drive(shaft: ShaftFriction, d0: float, d1: float, psi: float = 0.0, t0: float = 0.0,
           n: int = 200) -> float:  # fmt: skip
    for k in range(1, n + 1):
        shaft.drive(d0 + (d1 - d0) * k / n, psi, t0 + k * 0.01)
    return t0 + n * 0.01


def test_translation_lags_by_between_kinetic_and_static_over_k() -> None:
    """Pushing forward: the base lags the drive by F_k/k after a slip, never more than F_s/k;
    pulling back: the lag changes sign (backlash of 2 F_k / k to take up)."""
    shaft = ShaftFriction(P, (0,))
    lags = []
    for k in range(1, 1001):
        shaft.drive(10.0 * k / 1000, 0.0, k * 0.01)
        lags.append(shaft.lost_motion(k * 0.01)[0])
    assert shaft.slips > 10
    assert all(-0.4 - 1e-9 <= x <= 1e-9 for x in lags)
    assert lags[-1] == pytest.approx(-0.2, abs=0.2)
    _drive(shaft, 10.0, 5.0, t0=10.0)
    assert shaft.lost_motion(12.0)[0] > 0.19


def test_the_lost_motion_differs_from_one_return_to_the_next() -> None:
    """Repeating the same move ends at different lost motions: where the drive stops in
    the stick-slip cycle (between F_k / k and F_s / k), and with the static friction drawn
    per stick (S4) more so."""
    ends: dict[float, list[float]] = {}
    for sd in (0.0, 0.3):
        shaft = ShaftFriction(ShaftParams(**{**P.__dict__, "static_friction_sd": sd}), (1, 2))
        t = 0.0
        ends[sd] = []
        for _ in range(8):
            t = _drive(shaft, 0.0, 5.0, t0=t)
            ends[sd].append(shaft.lost_motion(t)[0])
            t = _drive(shaft, 5.0, 0.0, t0=t)
    assert all(-0.4 - 1e-9 <= e <= -0.2 + 1e-9 for e in ends[0.0])
    assert len({round(e, 9) for e in ends[0.0]}) >= 2
    assert ends[0.3] != ends[0.0]
    assert len({round(e, 9) for e in ends[0.3]}) > len({round(e, 9) for e in ends[0.0]})


def test_roll_and_translation_share_one_friction_disc() -> None:
    """(S2)-(S3): a torsional load already near the limit makes a small axial move slip
    both; the load after a slip lies on the kinetic circle."""
    shaft = ShaftFriction(P, (0,))
    t = 0.0
    for k in range(1, 301):
        t = k * 0.01
        shaft.drive(0.0, 0.3 * k / 300, t)  # wind the roll up
    s, rho = shaft.lost_motion(t)
    ft = P.torsional_stiffness_nmm_per_rad * (-rho) / P.radius_mm
    assert ft == pytest.approx(0.2, abs=0.2)
    slips = shaft.slips
    shaft.drive(0.35, 0.3, t + 0.01)
    s, rho = shaft.lost_motion(t + 0.01)
    fa = P.axial_stiffness_n_per_mm * (-s)
    ft = P.torsional_stiffness_nmm_per_rad * (-rho) / P.radius_mm
    assert shaft.slips == slips + 1
    assert math.hypot(fa, ft) == pytest.approx(0.2, rel=1e-9)


def test_ageing_raises_the_breakaway() -> None:
    """(S4): after a long stick the first slip needs more travel."""
    travel = []
    for dwell in (0.0, 100.0):
        shaft = ShaftFriction(ShaftParams(**{**P.__dict__, "ageing": 0.1}), (0,))
        shaft.reset(0.0, 0.0, 0.0)
        d = 0.0
        t = dwell
        while shaft.slips == 0:
            d += 0.001
            t += 0.001
            shaft.drive(d, 0.0, t)
        travel.append(d)
    assert travel[1] > travel[0] * 1.3


def test_a_breathing_wall_drags_the_shaft_and_past_times_are_answered() -> None:
    """(S5): stuck, the base moves with the wall; the wall's swing makes it slip; a query
    of a past time after the last drive change gives the state then."""
    wall = lambda t: 4.0 * math.sin(2 * math.pi * t / 4.0)  # noqa: E731
    shaft = ShaftFriction(ShaftParams(**{**P.__dict__, "entrainment": 0.5}), (0,), wall)
    shaft.reset(0.0, 0.0, 0.0)
    shaft.advance(0.05)  # the wall has moved 0.16 mm: less than F_s / k, still stuck
    assert shaft.slips == 0
    assert shaft.lost_motion(0.05)[0] == pytest.approx(0.5 * wall(0.05), abs=1e-9)
    shaft.advance(20.0)
    assert shaft.slips > 2
    values = [shaft.lost_motion(t)[0] for t in (12.0, 13.0, 14.0)]
    assert max(values) - min(values) > 0.05
    assert all(abs(v) <= 0.4 + 1e-9 for v in values)


def test_the_wall_is_asked_once_per_time_and_its_answer_kept_exact(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """(S5) is a function of time: a time asked again (the last check of an advance, then
    the state at that time, then a past sample) is not evaluated again, and the shaft
    follows the same path as one that remembers only the last time asked."""
    calls: list[float] = []

    def wall(t: float) -> float:
        calls.append(t)
        return 4.0 * math.sin(2 * math.pi * t / 4.0)

    params = ShaftParams(**{**P.__dict__, "entrainment": 0.5})
    shaft = ShaftFriction(params, (0,), wall)
    shaft.advance(30.0)
    asked = len(calls)
    shaft.lost_motion(30.0)  # the time the advance ended on
    assert len(calls) == asked
    times = np.linspace(25.0, 30.0, 51)  # past times, twice: asked once
    path = [shaft.lost_motion(t) for t in times]
    assert [shaft.lost_motion(t) for t in times] == path
    assert len(calls) <= asked + len(times)
    # more distinct times than the memo holds: it is cleared, the answers stay the wall's
    for t in np.linspace(30.0, 60.0, 1500):
        shaft.advance(float(t))
    monkeypatch.setattr(introducer, "_WALL_MEMO", 0)  # cleared at every new time
    fresh = ShaftFriction(params, (0,), lambda t: 4.0 * math.sin(2 * math.pi * t / 4.0))
    fresh.advance(30.0)
    assert [fresh.lost_motion(t) for t in times] == path
    for t in np.linspace(30.0, 60.0, 1500):
        fresh.advance(float(t))
    assert fresh.slips == shaft.slips and fresh.lost_motion(60.0) == shaft.lost_motion(60.0)


def test_settling_follows_a_slip_with_the_time_constant() -> None:
    """(S6): after a slip the base is J exp(-t / tau) behind the quasi-static end."""
    shaft = ShaftFriction(ShaftParams(**{**P.__dict__, "settling_time_s": 1.0}), (0,))
    shaft.drive(2.0, 0.0, 1.0)  # one big slip at t = 1
    s0, _ = shaft.lost_motion(1.0)
    s1, _ = shaft.lost_motion(2.0)
    s_inf, _ = shaft.lost_motion(30.0)
    assert s0 == pytest.approx(-2.0, abs=1e-9)  # still where it was
    assert s_inf == pytest.approx(-0.2, abs=1e-6)
    assert (s1 - s_inf) / (s0 - s_inf) == pytest.approx(math.exp(-1.0), rel=1e-6)


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ConfigurationError, match="kinetic_friction_n"):
        ShaftParams(static_friction_n=0.1, kinetic_friction_n=0.2)
    with pytest.raises(ConfigurationError, match="entrainment"):
        ShaftParams(entrainment=1.5)
    with pytest.raises(ConfigurationError, match="settling_time_s"):
        ShaftParams(settling_time_s=-1.0)

"""Tests of the tables of ``icenav eval spin`` over many catheters (synthetic records)."""

from __future__ import annotations

import pytest

from icenav.eval.spin import SpinRecord
from icenav.eval.spin_report import (
    PAPER_VESSEL_BOUNDS,
    format_table,
    format_vessel_effect,
    summarize,
    vessel_effect,
)


def rec(seed: int, vessel: str, condition: str, bend: int, pos: float, rot: float) -> SpinRecord:
    return SpinRecord(
        bend_deg=bend,
        condition=condition,
        position_rmse_mm=pos,
        rotation_rmse_deg=rot,
        true_position_rmse_mm=pos - 0.1,
        true_rotation_rmse_deg=rot + 0.2,
        seed=seed,
        vessel=vessel,
        n_samples=360,
        em_missing=3,
    )


RECORDS = [
    rec(110, "straight", "dense", 60, 4.0, 15.0),
    rec(111, "straight", "dense", 60, 5.0, 16.0),
    rec(110, "steep", "dense", 60, 4.5, 15.5),
    rec(111, "steep", "dense", 60, 6.5, 17.0),
    rec(112, "steep", "dense", 60, 9.0, 19.0),  # no straight run: not in the vessel effect
    rec(110, "straight", "none", 60, 12.0, 27.0),
]


def test_summary_is_the_mean_and_the_worst_catheter() -> None:
    cells = summarize(RECORDS)
    c = cells[("straight", "dense", 60)]
    assert c.n == 2
    assert c.position_mm == pytest.approx(4.5) and c.rotation_deg == pytest.approx(15.5)
    assert c.true_position_mm == pytest.approx(4.4) and c.true_rotation_deg == pytest.approx(15.7)
    assert c.worst_position_mm == 5.0 and c.worst_rotation_deg == 16.0
    assert cells[("steep", "dense", 60)].n == 3


def test_vessel_effect_pairs_each_catheter_with_its_own_straight_run() -> None:
    eff = vessel_effect(RECORDS)
    assert set(eff) == {("steep", "dense", 60)}
    e = eff[("steep", "dense", 60)]
    assert e.n == 2  # catheter 112 ran only the steep vessel
    assert e.position_mm == pytest.approx((0.5 + 1.5) / 2)
    assert e.rotation_deg == pytest.approx((0.5 + 1.0) / 2)
    assert e.worst_position_mm == pytest.approx(1.5) and e.worst_rotation_deg == pytest.approx(1.0)


def test_tables_show_the_papers_numbers_and_bounds() -> None:
    text = format_table(RECORDS)
    assert "vessel straight, catheters 110-111 (mean of 2)" in text
    assert "(5.0, 10.3)" in text  # the paper's dense row at 60 deg, straight only
    assert "vessel steep, catheters 110-112 (mean of 3)" in text
    effect = format_vessel_effect(RECORDS)
    lo, hi = PAPER_VESSEL_BOUNDS["dense"]
    assert f"[< {lo:.0f} mm, < {hi:.0f} deg]" in effect
    assert "+1.00  +0.8 / +1.5 +1.0" in effect
    assert format_vessel_effect([r for r in RECORDS if r.vessel == "straight"]) == ""

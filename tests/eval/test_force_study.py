"""The force study's operating point: chosen on one set of records, applied to another."""

from __future__ import annotations

from typing import Any

from icenav.eval.force_study import operating_point, score


def _rec(shift: float, needed: dict[str, float]) -> dict[str, Any]:
    return {
        "shift_mm": [0.0, shift, 0.0],
        "needed_n": {ref: {"1": v} for ref, v in needed.items()},
    }


def test_the_point_keeps_false_alarms_under_the_bound_and_stops_the_most_shifts() -> None:
    # the motor reference needs 1.2 N on an undisturbed return; the tip one 0.12 N
    records = [_rec(0.0, {"motor": 1.2, "tip": 0.12})] + [
        _rec(0.0, {"motor": 0.0, "tip": 0.0}) for _ in range(19)
    ]
    records += [_rec(20.0, {"motor": 0.6, "tip": 0.6}) for _ in range(5)]
    records += [_rec(-20.0, {"motor": 0.0, "tip": 0.0}) for _ in range(5)]
    ref, c, m = operating_point(records, max_false_alarms=0.0)
    assert (ref, c, m) == ("tip", "1", 0.15)
    (fa, n), caught = score(records, ref, c, m)
    assert (fa, n) == (0, 20) and caught == {20.0: (5, 10)}
    (fa_loose, _), _ = score(records, "motor", "1", 0.5)
    assert fa_loose == 1

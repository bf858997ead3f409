"""Tests of ``icenav eval spin`` on a reduced run (72-sample spin, one bend)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from icenav.eval import spin

KEYS = {
    "bend_deg",
    "condition",
    "position_rmse_mm",
    "rotation_rmse_deg",
    "true_position_rmse_mm",
    "true_rotation_rmse_deg",
}


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, object]]:
    out = tmp_path_factory.mktemp("spin") / "spin.json"
    code = spin.main(["--seed", "101", "--samples", "72", "--bends", "40", "--json", str(out)])
    assert code == 0
    data = json.loads(out.read_text())
    assert isinstance(data, list)
    return data


def test_records_have_the_issue_structure(records: list[dict[str, object]]) -> None:
    assert len(records) == len(spin.CONDITIONS)
    assert {r["condition"] for r in records} == set(spin.CONDITIONS)
    for r in records:
        assert set(r) >= KEYS
        assert r["bend_deg"] == 40
        assert r["seed"] == 101 and r["vessel"] == "straight" and r["n_samples"] == 72
        for k in KEYS - {"bend_deg", "condition"}:
            v = r[k]
            assert isinstance(v, float) and math.isfinite(v) and v >= 0.0


def test_dense_compensation_beats_none(records: list[dict[str, object]]) -> None:
    by = {r["condition"]: r for r in records}
    for key in ("true_position_rmse_mm", "position_rmse_mm"):
        assert by["dense"][key] < 0.6 * by["none"][key]  # type: ignore[operator]
        assert by["simplified"][key] < by["none"][key]  # type: ignore[operator]
    # the roll's play is compensated: the orientation error drops
    assert (
        by["dense+hysteresis"]["true_rotation_rmse_deg"]
        < by["dense"][  # type: ignore[operator]
            "true_rotation_rmse_deg"
        ]
    )


def test_closed_loop_on_the_tracker_beats_the_open_loop(
    records: list[dict[str, object]],
) -> None:
    by = {r["condition"]: r for r in records}
    # the loop corrects its own feed-forward (the per-knob model); both aim where the tracker
    # reads the intended tip (icenav.tracker_bias)
    closed, open_ = by[spin.CLOSED_LOOP], by[spin.KNOB_HYSTERESIS]
    for key in ("position_rmse_mm", "rotation_rmse_deg", "true_position_rmse_mm"):
        assert closed[key] < 0.85 * open_[key]  # type: ignore[operator]


def test_closed_loop_spin_returns_poses_and_bounded_commands() -> None:
    from icenav.feedback import PoseServoConfig, TipPoseServo
    from icenav.trajectories import spin_trajectory

    cal = spin.calibrate(52)
    plant, tracker = spin._make_plant(52, "moderate")
    sp = spin_trajectory([math.radians(40.0), 0.0, 0.0, 0.0], 24, include_end=True)
    limit = (0.05, 0.05, 0.05, 1.0)
    servo = TipPoseServo(PoseServoConfig(max_correction=limit))
    true, em, cmd = spin.run_spin_closed_loop(plant, tracker, sp.q_model, cal, servo)
    n = sp.q_model.shape[0]
    assert true.shape == em.shape == (n, 4, 4) and cmd.shape == (n, 4)
    assert servo.n_updates + servo.n_missing == spin.SETTLE_UPDATES + n
    assert all(abs(c) <= lim + 1e-12 for c, lim in zip(servo.correction, limit, strict=True))


def test_table_prints_the_papers_numbers(records: list[dict[str, object]]) -> None:
    recs = [spin.SpinRecord(**r) for r in records]  # type: ignore[arg-type]
    text = spin.format_table(recs)
    assert "(11.0, 20.5)" in text and "(4.2, 8.6)" in text and "(5.8, 13.6)" in text
    assert "dense+hysteresis" in text


def test_bad_options_are_refused(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert spin.main(["--bends", "x"]) == 2
    assert spin.main(["--conditions", "perfect"]) == 2
    assert spin.main(["--bends", "120"]) == 2
    with pytest.raises(SystemExit):
        spin.main(["--vessel", "curly"])
    assert "unknown condition" in capsys.readouterr().err


def test_in_situ_identification_sees_the_vessels_wider_roll_play() -> None:
    """The sweeps repeated in a curved vessel find the wider play the capstan wrap gives."""
    straight = spin.identify_in_situ(101, "straight")
    steep = spin.identify_in_situ(101, "steep")
    m0, m1 = straight.joints[2], steep.joints[2]
    assert m0 is not None and m1 is not None
    # twin: roll play x exp(mu Theta_vessel), about 2.4 for the steep vessel
    assert 1.5 < m1.backlash / m0.backlash < 3.5
    assert steep.roll_play_per_bend > straight.roll_play_per_bend


def test_ours_is_reidentified_in_a_curved_vessel() -> None:
    """In a curved vessel our plays are re-identified there before the spin (default), which
    beats keeping the straight vessel's; the paper's conditions are never re-identified."""
    cal = spin.calibrate(52)
    errs = {}
    for in_situ in (True, False):
        recs = spin.run_vessel(
            52,
            "moderate",
            cal,
            bends_deg=(60,),
            n_samples=72,
            conditions=("dense", spin.OURS),
            in_situ=in_situ,
        )
        by = {r.condition: r for r in recs}
        errs[in_situ] = (by[spin.OURS].position_rmse_mm, by["dense"].position_rmse_mm)
    assert errs[True][0] < 0.8 * errs[False][0]
    assert errs[True][1] == pytest.approx(errs[False][1], abs=0.2)  # tracker noise only


def test_separating_the_tracker_bias_lowers_our_tracked_error() -> None:
    """Roll circles (icenav.tracker_bias) keep the field bias out of F's roll-turned
    correction; the paper's calibrations see the same samples with or without them."""
    import numpy as np

    with_bias = spin.calibrate(50)
    without = spin.calibrate(50, separate_bias=False)
    assert with_bias.tracker_bias is not None and without.tracker_bias is None
    np.testing.assert_array_equal(with_bias.dense_set.tip2base, without.dense_set.tip2base)
    np.testing.assert_array_equal(with_bias.five_set.tip2base, without.five_set.tip2base)
    errs = []
    for cal in (with_bias, without):
        (rec,) = spin.run_vessel(
            50, "straight", cal, bends_deg=(20,), n_samples=72, conditions=(spin.KNOB_HYSTERESIS,)
        )
        errs.append(rec.position_rmse_mm)
    assert errs[0] < 0.75 * errs[1]

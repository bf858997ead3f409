"""Tests of ``icenav eval spin`` on a reduced run (72-sample spin, one bend)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from icenav.eval import spin
from icenav.eval.spin_report import format_table

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
    # reads the intended tip (icenav.compensation.tracker_bias)
    closed, open_ = by[spin.CLOSED_LOOP], by[spin.KNOB_HYSTERESIS]
    for key in ("position_rmse_mm", "rotation_rmse_deg", "true_position_rmse_mm"):
        assert closed[key] < 0.85 * open_[key]  # type: ignore[operator]


def test_closed_loop_spin_returns_poses_and_bounded_commands() -> None:
    from icenav.control.servo import PoseServoConfig, TipPoseServo
    from icenav.geometry.trajectories import spin_trajectory

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
    text = format_table(recs)
    assert "(11.0, 20.5)" in text and "(4.2, 8.6)" in text and "(5.8, 13.6)" in text
    assert "dense+hysteresis" in text and "catheter 101" in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--bends", "x"], "--bends must be integers in deg, got 'x'"),
        (["--bends", "120"], "--bends must be in (0, 90] deg"),
        (["--conditions", "perfect"], "unknown condition"),
        (["--vessel", "curly"], "--vessel must be among"),
        (["--seeds", "110-x"], "--seeds: seeds must be integers or ranges"),
        (["--seeds", "119-110"], "ascending"),
        (["--seed", "-3"], "--seed must be >= 0, got -3"),
        (["--jobs", "0"], "--jobs must be in [1, 64] processes, got 0"),
        (["--samples", "5"], "--samples must be >= 10, got 5"),
    ],
)
def test_bad_options_are_refused_with_the_value_and_the_range(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert spin.main(argv) == 2
    assert message in capsys.readouterr().err


def test_seed_lists_and_ranges() -> None:
    assert spin.parse_seeds("110") == [110]
    assert spin.parse_seeds("112, 110-111,111") == [110, 111, 112]
    with pytest.raises(ValueError, match="no seed"):
        spin.parse_seeds(" , ")


def test_many_catheters_in_processes_give_the_same_records_as_one_by_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    common = ["--seeds", "110-111", "--vessel", "straight,steep", "--conditions", "none"]
    common += ["--samples", "24", "--bends", "40"]
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert spin.main([*common, "--jobs", "2", "--json", str(a), "--plots", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "2/2 catheters" in out and "what the curved vessel adds" in out
    assert spin.main([*common, "--json", str(b)]) == 0
    ra, rb = json.loads(a.read_text()), json.loads(b.read_text())
    assert ra == rb and len(ra) == 4
    assert {(r["seed"], r["vessel"]) for r in ra} == {
        (s, v) for s in (110, 111) for v in ("straight", "steep")
    }
    for name in (
        "curvature_position.png",
        "spin_commands_40deg.png",
        "spin_tip_straight_40deg.png",
    ):
        assert (tmp_path / name).stat().st_size > 10_000


def test_in_situ_identification_sees_the_vessels_wider_knob_play() -> None:
    """The sweeps repeated in a curved vessel find the wider knob play the tendons' capstan
    wrap gives there; the roll's play stays (the front unit turns the shaft beside the
    section, the vessel lies behind it)."""
    straight = spin.identify_in_situ(101, "straight")
    steep = spin.identify_in_situ(101, "steep")
    for k in (0, 1):
        m0, m1 = straight.joints[k], steep.joints[k]
        assert m0 is not None and m1 is not None
        assert m1.backlash_slope > 1.1 * m0.backlash_slope
    r0, r1 = straight.joints[2], steep.joints[2]
    assert r0 is not None and r1 is not None
    assert r1.backlash == pytest.approx(r0.backlash, rel=0.1)
    assert steep.roll_play_per_bend == pytest.approx(straight.roll_play_per_bend, rel=0.1)


def test_curved_vessel_calibrated_straight_and_the_opt_in_re_identification() -> None:
    """The paper's protocol by default: calibrated in the straight vessel, our model still
    beats the paper's dense map in the steep vessel. ``in_situ`` re-identifies only ours."""
    cal = spin.with_transmission(52, spin.calibrate(52))
    by = {}
    for in_situ in (False, True):
        recs = spin.run_vessel(
            52,
            "steep",
            cal,
            bends_deg=(60,),
            n_samples=72,
            conditions=("dense", spin.OURS),
            in_situ=in_situ,
        )
        by[in_situ] = {r.condition: r for r in recs}
    straight_cal = by[False]
    assert not any(r.in_situ for r in straight_cal.values())
    assert straight_cal[spin.OURS].position_rmse_mm < 0.6 * straight_cal["dense"].position_rmse_mm
    assert by[True][spin.OURS].in_situ and not by[True]["dense"].in_situ
    assert by[True]["dense"] == straight_cal["dense"]  # the paper's map is not re-identified
    assert by[True][spin.OURS] != straight_cal[spin.OURS]


def test_separating_the_tracker_bias_lowers_our_tracked_error() -> None:
    """Roll circles (icenav.compensation.tracker_bias) keep the field bias out of F's roll-turned
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


def test_plots_of_one_vessel_run_the_others_for_the_curvature_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "one.json"
    argv = ["--seed", "110", "--conditions", "none", "--samples", "24", "--bends", "40"]
    assert (
        spin.main([*argv, "--vessel", "steep", "--json", str(out), "--plots", str(tmp_path)]) == 0
    )
    assert "the others for the curvature figure only" in capsys.readouterr().out
    records = json.loads(out.read_text())
    assert [r["vessel"] for r in records] == ["steep"]  # the table and the file keep one
    assert (tmp_path / "curvature_rotation.png").stat().st_size > 10_000
    assert (tmp_path / "spin_tip_steep_40deg.png").exists()

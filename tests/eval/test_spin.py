"""Tests of ``icenav eval spin`` on a reduced run (36-sample spin, one bend)."""

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
    code = spin.main(["--seed", "101", "--samples", "36", "--bends", "40", "--json", str(out)])
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
        assert r["seed"] == 101 and r["vessel"] == "straight" and r["n_samples"] == 36
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
    closed, open_ = by[spin.CLOSED_LOOP], by["dense+hysteresis"]
    for key in ("true_position_rmse_mm", "position_rmse_mm", "true_rotation_rmse_deg"):
        assert closed[key] < open_[key]  # type: ignore[operator]


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


def test_transmission_condition_runs_on_request(tmp_path: Path) -> None:
    """The opt-in per-tendon condition is calibrated only when asked for, and its spin is
    better than no compensation (its accuracy is measured in docs/results.md)."""
    out = tmp_path / "t.json"
    args = ["--seed", "52", "--samples", "36", "--bends", "40", "--json", str(out)]
    code = spin.main([*args, "--conditions", f"none,{spin.TRANSMISSION}"])
    assert code == 0
    by = {r["condition"]: r for r in json.loads(out.read_text())}
    assert set(by) == {"none", spin.TRANSMISSION}
    assert (
        by[spin.TRANSMISSION]["true_position_rmse_mm"] < 0.5 * by["none"]["true_position_rmse_mm"]
    )
    assert spin.TRANSMISSION not in spin.CONDITIONS and spin.TRANSMISSION in spin.ALL_CONDITIONS

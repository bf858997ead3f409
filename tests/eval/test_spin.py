"""Tests of ``icenav eval spin`` on a reduced run (72-sample spin, one bend)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from icenav.eval import spin, spin_cli
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
def cal52() -> spin.Calibrations:
    """Catheter 52 calibrated by the console's procedures (shared: a calibration takes
    about 40 s)."""
    return spin.calibrate(52)


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, object]]:
    out = tmp_path_factory.mktemp("spin") / "spin.json"
    code = spin_cli.main(["--seed", "101", "--samples", "72", "--bends", "40", "--json", str(out)])
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
    # the loop corrects the same knob map's feed-forward with the tracked tip: it drives the
    # *tracked* position to the target (the tracker's field bias included, so the true pose
    # keeps that offset; at this coarse 5 deg sampling its orientation gains nothing)
    closed, open_ = by[spin.CLOSED_LOOP], by[spin.OURS]
    assert closed["position_rmse_mm"] < 0.85 * open_["position_rmse_mm"]  # type: ignore[operator]


def test_the_calibrations_are_the_consoles_procedures(cal52: spin.Calibrations) -> None:
    from icenav.compensation.elasticity import ElasticityMap
    from icenav.compensation.tendon_map import TendonKnobMap

    assert (cal52.dense.kind, cal52.simplified.kind, cal52.ours.kind) == (
        "dense",
        "five_point",
        "dense+hysteresis",
    )
    assert isinstance(cal52.dense.knob_map, ElasticityMap)
    assert isinstance(cal52.ours.knob_map, TendonKnobMap)
    assert cal52.dense_set.n_samples > 300 and cal52.five_set.n_samples == 5
    for outcome in (cal52.dense, cal52.simplified, cal52.ours):
        assert " mm RMS" in outcome.quality.describe()


def test_open_loop_commands_are_the_knob_maps_with_observe(cal52: spin.Calibrations) -> None:
    """Our condition's commands are the controller's: each state through model_to_motor from
    the state the map is in, then observe(command); the same path twice from a fresh map
    gives the same commands, and a map that is not told the commands gives others."""
    import numpy as np

    from icenav.geometry.trajectories import spin_trajectory

    sp = spin_trajectory([math.radians(40.0), 0.0, 0.0, 0.0], 36, include_end=True)
    cmd = spin._commands(spin.OURS, sp.q_model, cal52)
    path = spin._approach_path(sp.q_model)
    np.testing.assert_array_equal(cmd, spin.knob_map_commands(cal52.catheter.knob_map(), path))
    kmap = cal52.catheter.knob_map()
    blind = np.array([kmap.model_to_motor(q) for q in path])  # never observed
    assert np.max(np.abs(blind - cmd)) > 0.01


def test_closed_loop_spin_returns_poses_and_bounded_commands(cal52: spin.Calibrations) -> None:
    from icenav.control.servo import PoseServoConfig, TipPoseServo
    from icenav.geometry.trajectories import spin_trajectory

    cal = cal52
    rig, tracker = spin.make_rig(52, "moderate")
    sp = spin_trajectory([math.radians(40.0), 0.0, 0.0, 0.0], 24, include_end=True)
    limit = (0.05, 0.05, 0.05, 1.0)
    servo = TipPoseServo(PoseServoConfig(max_correction=limit))
    true, em, cmd = spin.run_spin_closed_loop(rig, tracker, sp.q_model, cal, servo)
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
    assert spin_cli.main(argv) == 2
    assert message in capsys.readouterr().err


def test_seed_lists_and_ranges() -> None:
    assert spin_cli.parse_seeds("110") == [110]
    assert spin_cli.parse_seeds("112, 110-111,111") == [110, 111, 112]
    with pytest.raises(ValueError, match="no seed"):
        spin_cli.parse_seeds(" , ")


def test_many_catheters_in_processes_give_the_same_records_as_one_by_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    common = ["--seeds", "110-111", "--vessel", "straight,steep", "--conditions", "none"]
    common += ["--samples", "24", "--bends", "40"]
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert spin_cli.main([*common, "--jobs", "2", "--json", str(a), "--plots", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "2/2 catheters" in out and "what the curved vessel adds" in out
    assert spin_cli.main([*common, "--json", str(b)]) == 0
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


def test_curved_vessel_calibrated_straight_and_the_opt_in_re_identification(
    cal52: spin.Calibrations,
) -> None:
    """The paper's protocol by default: calibrated in the straight vessel, our model still
    beats the paper's dense map in the steep vessel. ``in_situ`` re-identifies only ours."""
    cal = cal52
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


def test_plots_of_one_vessel_run_the_others_for_the_curvature_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "one.json"
    argv = ["--seed", "110", "--conditions", "none", "--samples", "24", "--bends", "40"]
    assert (
        spin_cli.main([*argv, "--vessel", "steep", "--json", str(out), "--plots", str(tmp_path)])
        == 0
    )
    assert "the others for the curvature figure only" in capsys.readouterr().out
    records = json.loads(out.read_text())
    assert [r["vessel"] for r in records] == ["steep"]  # the table and the file keep one
    assert (tmp_path / "curvature_rotation.png").stat().st_size > 10_000
    assert (tmp_path / "spin_tip_steep_40deg.png").exists()


def test_a_version_3_calibration_file_reproduces_our_condition(
    cal52: spin.Calibrations, tmp_path: Path
) -> None:
    """``eval spin --calibration CAL.json`` with the file of the dense+hysteresis fit spins as
    condition dense+hysteresis on the same catheter: the file keeps the fitted model (not only
    the samples), and the stateful map starts relaxed at every spin."""
    import numpy as np

    from icenav.calibration.files import CalibrationFile

    path = tmp_path / "cal.json"
    CalibrationFile.from_outcome(cal52.ours).save(path)
    file_map = CalibrationFile.load(path).compensation()
    commands: dict[tuple[int, str], np.ndarray] = {}
    records = spin.run_vessel(
        52,
        "straight",
        cal52,
        bends_deg=(20, 60),
        n_samples=72,
        conditions=(spin.OURS, spin.FILE),
        file_map=file_map,
        keep_commands=commands,
    )
    by = {(r.bend_deg, r.condition): r for r in records}
    for bend in (20, 60):
        ours, file = by[(bend, spin.OURS)], by[(bend, spin.FILE)]
        a, b = commands[(bend, spin.OURS)], commands[(bend, spin.FILE)]
        diff = np.max(np.abs(np.asarray(a) - np.asarray(b)), axis=1)
        # the same motor commands but where the per-tendon inverse has more than one root
        # (a knob inside its friction band: a last-bit difference of F's rebuilt tables picks
        # another one; measured on catheter 52: 2 of the 73 samples, at the spin's start,
        # by at most 0.03 rad, none at 60 deg; since session 10's tension form and F
        # smoothing (the model and F round-trip exactly, F within 1e-15): 5 samples at the
        # start, the first by 0.056 rad, the rest decaying below 2e-5; session 12's plan:
        # 3 at the start, the first by 0.038 rad, then 3 of the 73 by at most 2.4e-8 rad,
        # the inverse's solver tolerance): a few samples at the start, then the same commands
        # within 1e-6 rad (6e-5 deg, below any drive's encoder count)
        late = np.flatnonzero(diff > 1e-6)
        assert late.size <= 5 and int(late.max(initial=0)) < 10, (bend, late, diff[late])
        assert float(diff.max()) < 0.1, diff
        # hence the same spin of the twin's true tip: 4e-4 mm and 7e-4 deg measured
        assert file.true_position_rmse_mm == pytest.approx(ours.true_position_rmse_mm, abs=5e-3)
        assert file.true_rotation_rmse_deg == pytest.approx(ours.true_rotation_rmse_deg, abs=1e-2)
        # the EM-tracked RMSE too, but the two spins draw different tracker noise (one noise
        # stream, read in turn): 0.04 mm and 0.06 deg measured
        assert file.position_rmse_mm == pytest.approx(ours.position_rmse_mm, abs=0.15)
        assert file.rotation_rmse_deg == pytest.approx(ours.rotation_rmse_deg, abs=0.15)


def test_every_family_has_a_play_prior_and_a_plug_in_has_none() -> None:
    """Condition ``short+rings+prior`` reads the product line's prior (package data made by
    docs/figures/make_play_priors.py from development catheters 215-217); a plant without
    one is refused by name."""
    from icenav.errors import InvalidValueError
    from icenav.eval.spin import family_play_prior
    from icenav.sim.families import FAMILIES

    for name in FAMILIES:
        prior = family_play_prior(name)
        assert prior.product == name and len(prior.catheters) == 3
        # the line's mean map, from the same catheters (docs/calibration.md section 7)
        assert prior.map is not None and prior.map.catheters == prior.catheters
    with pytest.raises(InvalidValueError, match="no play prior"):
        family_play_prior(lambda seed, vessel: (None, None))

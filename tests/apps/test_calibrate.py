"""``icenav calibrate``: calibration files from CSV recordings of the twin."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pytest

from icenav.apps.calibrate import load_registration, main, replay_kind
from icenav.apps.calibration_csv import CSV_COLUMNS, RecordingTracker, read_calibration_csv
from icenav.calibration.files import CalibrationFile
from icenav.calibration.procedure import run_procedure
from icenav.calibration.procedures import make_procedure
from icenav.errors import FileFormatError
from icenav.sim import CatheterPlant, EMTracker

SEED = 52  # a development seed (50-52): not one that tuned the twin, not a held-out one

MOUNT_TOML = "[mount]\nsensor2tip = [[1,0,0,-1],[0,1,0,0],[0,0,1,-4],[0,0,0,1]]\n"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dense calibration (with the registration states first) recorded from the twin."""
    path = tmp_path_factory.mktemp("rec") / "dense.csv"
    assert main(["--record-twin", str(path), "--kind", "dense", "--seed", str(SEED)]) == 0
    return path


def test_a_twin_recording_gives_a_calibration_file_with_an_estimated_registration(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mount = tmp_path / "tracker.toml"
    mount.write_text(MOUNT_TOML, encoding="utf-8")
    out = tmp_path / "cal.json"
    argv = ["--from-csv", str(recorded), "--out", str(out), "--tracker-config", str(mount)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "dense: 361 of 361 states" in text
    assert "five_point: not icenav's search" in text  # the raster states nearest the targets
    assert "dense+hysteresis: not in the recording (361 of" in text  # no sweeps recorded
    loaded = CalibrationFile.load(out)
    assert loaded.calibration.n_samples > 300
    assert loaded.kind == "dense" and loaded.model is not None  # version 3: F is kept
    assert '"version": 3' in out.read_text(encoding="utf-8")[:200]
    reg = loaded.registration
    assert reg is not None and reg.n_points >= 30
    truth = EMTracker(CatheterPlant(seed=SEED), seed=SEED).config.tracker2base
    # estimated through the twin's field distortion: about a millimetre, not exact
    assert np.linalg.norm(reg.tracker2base[:3, 3] - truth[:3, 3]) < 3.0
    assert 0.1 < reg.rms_residual_mm < 1.5
    # the file loads where a lab uses it: the controller's compensation
    from icenav.apps.wiring import install_calibration, make_sim_controller

    session = make_sim_controller(seed=SEED, imaging=False)
    try:
        note = install_calibration(session.controller, out)
        ctrl = session.controller
        assert ctrl.compensation_enabled and ctrl.calibration.n_samples == 361
        q_motor = ctrl.compensation.model_to_motor(np.array([[0.5, 0.0, 0.0, 0.0]]))
        assert not np.allclose(q_motor[0, :2], [0.5, 0.0])  # F is not the identity
    finally:
        session.close()
    assert "361 samples" in note
    # and the file just written can give the registration of the next recording
    # (--registration; the registration JSON form is used in the 5-point test)
    assert load_registration(out) == reg
    # and in the evaluation: eval spin --calibration spins with the F the console installs
    import json

    from icenav.eval.spin_cli import main as spin_main

    records = tmp_path / "spin.json"
    argv = ["--seed", str(SEED), "--conditions", "none", "--bends", "40", "--samples", "40"]
    assert spin_main([*argv, "--calibration", str(out), "--json", str(records)]) == 0
    rows = {r["condition"]: r for r in json.loads(records.read_text())}
    assert set(rows) == {"none", "file"}
    assert rows["file"]["true_position_rmse_mm"] < 0.5 * rows["none"]["true_position_rmse_mm"]
    assert spin_main([*argv, "--calibration", str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["five_point", "dense+hysteresis"])
def test_replaying_a_recording_gives_the_procedure_what_it_measured(
    kind: str, tmp_path: Path
) -> None:
    """The replay is exact: an adaptive procedure (5-point search) takes the same steps, a
    long one (raster, sweeps, circles) reads the same poses, from the CSV alone."""
    plant = CatheterPlant(seed=SEED)
    t = [0.0]
    tracker = EMTracker(plant, seed=SEED, clock=lambda: t[0])
    out = io.StringIO()
    rec = RecordingTracker(tracker, out, clock=lambda: t[0])

    def move(q: np.ndarray) -> None:
        plant.move(q)
        rec.move(q)
        t[0] += 0.5

    measured = run_procedure(make_procedure(kind), move, rec)
    path = tmp_path / "replay.csv"
    path.write_text(out.getvalue(), encoding="utf-8")
    samples = read_calibration_csv(path)
    _, replayed, replay = replay_kind(kind, samples, tracker.registration, 1e-9)
    assert replay.found == replay.asked > 0
    np.testing.assert_array_equal(replayed.plan.q_motor, measured.plan.q_motor)
    np.testing.assert_allclose(replayed.tip2base, measured.tip2base, atol=1e-9, equal_nan=True)


def _csv(tmp_path: Path, rows: list[str]) -> Path:
    path = tmp_path / "rec.csv"
    path.write_text(",".join(CSV_COLUMNS) + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


GOOD = "0.0,0,0,0,0,1,2,300,1,0,0,0,valid"


def test_bad_rows_are_reported_by_line_number(tmp_path: Path) -> None:
    path = _csv(
        tmp_path,
        [
            GOOD,
            "0.1,0,0,0,0,1,2,300,1,0,0,0,lost",  # line 3
            "0.2,zero,0,0,0,1,2,300,1,0,0,0,valid",  # line 4
            "0.3,0,0,0,0,1,2,300,2,0,0,0,valid",  # line 5: quaternion norm 2
            "0.4,0,0,0,99,1,2,300,1,0,0,0,valid",  # line 6: d4 beyond +-50 mm
            "0.5,0,0,0,0,1,2,300,1,0,0,0,missing",  # line 7: a pose with missing
            "-0.5,0,0,0,0,,,,,,,,missing",  # line 8: time goes back
            "0.6,0,0,0,0,1,2,300,1,0,0,0",  # line 9: 12 columns
            "0.7,0,0,0,0,1,2,,1,0,0,0,valid",  # line 10: no z
        ],
    )
    with pytest.raises(FileFormatError) as exc:
        read_calibration_csv(path)
    text = str(exc.value)
    assert str(path) in text and "8 bad row(s)" in text
    for needle in (
        "line 3: status 'lost' is not one of valid, missing, out_of_volume",
        "line 4: phi1_rad 'zero' is not a number",
        "line 5: quaternion (qw, qx, qy, qz) has norm 2.0000, not 1",
        "line 6: d4_mm 99 mm is outside [-50, 50] mm",
        "line 7: a missing row must leave the pose columns empty",
        "line 8: t_s -0.5 s is before the previous row's 0 s",
        "line 9: 12 columns, expected 13",
        "line 10: z_mm '' is not a number (status valid)",
    ):
        assert needle in text
    samples = read_calibration_csv(path, skip_bad_rows=True)
    assert samples.n == 1 and len(samples.skipped) == 8


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "empty: no header line"),
        ("t,phi1\n", "line 1: the header must be t_s,phi1_rad"),
        (",".join(CSV_COLUMNS) + "\n", "no data rows after the header"),
        (b"\xff\xfe", "not a UTF-8 text (CSV) file"),
    ],
)
def test_unreadable_recordings_are_refused(
    content: str | bytes, message: str, tmp_path: Path
) -> None:
    path = tmp_path / "rec.csv"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8")
    with pytest.raises(FileFormatError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read_calibration_csv(path)


def test_the_cli_reports_what_it_cannot_do(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _csv(tmp_path, [GOOD])
    out = tmp_path / "cal.json"
    assert main(["--from-csv", str(path), "--out", str(out)]) == 1
    assert "give --registration FILE, or --tracker-config FILE" in capsys.readouterr().err
    mount = tmp_path / "tracker.toml"
    mount.write_text(MOUNT_TOML, encoding="utf-8")
    argv = ["--from-csv", str(path), "--out", str(out), "--tracker-config", str(mount)]
    assert main(argv) == 1
    assert "the recording holds 1 of the 36 registration states" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "one of the arguments --from-csv --record-twin is required"),
        (["--from-csv", "{csv}"], "--from-csv needs --out CAL.json"),
        (["--from-csv", "/nonexistent.csv", "--out", "x.json"], "no such file"),
        (["--from-csv", "{csv}", "--out", "x.json", "--joint-tol", "0"], "--joint-tol must be"),
        (["--from-csv", "{csv}", "--out", "x.json", "--kind", "raster"], "invalid choice"),
        (["--from-csv", "{csv}", "--out", "x.json", "--five-point-tol-mm", "-1"], "(0, 20] mm"),
        (["--record-twin", "x.csv", "--seed", "-2"], "--seed must be >= 0 (an integer), got -2"),
        (["--from-csv", "{csv}", "--out", "x.json", "--registration", "/no.json"], "no such"),
    ],
)
def test_calibrate_refuses_bad_options(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv_path = _csv(tmp_path, [GOOD])
    with pytest.raises(SystemExit) as exc:
        main([a.replace("{csv}", str(csv_path)) for a in argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_five_points_reached_in_any_order_are_a_five_point_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An operator's recording (not icenav's search): the five targets reached somewhere."""
    plant = CatheterPlant(seed=SEED)
    tracker = EMTracker(plant, seed=SEED)
    out = io.StringIO()
    rec = RecordingTracker(tracker, out, clock=lambda: 0.0)

    def move(q: np.ndarray) -> None:
        plant.move(q)
        rec.move(q)

    run_procedure(make_procedure("five_point"), move, rec)
    header, *rows = out.getvalue().splitlines()
    # the visits in reverse order, re-stamped: icenav's search cannot be replayed from it
    blocks: list[list[str]] = []
    for row in rows:
        if blocks and row.split(",")[1:5] == blocks[-1][0].split(",")[1:5]:
            blocks[-1].append(row)
        else:
            blocks.append([row])
    shuffled = [r for block in reversed(blocks) for r in block]
    restamped = [f"{0.1 * i!r}," + r.split(",", 1)[1] for i, r in enumerate(shuffled)]
    path = tmp_path / "operator.csv"
    path.write_text("\n".join([header, *restamped]) + "\n", encoding="utf-8")
    registration = tmp_path / "reg.json"
    import json

    registration.write_text(json.dumps(tracker.registration.to_dict()), encoding="utf-8")
    cal = tmp_path / "five.json"
    argv = ["--from-csv", str(path), "--out", str(cal), "--registration", str(registration)]
    assert main([*argv, "--kind", "five_point"]) == 0
    text = capsys.readouterr().out
    m = re.search(r"five_point: not icenav's search; (\d) of 5 targets reached within 5 mm", text)
    assert m is not None and int(m.group(1)) >= 3
    loaded = CalibrationFile.load(cal)
    assert loaded.calibration.n_samples == int(m.group(1))
    assert loaded.calibration.method == "five-point"
    # a strict tolerance leaves too few: refused, naming the distances
    assert main([*argv, "--kind", "five_point", "--five-point-tol-mm", "0.01"]) == 1
    assert "targets reached within 0.01 mm (nearest tips" in capsys.readouterr().out


def test_a_raster_recorded_in_another_order_is_still_the_dense_calibration(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lines = recorded.read_text(encoding="utf-8").splitlines()
    header_at = next(i for i, ln in enumerate(lines) if ln.startswith("t_s,"))
    rows = lines[header_at + 1 :]
    shuffled = rows[::-1]  # the raster (and the registration) backwards
    restamped = [f"{0.1 * i!r}," + r.split(",", 1)[1] for i, r in enumerate(shuffled)]
    path = tmp_path / "backwards.csv"
    path.write_text("\n".join([lines[header_at], *restamped]) + "\n", encoding="utf-8")
    mount = tmp_path / "tracker.toml"
    mount.write_text(MOUNT_TOML, encoding="utf-8")
    argv = ["--from-csv", str(path), "--out", str(tmp_path / "c.json")]
    assert main([*argv, "--tracker-config", str(mount), "--kind", "dense"]) == 0
    assert "dense: 361 of 361 states" in capsys.readouterr().out


def test_a_bad_calibration_file_is_refused_naming_it(tmp_path: Path) -> None:
    from icenav.apps.wiring import install_calibration, make_sim_controller

    bad = tmp_path / "cal.json"
    bad.write_text('{"format": "icenav.calibration.plans", "version": 2', encoding="utf-8")
    session = make_sim_controller(imaging=False)
    try:
        with pytest.raises(FileFormatError, match=r"cal\.json: not valid JSON"):
            install_calibration(session.controller, bad)
        assert session.controller.compensation is None
    finally:
        session.close()


def test_the_registration_comes_from_a_session_a_calibration_file_or_its_json(
    tmp_path: Path,
) -> None:
    import json

    from icenav.devices.registration import Registration
    from icenav.errors import RegistrationError
    from icenav.persistence.store import SessionStore

    t2b = np.eye(4)
    t2b[:3, 3] = (1.0, 2.0, 3.0)
    reg = Registration(t2b, 0.4, 0.7, 36)
    session = tmp_path / "lab.sqlite"
    with SessionStore(session) as store:
        store.save_registration(reg, 0.0)
    assert load_registration(session) == reg
    (tmp_path / "reg.json").write_text(json.dumps(reg.to_dict()), encoding="utf-8")
    assert load_registration(tmp_path / "reg.json") == reg
    with SessionStore(tmp_path / "empty.sqlite") as store:
        pass
    with pytest.raises(RegistrationError, match="the session holds no registration"):
        load_registration(tmp_path / "empty.sqlite")
    (tmp_path / "other.json").write_text("{}", encoding="utf-8")
    with pytest.raises(RegistrationError, match="holds no registration"):
        load_registration(tmp_path / "other.json")

"""``icenav run`` end to end: emulated CiA 402 drives configured as examples/robot.toml on the
virtual bus, the NDI Aurora's mocked command sequence (or the twin's tracker), the guided
registration stored in the session, the controller running headless."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from icenav.apps.run import main
from icenav.calibration.files import CalibrationFile
from icenav.calibration.plans import five_point_targets
from icenav.compensation.elasticity import CalibrationSet, ElasticityMap
from icenav.geometry.kinematics import forward
from icenav.persistence.store import SessionStore
from tests.support.hardware import (
    TRUE_TRACKER2BASE,
    TrackingAurora,
    emulated_bench,
    tracker_toml,
)


def five_point_file(path: Path) -> Path:
    """A version 3 five_point calibration file of a catheter that bends 10 % further than the
    model (F from five tracked samples)."""
    knobs, _ = five_point_targets()
    q = np.zeros((5, 4))
    q[:, :2] = knobs
    truth = q.copy()
    truth[:, :2] *= 1.1
    samples = CalibrationSet(q_motor=q, tip2base=forward(truth, check=False), method="five-point")
    CalibrationFile(samples, kind="five_point", model=ElasticityMap.build(samples)).save(path)
    return path


def test_run_registers_an_ndi_tracker_on_the_drives_and_stores_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    session = tmp_path / "bench.sqlite"
    with emulated_bench(tmp_path) as (robot, drives):
        aurora = TrackingAurora(robot, drives)
        aurora.install(monkeypatch)
        argv = ["--robot-config", str(robot), "--tracker", "ndi"]
        argv += ["--tracker-config", str(tracker_toml(tmp_path)), "--session", str(session)]
        cal = five_point_file(tmp_path / "cal.json")
        assert main([*argv, "--headless", "--duration", "0.5", "--calibration", str(cal)]) == 0
        out = capsys.readouterr().out
        assert "registration state 36" in out
        assert "TSTART:" in aurora.commands and aurora.commands[-1] == "TSTOP:"
        # the second run reuses the session's registration: no registration motion; and the
        # calibration installed in the first is installed again from the session
        n_reads = aurora.commands.count("BX:0801")
        assert main([*argv, "--headless", "--duration", "0.3"]) == 0
        out2 = capsys.readouterr().out
    assert "registration: from the session" in out2
    assert "registration state" not in out2
    assert "calibration re-installed from the session: 5 samples (five_point)" in out2
    assert aurora.commands.count("BX:0801") - n_reads < 36
    with SessionStore(session, read_only=True) as store:
        reg = store.registration()
    assert reg is not None and reg.n_points == 36
    # recovered from poses at commanded states: the encoders' resolution, not the model's
    assert np.allclose(reg.tracker2base, TRUE_TRACKER2BASE, atol=0.05)
    assert reg.rms_residual_mm < 0.05
    assert f"residual {reg.rms_residual_mm:.2f} mm RMS" in out


def test_run_refuses_a_registration_above_the_residual_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    wrong_mount = np.eye(4)
    wrong_mount[:3, 3] = (6.0, 0.0, -4.0)  # a mount drawing 7 mm off
    with emulated_bench(tmp_path) as (robot, drives):
        TrackingAurora(robot, drives).install(monkeypatch)
        code = main(
            ["--robot-config", str(robot), "--tracker", "ndi", "--headless", "--duration", "0.1"]
            + ["--tracker-config", str(tracker_toml(tmp_path, sensor2tip=wrong_mount))]
        )
    assert code == 1
    err = capsys.readouterr().err
    assert "exceeds the limit 1.00 mm ([registration] max_residual_mm)" in err


def test_run_with_the_twins_tracker_follows_the_drives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = tmp_path / "twin.sqlite"
    with emulated_bench(tmp_path) as (robot, _):
        code = main(
            ["--robot-config", str(robot), "--tracker", "sim", "--session", str(session)]
            + ["--headless", "--duration", "0.3", "--seed", "101"]
        )
    assert code == 0, capsys.readouterr().err
    with SessionStore(session, read_only=True) as store:
        reg = store.registration()
    assert reg is not None
    # the twin's tracker: field distortion, jitter and roll play (docs: 0.3-0.8 mm)
    assert 0.05 < reg.rms_residual_mm < 1.5


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--tracker", "gps"], "invalid choice: 'gps'"),
        (["--tracker", "none", "--tracker-config", "{cfg}"], "there is no tracker to configure"),
        (["--duration", "5"], "--duration and --calibrate go with --headless"),
        (["--headless", "--duration", "-1"], "--duration must be finite and > 0 s, got -1.0"),
        (["--port", "99999"], "--port must be in [0, 65535], got 99999"),
        (["--registration", "session"], "--registration session needs --session FILE"),
        (["--headless", "--calibrate", "dense", "--tracker", "none"], "needs a tracker"),
        (["--host", "0.0.0.0"], "this machine only"),
    ],
)
def test_run_refuses_bad_options(
    extra: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    robot = tmp_path / "robot.toml"
    robot.write_text("", encoding="utf-8")
    cfg = tmp_path / "tracker.toml"
    cfg.write_text("", encoding="utf-8")
    extra = [e.replace("{cfg}", str(cfg)) for e in extra]
    with pytest.raises(SystemExit) as exc:
        main(["--robot-config", str(robot), *extra])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_run_needs_a_robot_config(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--headless"])
    assert "--robot-config" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[ndi]\nbaud = 9600\n", "[ndi] has unknown key(s) ['baud']"),
        ("[mount]\nsensor2tip = [[1, 2], [3, 4]]\n", "[mount] sensor2tip must be"),
        ("[registration]\nn_average = 0\n", "n_average must be >= 1 samples, got 0"),
        ("[registration]\nmax_residual_mm = -1\n", "max_residual_mm must be > 0 mm"),
        ("[laser]\n", "unknown table(s) ['laser']"),
        ("[ndi\n", "not a valid TOML file"),
    ],
)
def test_tracker_config_errors_name_the_file_and_key(
    text: str, message: str, tmp_path: Path
) -> None:
    from icenav.apps.hardware import load_tracker_config
    from icenav.errors import FileFormatError

    path = tmp_path / "tracker.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(FileFormatError, match=None) as exc:
        load_tracker_config(path)
    assert str(path) in str(exc.value) and message in str(exc.value)


def test_run_without_a_session_registration_refuses_registration_session(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    with emulated_bench(tmp_path) as (robot, drives):
        TrackingAurora(robot, drives).install(monkeypatch)
        code = main(
            ["--robot-config", str(robot), "--tracker", "ndi", "--headless", "--duration", "0.1"]
            + ["--tracker-config", str(tracker_toml(tmp_path))]
            + ["--session", str(tmp_path / "empty.sqlite"), "--registration", "session"]
        )
    assert code == 1
    assert "the session holds no registration" in capsys.readouterr().err


def test_a_stop_during_the_registration_ends_it_and_the_robot_holds(tmp_path: Path) -> None:
    """Ctrl-C / SIGTERM set the stop event: the registration's next wait raises and the
    drives hold where they are (no further state is commanded)."""
    import threading

    from icenav.apps.hardware import FollowingTwin, guided_registration
    from icenav.devices.canopen.config import load_robot_config
    from icenav.devices.canopen.robot import CANopenRobot
    from icenav.errors import MotionAborted

    stop = threading.Event()
    lines: list[str] = []

    def report(text: str) -> None:
        lines.append(text)
        if "registration state 3:" in text:
            stop.set()  # the operator presses Ctrl-C after the third state

    with emulated_bench(tmp_path) as (robot_toml, _):
        robot = CANopenRobot(load_robot_config(robot_toml))
        try:
            robot.home()
            twin = FollowingTwin(robot, 101, "straight", clock=lambda: 0.0)
            twin.tracker.start()
            mount = twin.tracker.config.sensor2tip
            with pytest.raises(MotionAborted, match="Ctrl-C or SIGTERM"):
                guided_registration(robot, twin.tracker, mount, report=report, stop=stop)
            held = robot.read_state().q
        finally:
            robot.close()
    assert [ln for ln in lines if "registration state" in ln][-1].startswith(
        "  registration state 3:"
    )
    assert twin.tracker.registration is None  # nothing half-done is installed
    # held at the third state (roll 120 deg at -30 mm): the fourth was never commanded
    np.testing.assert_allclose(held, [0.0, 0.0, np.radians(120.0), -30.0], atol=2e-3)


def test_a_stop_during_a_move_holds_the_robot_where_it_is() -> None:
    import threading
    from types import SimpleNamespace

    from icenav.apps.hardware import move_and_wait
    from icenav.devices.robot import RobotStatus
    from icenav.errors import MotionAborted

    stop = threading.Event()
    calls: list[str] = []

    class Robot:
        def command_position(self, q: np.ndarray) -> None:
            calls.append("command")

        def read_state(self) -> SimpleNamespace:
            calls.append("read")
            stop.set()  # Ctrl-C arrives while the robot is still on its way
            return SimpleNamespace(q=np.zeros(4), status=RobotStatus.ENABLED)

        def stop(self) -> None:
            calls.append("stop")

    with pytest.raises(MotionAborted, match="the robot holds"):
        move_and_wait(Robot(), np.array([0.0, 0.0, 0.0, 40.0]), stop=stop)
    assert calls == ["command", "read", "stop"]

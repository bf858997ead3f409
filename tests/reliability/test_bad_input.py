"""Bad input where it enters: console fields (view names), CLI flags, OpenIGTLink commands,
files. Every rejection is a clear IcenavError or an argparse usage error; never a crash."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icenav.control.controller import Controller, ControllerConfig
from icenav.devices.sim_robot import IdealPlant, SimulatedRobot
from icenav.errors import FileFormatError, IcenavError
from icenav.persistence.store import SessionStore

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from fuzz.targets import target_igtl_command  # noqa: E402


def _controller(tmp_path: Path) -> tuple[Controller, SessionStore]:
    from icenav.apps.wiring import StoreRecorder

    store = SessionStore(tmp_path / "s.icenav")
    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    ctrl.set_recorder(StoreRecorder(store, ctrl.roadmap))
    return ctrl, store


NASTY_NAMES = [
    "",
    "   ",
    "\x00",
    "a\x00b",
    "\x1b[2J\x1b[31mred",
    "x" * 100_000,
    "../../etc/passwd",
    "/abs/path",
    "C:\\\\windows",
    "\u202eevil",
    "name'); DROP TABLE views;--",
    "snow\u2603",
]


@pytest.mark.parametrize("name", NASTY_NAMES, ids=range(len(NASTY_NAMES)))
def test_view_names_from_clients_are_data_never_paths(tmp_path: Path, name: str) -> None:
    ctrl, store = _controller(tmp_path)
    before = set(tmp_path.iterdir())
    ctrl.save_view(name)
    state = ctrl.step()
    if name.strip():
        assert [v.name for v in state.views] == [name]
        store.commit()
        assert [v.name for v in store.load_views()] == [name]  # stored verbatim
    else:
        assert state.views == () and "non-empty" in state.message
    assert set(tmp_path.iterdir()) == before  # no file was made from the name
    store.close()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(names=st.lists(st.text(max_size=40), min_size=1, max_size=6))
def test_any_view_names_round_trip_through_the_store(names: list[str]) -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        ctrl, store = _controller(Path(d))
        for n in names:
            ctrl.save_view(n)
            ctrl.step()
        expected = list(dict.fromkeys(n for n in names if n.strip()))
        assert [v.name for v in ctrl.views] == expected
        store.close()
        with SessionStore(Path(d) / "s.icenav", read_only=True) as again:
            assert [v.name for v in again.load_views()] == expected


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
def test_igtl_command_parser_never_raises(data: bytes) -> None:
    target_igtl_command(data)


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--port", "-1"], "--port must be in"),
        (["--port", "70000"], "--port must be in"),
        (["--port", "x"], "invalid int value"),
        (["--igtl-port", "-5"], "--igtl-port must be in"),
        (["--duration", "nan"], "--duration must be > 0"),
        (["--duration", "inf"], "--duration must be > 0"),
        (["--duration", "-3"], "--duration must be > 0"),
        (["--seed", "-1"], "--seed must be >= 0"),
        (["--vessel", "wavy"], "invalid choice"),
        (["--host", "0.0.0.0"], "add --allow-remote"),
        (["--host", "10.0.0.5", "--headless"], "add --allow-remote"),
    ],
)
def test_demo_cli_rejects_bad_flags_with_usage(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture
) -> None:
    from icenav.apps.demo import main

    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "usage: icenav demo" in err and expected in err


def test_demo_with_a_corrupt_session_file_is_a_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from icenav.apps.demo import main

    bad = tmp_path / "s.icenav"
    bad.write_bytes(b"SQLite format 3\x00" + bytes(range(256)) * 8)
    assert main(["--headless", "--duration", "0.5", "--session", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "icenav demo:" in err and "not a readable icenav session" in err


@settings(max_examples=40, deadline=None)
@given(
    q=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=4, max_size=4),
    frame=st.sampled_from(["knob", "tip", "joint", ""]),
)
def test_jog_requests_are_checked_at_the_boundary(q: list[float], frame: str) -> None:
    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    v = q if frame != "tip" else q + [0.0, 0.0]
    try:
        ctrl.jog(v, frame)  # type: ignore[arg-type]
    except IcenavError as exc:
        assert "jog" in str(exc)
        return
    assert frame in ("knob", "tip") and np.all(np.isfinite(v))
    state = ctrl.step()
    assert np.all(np.isfinite(state.q_motor))


def test_store_file_of_another_kind_is_rejected(tmp_path: Path) -> None:
    import sqlite3

    other = tmp_path / "other.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE t(x)")
    with pytest.raises(FileFormatError, match="not an icenav session"):
        SessionStore(other)
    text = tmp_path / "text.icenav"
    text.write_text("hello")
    with pytest.raises(FileFormatError, match="not a readable icenav session"):
        SessionStore(text)


def test_huge_finite_jog_is_refused_not_overflowed() -> None:
    """Found by hypothesis: a finite but huge tip-frame velocity overflowed the tip-jog
    solve; it is refused with the bound and the unit."""
    ctrl = Controller(SimulatedRobot(IdealPlant()), ControllerConfig())
    with pytest.raises(IcenavError, match=r"jog velocity must be within \+-1000 \(rad/s or mm/s"):
        ctrl.jog([0.0, 0.0, 0.0, 1.797693134862316e307, 0.0, 0.0], "tip")
    ctrl.jog([0.0, 0.0, 0.0, 999.0, 0.0, 0.0], "tip")
    assert np.all(np.isfinite(ctrl.step().q_motor))

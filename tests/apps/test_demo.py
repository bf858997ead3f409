"""``icenav demo``: the headless smoke run, the console process, and its CLI checks."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from icenav.apps.demo import main
from icenav.persistence.store import SessionStore

ICENAV = [sys.executable, "-m", "icenav.apps.cli"]


def test_headless_demo_runs_and_persists_its_session(tmp_path: Path) -> None:
    session = tmp_path / "procedure.icenav"
    assert main(["--headless", "--duration", "8", "--session", str(session)]) == 0
    with SessionStore(session, read_only=True) as store:
        views = store.load_views()
        assert len(views) == 2
        assert store.load_roadmap().n_vertices > 100


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--port", "-1"], "--port must be in"),
        (["--port", "70000"], "--port must be in"),
        (["--seed", "-3"], "--seed must be >= 0"),
        (["--headless", "--duration", "nan"], "--duration must be > 0"),
        (["--vessel", "twisty"], "invalid choice"),
    ],
)
def test_bad_flags_are_refused(
    argv: list[str], match: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert match in capsys.readouterr().err


def test_console_process_starts_prints_its_url_and_stops_on_sigterm(tmp_path: Path) -> None:
    env = dict(os.environ, SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="dummy")
    proc = subprocess.Popen(
        [*ICENAV, "demo", "--port", "0", "--session", str(tmp_path / "s.icenav")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 120
        url = ""
        lines = []
        while time.monotonic() < deadline and not url:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if line.startswith("icenav console: http://127.0.0.1:"):
                url = line.split()[2]
        assert url, "".join(lines)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
    assert (tmp_path / "s.icenav").exists()


@pytest.mark.slow
def test_headless_demo_on_emulated_canopen_drives() -> None:
    # the same scripted procedure through CANopenRobot and five emulated CiA 402 drives on
    # a virtual CAN bus (real time: about 20 s)
    assert main(["--headless", "--robot", "emulated-canopen", "--duration", "8"]) == 0


def test_export_directory_defaults_beside_the_session(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from icenav.apps.demo import _check_args, _parser, export_dir_for

    parser = _parser()
    args = parser.parse_args(["--session", str(tmp_path / "a" / "s.icenav")])
    assert export_dir_for(args) == tmp_path / "a" / "exports"
    monkeypatch.chdir(tmp_path)
    assert export_dir_for(parser.parse_args([])) == tmp_path / "exports"
    args = parser.parse_args(["--export-dir", "out", "--session", "x/s.icenav"])
    assert export_dir_for(args) == tmp_path / "out"  # the option wins, made absolute
    (tmp_path / "file").write_text("x")
    with pytest.raises(SystemExit) as info:
        _check_args(parser.parse_args(["--export-dir", "file"]), parser)
    assert info.value.code == 2
    assert "--export-dir file exists and is not a directory" in capsys.readouterr().err


def test_session_files_the_demo_refuses_name_the_file_or_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty.icenav"
    empty.touch()
    assert main(["--headless", "--duration", "1", "--session", str(empty)]) == 1
    assert f"session file {empty} is empty (0 bytes)" in capsys.readouterr().err
    missing = tmp_path / "nope" / "s.icenav"
    assert main(["--headless", "--duration", "1", "--session", str(missing)]) == 1
    assert f"the folder {missing.parent} does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--new-session"])
    assert "--new-session needs --session" in capsys.readouterr().err


def test_new_session_starts_a_session_in_an_empty_file_and_never_overwrites(
    tmp_path: Path,
) -> None:
    from icenav.apps.demo import _parser, start_new_session
    from icenav.errors import StoreError

    empty = tmp_path / "empty.icenav"
    empty.touch()
    args = _parser().parse_args(["--session", str(empty), "--new-session"])
    start_new_session(args)
    with SessionStore(empty) as store:  # now a session, resumed without the flag
        assert store.load_views().names() == []
    with pytest.raises(StoreError, match="never written over"):
        start_new_session(args)


def test_the_console_keeps_its_session_in_the_default_file_and_says_where(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import argparse

    from icenav.apps.demo import resolve_session
    from icenav.apps.options import default_session_path

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert default_session_path() == tmp_path / "data" / "icenav" / "demo.sqlite"
    console = argparse.Namespace(session=None, no_session=False, headless=False)
    assert resolve_session(console) == tmp_path / "data" / "icenav" / "demo.sqlite"
    from icenav.apps.demo import export_dir_for

    console.session = resolve_session(console)
    console.session_is_default, console.export_dir = True, None
    assert export_dir_for(console) == Path.cwd().absolute() / "exports"  # not the data folder
    assert (tmp_path / "data" / "icenav").is_dir()
    given = argparse.Namespace(session=tmp_path / "mine.sqlite", no_session=False, headless=False)
    assert resolve_session(given) == tmp_path / "mine.sqlite"
    assert (
        resolve_session(argparse.Namespace(session=None, no_session=True, headless=False)) is None
    )
    # the scripted headless run keeps nothing unless asked
    assert (
        resolve_session(argparse.Namespace(session=None, no_session=False, headless=True)) is None
    )
    monkeypatch.setenv("XDG_DATA_HOME", "relative/dir")  # not absolute: ignored (XDG spec)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert (
        default_session_path() == tmp_path / "home" / ".local" / "share" / "icenav" / "demo.sqlite"
    )

"""The command-line entry point."""

from __future__ import annotations

import pytest

from icenav.apps.cli import main


def test_help_lists_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in (
        "demo",
        "serve",
        "run",
        "calibrate",
        "eval",
        "export-view",
        "export-calibration",
    ):
        assert f"  {command} " in out


@pytest.mark.parametrize(
    "command", ["serve", "run", "calibrate", "export-view", "export-calibration"]
)
def test_every_new_command_has_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: icenav {command}") and len(out.splitlines()) > 8


def test_unknown_command_fails_with_usage(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["frobnicate"]) == 2
    assert "unknown command 'frobnicate'" in capsys.readouterr().err


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("icenav ")

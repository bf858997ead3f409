"""``icenav export-calibration``: its bad inputs (the export of a real session is tested with
the session's calibration in tests/apps/test_wiring.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from icenav.apps.export_calibration import main


def test_bad_inputs_are_refused_naming_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--session", str(tmp_path / "none.sqlite"), "--out", str(tmp_path / "c.json")])
    assert exc.value.code == 2
    assert "none.sqlite: no such file" in capsys.readouterr().err
    not_a_session = tmp_path / "notes.txt"
    not_a_session.write_text("hello\n", encoding="utf-8")
    with pytest.raises(SystemExit):
        main(["--session", str(not_a_session), "--out", str(tmp_path)])
    assert "is a directory" in capsys.readouterr().err
    assert main(["--session", str(not_a_session), "--out", str(tmp_path / "c.json")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("icenav export-calibration: ") and "notes.txt" in err

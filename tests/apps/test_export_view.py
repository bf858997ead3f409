"""``icenav export-view --session FILE --view NAME``: a saved view out of a session file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from icenav.apps.cli import main
from icenav.apps.wiring import make_sim_controller
from icenav.persistence.dicom import read_view_clip


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    """A session of the twin with view "home" saved with its image."""
    path = tmp_path_factory.mktemp("s") / "lab.sqlite"
    s = make_sim_controller(seed=101, session=path)
    try:
        ctrl = s.controller
        frame = ctrl.render_image()
        assert frame is not None
        ticket = ctrl.save_view("home")
        ctrl.run_until(lambda _: ticket.finished, 2000)  # saved once it is on disk
        assert ticket.final(0).outcome.value == "done"
        q = ctrl.views.get("home").q.copy()
    finally:
        s.close()
    return path, q, frame.pixels


def test_export_view_writes_the_views_image_with_its_state(
    session: tuple[Path, np.ndarray, np.ndarray],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    path, q, pixels = session
    assert (
        main(["export-view", "--session", str(path), "--view", "home", "--out", str(tmp_path)]) == 0
    )
    written = Path(capsys.readouterr().out.split("wrote ", 1)[1].strip())
    assert written.parent == tmp_path.absolute()
    clip = read_view_clip(written)
    assert clip.view_name == "home"
    np.testing.assert_array_equal(clip.frames[0], pixels)
    np.testing.assert_allclose(clip.q_motor, q)


@pytest.mark.parametrize(
    ("view", "message"),
    [("apex", "no saved view named 'apex' (saved views: 'home')")],
)
def test_export_view_names_what_is_missing(
    session: tuple[Path, np.ndarray, np.ndarray],
    view: str,
    message: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    path, _, _ = session
    assert (
        main(["export-view", "--session", str(path), "--view", view, "--out", str(tmp_path)]) == 1
    )
    assert message in capsys.readouterr().err
    missing = tmp_path / "none.sqlite"
    assert main(["export-view", "--session", str(missing), "--view", "home"]) == 1
    assert "no such session file" in capsys.readouterr().err


def test_export_view_refuses_a_file_as_out_dir(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(SystemExit):
        main(["export-view", "--session", str(f), "--view", "v", "--out", str(f)])
    assert "exists and is not a directory" in capsys.readouterr().err

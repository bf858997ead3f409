"""The wiring: the console's anatomy (meshes and their labels in the base frame), and the
calibration in use (installed from a file, stored in the session, re-installed on reopen --
after a kill -9 too -- and exported)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from icenav.apps import export_calibration
from icenav.apps.wiring import (
    anatomy_labels,
    anatomy_meshes,
    install_calibration,
    make_sim_controller,
)
from icenav.calibration.files import CalibrationFile
from icenav.compensation.elasticity import ElasticityMap
from icenav.compensation.tendon_map import TendonKnobMap
from icenav.persistence.store import SessionStore
from icenav.sim.anatomy import BASE2ANATOMY, Tissue, default_phantom


def test_labels_anchor_each_mesh_in_the_base_frame() -> None:
    ph = default_phantom()
    meshes = {m.name: m for m in anatomy_meshes(ph)}
    labels = {lm.key: lm for lm in anatomy_labels(ph)}
    for key in ("ra", "rv", "la", "lv", "aorta", "ivc", "svc", "tricuspid_valve"):
        assert f"anatomy-{key}" in meshes
        mesh = meshes[f"anatomy-{key}"]
        p = np.asarray(labels[key].point)
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        assert np.all(p >= lo - 1e-9) and np.all(p <= hi + 1e-9), key
    # the RA anchor maps back into RA blood
    ra = BASE2ANATOMY[:3, :3] @ np.asarray(labels["ra"].point) + BASE2ANATOMY[:3, 3]
    assert ph.labels_at(ra, 0.0) == Tissue.RA_BLOOD
    # orientation marker: anterior is base +x (the image direction at q = 0), superior +z
    np.testing.assert_allclose(labels["dir-A"].point, [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(labels["dir-S"].point, [0.0, 0.0, 1.0], atol=1e-12)
    assert labels["interatrial_septum"].label == "IAS"


# --- calibrations: installed from a file, stored in the session, re-installed on reopen -------

CHILD = textwrap.dedent(
    """
    import json
    import sys

    import numpy as np

    from icenav.apps.wiring import make_sim_controller
    from icenav.control.config import ControllerConfig
    from icenav.control.modes import Mode

    # 25 Hz: the same motions at the same speeds in a quarter of the cycles
    config = ControllerConfig(rate_hz=25.0)
    session = make_sim_controller(seed=103, imaging=False, session=sys.argv[1], config=config)
    ctrl = session.controller
    ticket = ctrl.start_calibration("five_point")
    ctrl.run_until(lambda s: s.mode is Mode.IDLE and s.cycle > 5, 10000)
    ctrl.run_cycles(3)  # the fit is installed by the loop
    print("RESULT", ticket.final(timeout=0).outcome.value, flush=True)
    q = np.array(json.loads(sys.argv[2]))
    print("MAP", json.dumps(ctrl.compensation.model_to_motor(q).tolist()), flush=True)
    session.recorder.drain()  # the writer thread has run the calibration's row
    print("STORED", flush=True)
    sys.stdin.read()  # until killed
    """
)
CHILD_TIMEOUT_S = 300.0
"""The child is killed after this long whatever it printed (the test then fails, never hangs)."""


def _states(n: int) -> np.ndarray:
    rng = np.random.default_rng(5)
    return np.column_stack(
        [rng.uniform(-1.2, 1.2, (n, 2)), rng.uniform(-2.0, 2.0, n), rng.uniform(-20, 20, n)]
    )


def test_a_console_calibration_survives_a_kill_9_and_is_installed_again(tmp_path: Path) -> None:
    path = tmp_path / "session.icenav"
    q = _states(8)
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path), json.dumps(q.tolist())],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    lines: dict[str, str] = {}
    watchdog = threading.Timer(CHILD_TIMEOUT_S, proc.kill)
    watchdog.start()
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # blocks on the child's output: no sleep, no timing
            key, _, rest = line.partition(" ")
            lines[key.strip()] = rest.strip()
            if key.strip() == "STORED":
                break
    finally:
        watchdog.cancel()
        proc.send_signal(signal.SIGKILL)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert lines.get("RESULT") == "done", err
    before = np.array(json.loads(lines["MAP"]))

    session = make_sim_controller(seed=103, imaging=False, session=path)
    try:
        ctrl = session.controller
        text = session.resumed_calibration
        assert text is not None and "re-installed from the session" in text, text
        assert "five_point" in text and "compensation on" in text
        assert ctrl.compensation_enabled and isinstance(ctrl.compensation, ElasticityMap)
        np.testing.assert_allclose(ctrl.compensation.model_to_motor(q), before, atol=1e-12)
        assert "re-installed" in ctrl.step().message  # what the console shows first
    finally:
        session.close()
    # the operator writes the calibration in use to a file: it loads as the same F
    out = tmp_path / "cal.json"
    assert export_calibration.main(["--session", str(path), "--out", str(out)]) == 0
    loaded = CalibrationFile.load(out)
    assert loaded.kind == "five_point"
    np.testing.assert_allclose(loaded.compensation().model_to_motor(q), before, atol=1e-12)
    assert export_calibration.main(["--session", str(path), "--out", str(out)]) == 1  # exists


def test_a_dense_hysteresis_file_installs_its_knob_map_and_the_session_keeps_it(
    twin_catheter_calibration: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cat = twin_catheter_calibration
    cal = tmp_path / "cal.json"
    CalibrationFile(cat.dense, kind="dense+hysteresis", model=cat).save(cal)
    path = tmp_path / "session.icenav"
    q = _states(6)
    first = make_sim_controller(seed=52, imaging=False, session=path)
    try:
        assert first.resumed_calibration is None  # a new session holds none
        text = install_calibration(first.controller, cal, first.store)
        assert "dense+hysteresis" in text and str(cal) in text
        comp = first.controller.compensation
        assert isinstance(comp, TendonKnobMap) and first.controller.compensation_enabled
        np.testing.assert_allclose(
            comp.model_to_motor(q), cat.knob_map().model_to_motor(q), atol=1e-12
        )
    finally:
        first.close()
    again = make_sim_controller(seed=52, imaging=False, session=path)
    try:
        assert again.resumed_calibration is not None
        assert "dense+hysteresis" in again.resumed_calibration
        comp = again.controller.compensation
        assert isinstance(comp, TendonKnobMap)
        np.testing.assert_allclose(
            comp.model_to_motor(q), cat.knob_map().model_to_motor(q), atol=1e-12
        )
    finally:
        again.close()
    # a damaged stored calibration does not stop the session: compensation off, and said so
    with SessionStore(path) as store:
        store.save_calibration_document("dense+hysteresis", {"format": "nope"}, 0.0)
    third = make_sim_controller(seed=52, imaging=False, session=path)
    try:
        assert third.resumed_calibration is not None
        assert "NOT installed (compensation off)" in third.resumed_calibration
        assert "not an icenav calibration file" in third.resumed_calibration
        assert third.controller.compensation is None
    finally:
        third.close()
    # a session without a calibration has nothing to export
    empty = tmp_path / "empty.icenav"
    make_sim_controller(imaging=False, session=empty).close()
    assert export_calibration.main(["--session", str(empty), "--out", str(tmp_path / "x")]) == 1
    assert "holds no calibration in use" in capsys.readouterr().err

"""The process killed (SIGKILL) mid-procedure and restarted: nothing committed is lost, and
the restarted controller does not pretend it travelled from the old last state to its start."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest

from icenav.apps.wiring import make_sim_controller
from icenav.persistence.store import SessionStore

# A procedure that saves a view every 150 cycles and says so once the controller tells the
# operator it is saved (the store's writer thread has committed it; until then the message
# is "saving to disk"), then keeps driving until it is killed. The next view is saved only
# after the previous one was reported saved: on a busy machine a commit can take longer
# than 150 cycles, and a later "saving to disk" would hide the earlier "saved"; and the
# motion stays inside the joint limits, whose message would hide it too. The procedure runs
# at most 2.5x faster than real time (4 ms per 10 ms cycle): as fast as it goes, the loop
# queues state batches faster than the store's writer thread commits them, and a view's
# commit waits behind an ever longer queue (tens of thousands of cycles per view).
SCRIPT = textwrap.dedent(
    """
    import sys
    import time
    from icenav.apps.wiring import make_sim_controller

    t = [0.0]
    session = make_sim_controller(imaging=False, session=sys.argv[1], clock=lambda: t[0])
    ctrl = session.controller
    v = [0.25, -0.15, 0.3, 2.0]
    cycle = 0
    n_saved = 0
    pending = None
    while True:
        if pending is None and cycle % 150 == 149:
            pending = f"v{n_saved}"
            ctrl.save_view(pending)
        if cycle >= 300 and cycle % 150 == 0:
            # out to about (0.75, -0.45, 0.9 rad, 6 mm), then back and forth by half that:
            # never near the restart's q = 0, and inside the joint limits
            v = [-v[0], -v[1], -v[2], -v[3]]
        ctrl.jog(v, "knob")
        t[0] += ctrl.config.dt
        state = ctrl.step()
        time.sleep(0.004)
        if pending is not None and state.message == f"view {pending!r} saved":
            print("SAVED", pending, flush=True)
            n_saved += 1
            pending = None
        cycle += 1
    """
)
CHILD_TIMEOUT_S = 300.0
"""The child is killed after this long whatever it printed (the test then fails, never hangs)."""


@pytest.mark.slow
def test_kill_9_mid_procedure_then_restart(tmp_path: Path) -> None:
    path = tmp_path / "session.icenav"
    proc = subprocess.Popen(
        [sys.executable, "-c", SCRIPT, str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    saved: list[str] = []
    watchdog = threading.Timer(CHILD_TIMEOUT_S, proc.kill)
    watchdog.start()
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # blocks on the child's output: no sleep, no timing
            if line.startswith("SAVED "):
                saved.append(line.split()[1])
            if len(saved) == 4:
                break
    finally:
        watchdog.cancel()
        proc.send_signal(signal.SIGKILL)
        _, err = proc.communicate(timeout=30)  # reaps the child and closes the pipes
    assert proc.returncode == -signal.SIGKILL
    assert saved == ["v0", "v1", "v2", "v3"], err

    # the file opens, passes SQLite's integrity check, and holds every view saved before the kill
    with SessionStore(path, read_only=True) as store:
        check = store._db.execute("PRAGMA integrity_check").fetchone()[0]  # noqa: SLF001
        assert check == "ok"
        views = store.load_views()
        rm = store.load_roadmap()
    names = [v.name for v in views]
    assert names[:4] == saved
    for view in views:
        np.testing.assert_allclose(rm.vertices()[view.vertex], view.q)
    n_old_trace = rm.n_trace
    last_old = int(rm.trace()[-1])
    q_last_old = rm.vertices()[last_old]

    # restart on the same file: the twin starts at q = 0, far from where the old trace ended
    t = [0.0]
    session = make_sim_controller(imaging=False, session=path, clock=lambda: t[0])
    try:
        ctrl = session.controller
        assert [v.name for v in ctrl.views] == names
        q_start = ctrl.snapshot().q_motor
        assert np.max(np.abs(q_start - q_last_old)) > 0.1
        for _ in range(50):
            ctrl.jog([0.1, 0.0, 0.0, 0.5], "knob")
            t[0] += ctrl.config.dt
            ctrl.step()
        new_trace = ctrl.roadmap.trace(n_old_trace)
        first_new = int(new_trace[0])
        uv, _ = ctrl.roadmap.edges()
        pairs = {(min(a, b), max(a, b)) for a, b in uv.tolist()}
        # no edge claims the robot travelled from the old end to the new start
        assert (min(last_old, first_new), max(last_old, first_new)) not in pairs
        # and a view saved before the kill can be planned to from here only if connected
        ctrl.goto_view(names[0])
        t[0] += ctrl.config.dt
        state = ctrl.step()
        assert state.mode.value == "goto_view" or "cannot go to" in state.message
    finally:
        session.close()
    with SessionStore(path, read_only=True) as store:
        assert [v.name for v in store.load_views()] == names
        assert store.load_roadmap().n_trace == ctrl.roadmap.n_trace

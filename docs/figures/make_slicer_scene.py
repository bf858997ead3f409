"""docs/figures/slicer_scene.png: the scene the OpenIGTLink stream of ``icenav serve`` builds,
drawn from what a real pyigtl client receives -- NOT a 3D Slicer screenshot (Slicer cannot run
on the development machine).

What it does (about 30 s):

1. a session of the twin (catheter seed 101) with one saved view, ``septum`` (the catheter
   bent and rolled), made with the controller as the console would;
2. ``icenav serve --session ... --igtl-port 0 --igtl-commands go_to_view`` in its own process;
3. a pyigtl client (the library Slicer's Python uses) connects, sends ``go_to_view septum`` on
   ``IcenavCommand`` and keeps every ``TipToBase`` and the last ``Image`` until the command's
   reply ``done`` arrives on ``IcenavCommandAck``;
4. draws, in the robot base frame (Slicer's world with ``examples/slicer/icenav.mrml``): the
   received tip positions (the path to the view), the tip frame of the last ``TipToBase`` (x:
   imaging direction, z: catheter axis), the last ``Image`` placed by its own ``ijk2base``
   matrix, and the catheter's bending section as the model's arc through the received tip pose
   (``icenav.geometry.kinematics``: the stream carries poses, not the shape).

Run: ``.venv/bin/python docs/figures/make_slicer_scene.py``.
"""

from __future__ import annotations

import math
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyigtl

from icenav.apps.wiring import make_sim_controller
from icenav.geometry.kinematics import backbone, inverse

OUT = Path(__file__).parent / "slicer_scene.png"
VIEW = "septum"
TIMEOUT_S = 120.0


def make_session(path: Path) -> None:
    """A session with view VIEW saved at a bent, rolled, advanced state."""
    s = make_sim_controller(seed=101, session=path, imaging=True)
    try:
        ctrl = s.controller
        for _ in range(150):  # knobs, roll and translation, as the operator would jog them
            ctrl.jog([0.35, 0.15, 0.4, 2.0], "knob")
            ctrl.step()
        ctrl.run_cycles(30)
        ctrl.render_image()
        ticket = ctrl.save_view(VIEW)
        ctrl.run_until(lambda _: ticket.finished, 4000)
        assert ticket.final(0).outcome.value == "done", ticket.final(0).reason
    finally:
        s.close()


def start_serve(session: Path) -> tuple[subprocess.Popen[str], int]:
    argv = [sys.executable, "-m", "icenav.apps.cli", "serve", "--seed", "101"]
    argv += ["--session", str(session), "--igtl-port", "0", "--no-gamepad"]
    argv += ["--igtl-commands", "go_to_view", "--duration", str(TIMEOUT_S)]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    for line in proc.stdout:
        print(line.rstrip())
        m = re.search(r"OpenIGTLink on 127\.0\.0\.1:(\d+)", line)
        if m:
            return proc, int(m.group(1))
    raise RuntimeError(f"serve printed no address: {proc.communicate()[1]}")


def receive(port: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Tip poses received (4, 4) in order, and the last image (H, W) with its ijk2base."""
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
    poses: list[np.ndarray] = []
    stamps: set[float] = set()
    image = ijk2base = None
    t_end = time.monotonic() + TIMEOUT_S
    client.wait_for_message("TipToBase", timeout=30)
    client.send_message(pyigtl.StringMessage(f"go_to_view {VIEW}", device_name="IcenavCommand"))
    done = False
    still_since = time.monotonic()
    while time.monotonic() < t_end and not done:
        # pyigtl keeps the latest message per device: poll faster than serve sends (50 Hz)
        for msg in client.get_latest_messages():
            if msg.device_name == "TipToBase" and msg.timestamp not in stamps:
                stamps.add(msg.timestamp)
                pose = np.array(msg.matrix, dtype=np.float64)
                if poses and np.max(np.abs(pose[:3, 3] - poses[-1][:3, 3])) > 1e-3:
                    still_since = time.monotonic()
                poses.append(pose)
            elif msg.device_name == "Image":
                image = np.asarray(msg.image)[0]  # one slice: (H, W)
                ijk2base = np.array(msg.ijk_to_world_matrix, dtype=np.float64)
            elif msg.device_name == "IcenavCommandAck":
                print("reply:", msg.string)
                done = msg.string.startswith(("done", "failed", "refused"))
        # at the view: the tip has not moved for 3 s (and an image of it has arrived)
        done = done or (len(poses) > 100 and time.monotonic() - still_since > 3.0)
        time.sleep(0.005)
    client.stop()
    if image is None or ijk2base is None or not poses:
        raise RuntimeError("no pose or image received")
    return poses, image, ijk2base


def draw(poses: list[np.ndarray], image: np.ndarray, ijk2base: np.ndarray) -> None:
    tip = poses[-1]
    q = inverse(tip)
    bb = backbone(q, n=60)
    path = np.array([p[:3, 3] for p in poses])
    fig = plt.figure(figsize=(8.5, 7.5))
    ax = fig.add_subplot(projection="3d")
    # the image plane, placed by its own ijk2base (every 4th pixel, grey levels)
    h, w = image.shape
    step = 4
    jj, ii = np.mgrid[0:h:step, 0:w:step]
    pts = ijk2base @ np.stack([ii.ravel(), jj.ravel(), np.zeros(ii.size), np.ones(ii.size)])
    x, y, z = (pts[k].reshape(ii.shape) for k in range(3))
    grey = image[::step, ::step].astype(float) / 255.0
    rgba = plt.cm.gray(grey)
    rgba[..., 3] = 0.08 + 0.9 * grey  # black (no echo) nearly transparent, as a slice in 3D
    ax.plot_surface(x, y, z, facecolors=rgba, rstride=1, cstride=1, shade=False, linewidth=0)
    # the catheter: the shaft (straight, to the base of the bending section) and the arc
    shaft_start = bb.points_in_base[0] - np.array([0.0, 0.0, 40.0])
    shaft = np.vstack([shaft_start, bb.points_in_base[0]])
    ax.plot(*shaft.T, color="0.3", linewidth=4)
    ax.plot(*bb.points_in_base.T, color="tab:orange", linewidth=5, label="bending section")
    ax.plot(*path.T, color="tab:purple", linewidth=1.2, label="TipToBase received")
    o = tip[:3, 3]
    for k, (colour, name) in enumerate(
        (("tab:red", "x: imaging"), ("tab:green", "y"), ("tab:blue", "z: catheter axis"))
    ):
        d = tip[:3, k] * 30.0
        ax.quiver(*o, *d, color=colour, linewidth=2, label=f"tip frame {name}")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    allp = np.vstack([x.ravel(), y.ravel(), z.ravel()]).T
    allp = np.vstack([allp, shaft, path])
    c = 0.5 * (allp.max(axis=0) + allp.min(axis=0))
    r = 0.5 * float(np.max(allp.max(axis=0) - allp.min(axis=0)))
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(elev=22, azim=-58)
    ax.legend(loc="upper left", fontsize=8)
    deg = [math.degrees(v) for v in q[:3]]
    ax.set_title(
        "The scene the icenav serve stream builds (drawn from a pyigtl client;\n"
        f"not a 3D Slicer screenshot): {len(poses)} TipToBase to view '{VIEW}', the last "
        f"Image in place\nq = ({deg[0]:.0f}, {deg[1]:.0f}, {deg[2]:.0f} deg, {q[3]:.1f} mm)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "scene.sqlite"
        make_session(session)
        proc, port = start_serve(session)
        try:
            poses, image, ijk2base = receive(port)
        finally:
            proc.send_signal(signal.SIGTERM)
            out, err = proc.communicate(timeout=60)
            print(out.strip())
    draw(poses, image, ijk2base)


if __name__ == "__main__":
    main()

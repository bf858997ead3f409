"""docs/figures/kinematics_bends.png: the catheter bent in a few configurations."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from icenav.geometry.kinematics import backbone

OUT = Path(__file__).parent / "kinematics_bends.png"

configs = [
    ((0, 0, 0, 0), "q = 0 (straight)"),
    ((45, 0, 0, 0), "phi1 = 45 deg (AP)"),
    ((90, 0, 0, 0), "phi1 = 90 deg (AP)"),
    ((0, 60, 0, 0), "phi2 = 60 deg (RL)"),
    ((60, 60, 0, 0), "phi1 = phi2 = 60 deg"),
    ((60, 0, 90, 10), "phi1 = 60, phi3 = 90 deg, d4 = 10 mm"),
]

fig = plt.figure(figsize=(8, 6.5))
ax = fig.add_subplot(projection="3d")
for (p1, p2, p3, d4), label in configs:
    q = np.array([np.radians(p1), np.radians(p2), np.radians(p3), d4])
    bb = backbone(q, n=60)
    pts = bb.points_in_base
    (line,) = ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], lw=3, label=label)
    tip = bb.tip2base
    end = pts[-1]
    ax.plot(*np.column_stack([end, tip[:3, 3]]), color=line.get_color(), lw=1.5, ls="--")
    o = tip[:3, 3]
    for axis, color in ((0, "r"), (2, "b")):
        d = tip[:3, axis] * 12
        ax.quiver(o[0], o[1], o[2], d[0], d[1], d[2], color=color, lw=1.5)
ax.set_xlabel("x (mm)")
ax.set_ylabel("y (mm)")
ax.set_zlabel("z (mm)")
ax.set_title(
    "Constant-curvature model: bending section (solid), T_US (dashed),\n"
    "image facing direction x_tip (red) and catheter axis z_tip (blue)"
)
ax.set_box_aspect((1, 1, 1))
ax.set_xlim(-40, 60)
ax.set_ylim(-50, 50)
ax.set_zlim(0, 100)
ax.view_init(elev=20, azim=-60)
ax.legend(loc="upper left", fontsize=8)
fig.tight_layout()
fig.savefig(OUT, dpi=110)
print(f"wrote {OUT}")

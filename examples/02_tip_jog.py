"""02: the paper's "intuitive" control: jog the tip in its own frame.

Pushes the image centre 10 mm along the image facing direction (tip x) in 1 s of 100 Hz
control cycles and prints where it went. Run: .venv/bin/python examples/02_tip_jog.py
"""

import numpy as np

from icenav import forward, tip_jog

q = np.array([np.radians(30.0), 0.0, 0.0, 0.0])
start = forward(q)
dt = 0.01
for _ in range(100):
    twist_tip = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # 10 mm/s along tip x
    q = q + tip_jog(q, twist_tip, dt=dt) * dt

moved_in_tip = start[:3, :3].T @ (forward(q)[:3, 3] - start[:3, 3])
print("tip displacement in the starting tip frame (mm):", np.round(moved_in_tip, 2))
print("joint state now (deg, deg, deg, mm):", np.round([*np.degrees(q[:3]), q[3]], 2))

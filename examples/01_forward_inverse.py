"""01: forward and inverse kinematics of the constant-curvature model.

Bends the catheter with the anterior-posterior knob, rolls it, and recovers the joint state
from the tip pose. Run: .venv/bin/python examples/01_forward_inverse.py
"""

import numpy as np

from icenav import CatheterGeometry, forward, inverse

geometry = CatheterGeometry()  # L = 60 mm, knobs +-90 deg, image centre 10 mm past the bend
q = np.array([np.radians(40.0), np.radians(-20.0), np.radians(30.0), 5.0])  # rad, rad, rad, mm

tip2base = forward(q, geometry)
print("image centre in the base frame (mm):", np.round(tip2base[:3, 3], 2))
print("image facing direction (tip x axis):", np.round(tip2base[:3, 0], 3))

q_back = inverse(tip2base, geometry)
print(
    "joint state recovered (deg, deg, deg, mm):", np.round([*np.degrees(q_back[:3]), q_back[3]], 3)
)
assert np.allclose(q_back, q)

"""04: automated view recovery on the twin: record, save a view, wander, go back.

Drives the simulated robot with a scripted operator, records every state into the roadmap
(Algorithm 1), saves a view, explores, then plans back along visited states and executes
the path. Run: .venv/bin/python examples/04_view_recovery.py
"""

import numpy as np

from icenav import Roadmap
from icenav.devices import SimulatedRobot
from icenav.sim import CatheterPlant
from icenav.sim.operator import ScriptedOperator, drive

plant = CatheterPlant(seed=111)
robot = SimulatedRobot(plant)
robot.enable()
roadmap = Roadmap(epsilon=1.0)  # 1 mm == 1 deg
operator = ScriptedOperator(np.zeros(4), seed=1)

drive(operator.move_to([0.5, -0.3, 0.4, 5.0]), robot, roadmap)
view = roadmap.make_view("aortic valve", created_s=0.0)
view_tip = plant.state.tip2base[:3, 3].copy()
drive(operator.explore(6), robot, roadmap)
print(f"roadmap: {roadmap.n_vertices} states, {roadmap.n_edges} edges")

path = roadmap.plan(robot.read_state().q, view, approach=True)
for q in path:  # every step is within epsilon or along a travelled edge
    robot.command_position(q)
error = np.linalg.norm(plant.state.tip2base[:3, 3] - view_tip)
print(f"returned along {len(path)} recorded states; true tip {error:.2f} mm from the saved view")

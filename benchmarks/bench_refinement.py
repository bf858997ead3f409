"""Time of one closed-loop view refinement on the twin, and its parts.

A refinement's cost is dominated by rendering one beat per evaluation; the robot moves and
the scoring are small. Reported: one beat rendered (5 frames at 128 px, the evaluation's
settings), one score against 4 reference beats, and a whole refinement (hysteretic plant,
moderate vessel, return perturbed by 2 deg / 0.5 mm, the at-view gate off so the search
runs) in wall time and in controller time; and one EM pose stage (the stage before the
image search: the play of roll, distal twist and translation put on the other side, about
20 deg / several mm off) in wall time, controller time and EM measurements.
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Result, time_per_call
from icenav.devices.sim_robot import SimulatedRobot
from icenav.refinement.image_search import (
    RefinementConfig,
    RefinementTask,
    refine,
)
from icenav.refinement.pose_stage import pose_stage
from icenav.sim.anatomy import EXAMPLE_VIEWS, default_phantom
from icenav.sim.beat_imager import SimClock, SimulatedBeatImager
from icenav.sim.plant import CatheterPlant
from icenav.sim.tracker import EMTracker
from icenav.sim.ultrasound import ProbeConfig, UltrasoundRenderer


def main() -> list[Result]:
    renderer = UltrasoundRenderer(
        default_phantom(), ProbeConfig(image_size=128, n_beams=64, n_samples=192, seed=100)
    )
    clock = SimClock()
    plant = CatheterPlant(seed=100, vessel="moderate")
    robot = SimulatedRobot(plant, clock=clock.now)
    robot.enable()
    imager = SimulatedBeatImager(plant, renderer, clock.now, frames_per_beat=5)
    q_view = np.array(EXAMPLE_VIEWS["mitral_valve"])
    plant.reset(q_view)
    robot.command_position(q_view)
    refs = []
    for _ in range(4):
        clock.advance(imager.beat_duration_s)
        refs.append(imager.acquire_beat())
    task = RefinementTask(q_view, refs, imager)
    clip = imager.acquire_beat()
    results = [
        Result("refinement: render one beat (5 frames, 128 px)",
               time_per_call(imager.acquire_beat, repeat=3), "s"),
        Result("refinement: score one beat against 4 saved beats",
               time_per_call(lambda: task.score(clip), repeat=3), "s"),
    ]  # fmt: skip
    times, ctrl, evals = [], [], []
    deg = math.pi / 180
    for k in range(3):
        offset = np.array([2 * deg, -2 * deg, 2 * deg, 0.5]) * (1 if k % 2 == 0 else -1)
        robot.command_position(q_view + offset)
        t0 = time.perf_counter()
        res = refine(robot, q_view, refs, imager, config=RefinementConfig(stop_within=0.0),
                     sleep=clock.advance)  # fmt: skip
        times.append(time.perf_counter() - t0)
        ctrl.append(res.duration_s)
        evals.append(len(res.trials))
        robot.command_position(q_view)
    results += [
        Result("refinement: one refinement, wall time (24-beat budget), median of 3",
               float(np.median(times)), "s"),
        Result("refinement: one refinement, controller time", float(np.median(ctrl)), "s"),
        Result("refinement: one refinement, beats measured", float(np.median(evals)), "beats"),
    ]  # fmt: skip
    results += _pose_stage_results()
    return results


def _pose_stage_results() -> list[Result]:
    deg = math.pi / 180
    wall, ctrl, meas = [], [], []
    for seed in (110, 111, 112):
        clock = SimClock()
        plant = CatheterPlant(seed=seed, vessel="moderate")
        robot = SimulatedRobot(plant, clock=clock.now)
        robot.enable()
        tracker = EMTracker(plant, seed=seed, clock=clock.now)
        q_view = np.array(EXAMPLE_VIEWS["aortic_valve"])
        below = np.array([16 * deg, 16 * deg, 30 * deg, 3.0])
        plant.move(q_view - below)
        robot.command_position(q_view)
        saved = tracker.measure_tip2base(n_average=64)
        assert saved is not None
        plant.move(q_view + below * np.array([-1, -1, 1, 1]))
        robot.command_position(q_view)
        t0 = time.perf_counter()
        res = pose_stage(robot, q_view, saved, tracker, arrival_direction=(1, 1, 1, 1),
                         start_direction=(1, 1, -1, -1), sleep=clock.advance)  # fmt: skip
        wall.append(time.perf_counter() - t0)
        ctrl.append(res.duration_s)
        meas.append(len(res.measurements))
    return [
        Result("refinement: one EM pose stage, wall time, median of 3",
               float(np.median(wall)), "s"),
        Result("refinement: one EM pose stage, controller time", float(np.median(ctrl)), "s"),
        Result("refinement: one EM pose stage, EM measurements (64 samples each)",
               float(np.median(meas)), "measurements"),
    ]  # fmt: skip


if __name__ == "__main__":
    for r in main():
        print(r)

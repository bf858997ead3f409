"""Tests of icenav.refinement.task: both refinement stages as one controller task."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from icenav.refinement.image_search import RefinementConfig, RefinementStatus
from icenav.refinement.pose_stage import PoseStageConfig, PoseStageStatus
from icenav.refinement.task import ViewRefinementTask
from icenav.sim.anatomy import EXAMPLE_VIEWS
from tests.support.refinement import BlobImager, em_bench, reference, true_error

Array = NDArray[np.float64]
DEG = math.pi / 180


def test_view_refinement_task_runs_the_pose_stage_then_the_image_stage() -> None:
    """One controller task: the EM pose stage fixes the play error, then the image stage
    starts where it ended (here it finds the image at its optimum and stays); the
    set-points stay in the pose stage's box plus the image stage's box around its start,
    and progress runs from 0 to 1."""
    clock, plant, robot, tracker = em_bench(117)
    q_view = np.array(EXAMPLE_VIEWS["aortic_valve"])
    below = np.array([16 * DEG, 16 * DEG, 30 * DEG, 3.0])
    plant.move(q_view - below)
    robot.command_position(q_view)
    saved_true = plant.state.tip2base.copy()
    saved = tracker.measure_tip2base(n_average=64)
    assert saved is not None
    plant.move(q_view + below * np.array([-1, -1, 1, 1]))
    robot.command_position(q_view)
    d0, a0 = true_error(plant, saved_true)
    imager = BlobImager(robot, q_view, noise=0.0, seed=0)
    ref = reference(imager)
    task = ViewRefinementTask(q_view, saved, tracker, [ref, ref], imager,
                              arrival_direction=(1, 1, 1, 1),
                              start_direction=(1, 1, -1, -1))  # fmt: skip
    assert task.progress == 0.0
    sent, progress = [], []
    while True:
        cmd = task.next_command(np.asarray(robot.read_state().q), 0.01)
        if cmd is None:
            break
        robot.command_position(cmd)
        sent.append(cmd)
        progress.append(task.progress)
        clock.advance(0.01)
    pose_res, image_res = task.result()
    assert pose_res.status in (PoseStageStatus.CONVERGED, PoseStageStatus.STALLED)
    assert image_res is not None and image_res.status == RefinementStatus.AT_VIEW
    d1, a1 = true_error(plant, saved_true)
    assert d1 < 0.3 and a1 < 0.3 and (d1 < d0 or a1 < a0)
    assert task.progress == 1.0 and max(progress) <= 1.0
    box = np.array(PoseStageConfig().radius) + np.array(RefinementConfig().radius)
    assert all(np.all(np.abs(q - q_view) <= box + 1e-12) for q in sent)
    assert task.next_command(q_view, 0.01) is None


def test_view_refinement_task_abort_ends_both_stages() -> None:
    clock, plant, robot, tracker = em_bench(118)
    q_view = np.array(EXAMPLE_VIEWS["mitral_valve"])
    robot.command_position(q_view)
    far = np.eye(4)
    far[:3, 3] = 1000.0
    imager = BlobImager(robot, q_view, noise=0.0, seed=0)
    task = ViewRefinementTask(q_view, far, tracker, reference(imager), imager,
                              abort=lambda: clock.now() > 1.0)  # fmt: skip
    n = 0
    while task.next_command(np.asarray(robot.read_state().q), 0.01) is not None:
        n += 1
        clock.advance(0.01)
    pose_res, image_res = task.result()
    assert pose_res.status == PoseStageStatus.ABORTED and image_res is None
    assert n <= 101

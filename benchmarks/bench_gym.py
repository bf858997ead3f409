"""Gymnasium environments: steps per second of icenav/ViewFinding-v0 at 64 x 64 on one core.

A random policy (seeded) steps the environment, resetting when an episode ends (resets
included, as in a rollout). Baselines, measured in the same run on the same catheter: the
plant's ``move`` alone over the same kind of increments, and the renderer alone at 64 x 64
(what one step must do at least). Target (issue 20): >= 100 steps/s at 64 x 64 on one core.
Wall time (best of repeats) and the process's CPU time are both reported: on a shared
machine the CPU time is the per-core cost. ``icenav/Spin-v0`` is reported beside it.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.common import Result, time_per_call  # noqa: E402
from icenav.gym import SpinEnv, ViewFindingEnv  # noqa: E402
from icenav.sim import CatheterPlant  # noqa: E402
from icenav.sim.anatomy import EXAMPLE_VIEWS, tip2anatomy  # noqa: E402
from icenav.sim.ultrasound import UltrasoundRenderer  # noqa: E402

TARGET_STEPS_PER_S = 100.0


def _cpu_seconds(fn: Callable[[], object], n: int) -> float:
    c0 = time.process_time()
    for _ in range(n):
        fn()
    return (time.process_time() - c0) / n


def _stepper(env: ViewFindingEnv | SpinEnv, seed: int) -> Callable[[], None]:
    env.reset(seed=seed)
    env.action_space.seed(seed)

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()

    return step


def main() -> list[Result]:
    env = ViewFindingEnv(image_size=64)
    step = _stepper(env, 0)
    step_s = time_per_call(step, min_time=1.0, repeat=3)
    step_cpu = _cpu_seconds(step, 300)
    # baselines on the same machine, same run
    plant = CatheterPlant(seed=1000)
    rng = np.random.default_rng(0)
    inc = np.asarray(env.config.max_increment)
    low, high = env.q_low, env.q_high
    q = [np.zeros(4)]

    def move() -> None:
        q[0] = np.clip(q[0] + rng.uniform(-1.0, 1.0, 4) * inc, low, high)
        plant.move(q[0])

    move_s = time_per_call(move, min_time=0.5, repeat=3)
    renderer = UltrasoundRenderer(config=env.config.probe())
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS["aortic_valve"]))
    t = [0.0]

    def render() -> None:
        t[0] += 1.0 / 30.0
        renderer.render(pose, t[0], check=False)

    render_s = time_per_call(render, min_time=0.5, repeat=3)
    spin_step = _stepper(SpinEnv(), 0)
    spin_s = time_per_call(spin_step, min_time=0.5, repeat=3)
    return [
        Result(
            "ViewFinding-v0 step at 64x64 (random policy, resets included)",
            step_s * 1e3,
            "ms/step",
            baseline=render_s * 1e3,
            baseline_name="the renderer alone, one 64x64 frame",
            target=f">= {TARGET_STEPS_PER_S:.0f} steps/s",
            met=1.0 / step_s >= TARGET_STEPS_PER_S,
        ),
        Result(
            "ViewFinding-v0 step, against the plant's move alone",
            step_s * 1e3,
            "ms/step",
            baseline=move_s * 1e3,
            baseline_name="CatheterPlant.move of one increment",
        ),
        Result("ViewFinding-v0 steps per second (wall)", 1.0 / step_s, "steps/s"),
        Result(
            "ViewFinding-v0 steps per second (CPU time of one core)",
            1.0 / step_cpu,
            "steps/s",
            target=f">= {TARGET_STEPS_PER_S:.0f} steps/s",
            met=1.0 / step_cpu >= TARGET_STEPS_PER_S,
        ),
        Result("Spin-v0 steps per second (wall)", 1.0 / spin_s, "steps/s"),
    ]


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())

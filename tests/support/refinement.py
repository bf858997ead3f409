"""Shared helpers of the refinement tests: a cheap synthetic imager, an ideal tracked plant
and an EM bench on the twin (tests never import each other)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from icenav.devices.sim_robot import SimulatedRobot
from icenav.eval.metrics import rotation_angle
from icenav.geometry.kinematics import forward
from icenav.recovery.beats import BeatClip
from icenav.sim.beat_imager import SimClock
from icenav.sim.plant import CatheterPlant
from icenav.sim.tracker import EMTracker

Array = NDArray[np.float64]
DEG = math.pi / 180


class BlobImager:
    """Cheap synthetic imager: a Gaussian blob whose place and size follow the commanded
    motor state, plus seeded noise (so the search sees a smooth but noisy landscape)."""

    def __init__(self, robot: SimulatedRobot, q_best: Array, noise: float, seed: int) -> None:
        self.robot = robot
        self.q_best = np.asarray(q_best, np.float64)
        self.noise = noise
        self.rng = np.random.default_rng(seed)
        y, x = np.mgrid[0:32, 0:32]
        self.yx = (y.astype(np.float64), x.astype(np.float64))
        self.calls = 0

    @property
    def beat_duration_s(self) -> float:
        return 0.5

    def image_at(self, q: Array) -> Array:
        d = (q - self.q_best) * np.array([1 / DEG, 1 / DEG, 1 / DEG, 1.0])
        cy, cx = 14 + 1.5 * d[0] + 0.3 * d[3], 14 + 1.5 * d[1] - 0.5 * d[2]
        w = 4.0 + 0.4 * d[2]
        y, x = self.yx
        blob = np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * w * w))
        dy = 24 + 1.5 * d[3]  # a second structure that only translation moves
        return blob + np.exp(-((y - dy) ** 2 + (x - 24) ** 2) / 8.0)

    def acquire_beat(self) -> BeatClip:
        self.calls += 1
        q = np.asarray(self.robot.read_state().q, np.float64)
        base = self.image_at(q)
        imgs = np.stack([base + self.rng.normal(0, self.noise, base.shape) for _ in range(3)])
        return BeatClip(imgs, np.array([0.0, 1 / 3, 2 / 3]))


def reference(imager: BlobImager) -> BeatClip:
    base = imager.image_at(imager.q_best)
    return BeatClip(np.stack([base] * 3), np.array([0.0, 1 / 3, 2 / 3]))


class TrackedPlant:
    """The ideal (model) catheter with the ``state.tip2base`` the imager reads."""

    class _State:
        tip2base: Array = np.eye(4)

    def __init__(self) -> None:
        self.state = self._State()

    def move(self, q_motor: Array) -> Array:
        self.state.tip2base = forward(np.asarray(q_motor, np.float64))
        return self.state.tip2base

    def reset(self, q_motor: Array | None = None) -> None:
        self.move(np.zeros(4) if q_motor is None else q_motor)


def em_bench(
    seed: int, vessel: str = "moderate"
) -> tuple[SimClock, CatheterPlant, SimulatedRobot, EMTracker]:
    clock = SimClock()
    plant = CatheterPlant(seed=seed, vessel=vessel)
    robot = SimulatedRobot(plant, clock=clock.now)
    robot.enable()
    tracker = EMTracker(plant, seed=seed, clock=clock.now)
    return clock, plant, robot, tracker


def true_error(plant: CatheterPlant, saved: Array) -> tuple[float, float]:
    t = plant.state.tip2base
    return (
        float(np.linalg.norm(t[:3, 3] - saved[:3, 3])),
        math.degrees(float(rotation_angle(t[:3, :3], saved[:3, :3]))),
    )


__all__ = ["BlobImager", "TrackedPlant", "em_bench", "reference", "true_error"]


class JitterBlobImager(BlobImager):
    """A :class:`BlobImager` whose every beat sees the blob at the motor state plus a
    random offset (sd ``jitter`` deg per knob / roll, mm of translation): beats that
    decorrelate as the heart's beat-to-beat position does on the twin."""

    jitter: float = 0.6

    def _jittered(self, q: Array) -> Array:
        scale = np.array([DEG, DEG, DEG, 1.0])
        out: Array = q + self.rng.normal(0.0, self.jitter, 4) * scale
        return out

    def acquire_beat(self) -> BeatClip:
        self.calls += 1
        q = np.asarray(self.robot.read_state().q, np.float64)
        return BeatClip(np.stack([self.image_at(self._jittered(q))] * 3), np.array([0, 1, 2]) / 3)

    def saved_beats(self, n: int) -> list[BeatClip]:
        """``n`` saved beats at the optimum, each with its own offset."""
        return [
            BeatClip(
                np.stack([self.image_at(self._jittered(self.q_best))] * 3), np.array([0, 1, 2]) / 3
            )  # fmt: skip
            for _ in range(n)
        ]

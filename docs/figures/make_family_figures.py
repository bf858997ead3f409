"""Figure of docs/digital-twin.md section 10 (run: python docs/figures/make_family_figures.py).

families.png, one panel per family's defining behaviour, on development catheters 200-209:
(a) AP knob loops of the default twin and the distributed-friction family, with a minor loop;
(b) rate-dependent: the bend reached at three motor speeds, then its drift after the stop;
(c) roll play against bend: default (a line) and nonlinear-play (bend x tension);
(d) field-distortion: position error at one sensor position as the sensor turns about an
axis across its coil, and as the robot's roll turns the metal.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icenav.sim import CatheterPlant, TrackerConfig  # noqa: E402
from icenav.sim.families import (  # noqa: E402
    DistributedFrictionPlant,
    FieldDistortionTracker,
    NonlinearPlayPlant,
    RateDependentPlant,
)
from icenav.sim.families.rate_dependent import DEFAULT_MOTOR_SPEED  # noqa: E402
from icenav.sim.tracker import rotvec_to_matrix  # noqa: E402

HERE = Path(__file__).parent
DEG = math.pi / 180.0


def _sweep(plant: object, knobs: np.ndarray) -> np.ndarray:
    out = []
    for k in knobs:
        plant.move([k, 0.0, 0.0, 0.0])  # type: ignore[attr-defined]
        out.append(plant.state.bend_angle * np.sign(k if k != 0 else 1.0))  # type: ignore[attr-defined]
    return np.degrees(out)


def loops(ax: plt.Axes) -> None:
    major = np.concatenate(
        [np.linspace(0, 60, 61), np.linspace(60, -60, 121), np.linspace(-60, 60, 121)]
    )
    minor = np.concatenate(
        [np.linspace(60, 20, 41), np.linspace(20, 40, 21), np.linspace(40, 20, 21)]
    )
    for plant, label, style in (
        (CatheterPlant(seed=200), "default (one sharp play)", "k-"),
        (DistributedFrictionPlant(seed=200), "distributed-friction (PI)", "C0-"),
    ):
        b = _sweep(plant, major * DEG)
        ax.plot(major[61:], b[61:], style, lw=1.2, label=label)
        m = _sweep(plant, minor * DEG)
        ax.plot(minor, m, style, lw=0.8, alpha=0.7)
    ax.set_xlabel("AP motor knob (deg)")
    ax.set_ylabel("true bend (deg, signed)")
    ax.set_title("(a) loops and a minor loop")
    ax.legend(fontsize=7)


def rate(ax: plt.Axes) -> None:
    q = np.array([0.8, 0.0, 0.0, 0.0])
    for scale, style in ((1.0, "C3-"), (0.3, "C1-"), (0.1, "C2-")):
        plant = RateDependentPlant(
            seed=200, motor_speed=np.array(DEFAULT_MOTOR_SPEED) * scale, settle_s=0.0
        )
        plant.move(q)
        t0 = plant.time
        ts = [0.0]
        bends = [math.degrees(plant.state.bend_angle)]
        for _ in range(60):
            plant.wait(0.5)
            ts.append(plant.time - t0)
            bends.append(math.degrees(plant.state.bend_angle))
        ax.plot(ts, bends, style, label=f"{30 * scale:.0f} deg/s knob")
    ax.set_xlabel("time after the move ends (s)")
    ax.set_ylabel("true bend (deg)")
    ax.set_title("(b) rate-dependent: speed and drift")
    ax.legend(fontsize=7)


def plays(ax: plt.Axes) -> None:
    for plant, label, style in (
        (CatheterPlant(seed=200), "default: h0 + h1 bend", "k.-"),
        (NonlinearPlayPlant(seed=200), "nonlinear-play: h0 + c bend sum T", "C0.-"),
    ):
        bend, play = [], []
        for k in np.linspace(0, 80, 17):
            plant.reset()
            plant.move_along(np.linspace([0, 0, 0, 0], [k * DEG, 0, 0, 0], 20))
            plant.move_along(np.linspace([k * DEG, 0, 0, 0], [k * DEG, 0, 0.6, 0], 30))
            bend.append(math.degrees(plant.state.bend_angle))
            play.append(math.degrees(0.6 - plant.state.roll))
        ax.plot(bend, play, style, label=label)
    ax.set_xlabel("true bend (deg)")
    ax.set_ylabel("roll play (deg)")
    ax.set_title("(c) roll play against bend")
    ax.legend(fontsize=7)


def tracker(ax: plt.Axes) -> None:
    t = FieldDistortionTracker(CatheterPlant(seed=200), seed=200)
    cfg = TrackerConfig()
    pose = np.linalg.inv(cfg.tracker2base) @ np.array(
        [[1, 0, 0, 20.0], [0, 1, 0, 0.0], [0, 0, 1, 60.0], [0, 0, 0, 1]]
    )
    p, r = pose[:3, 3], pose[:3, :3]
    ang = np.linspace(0, 360, 73)
    turn = [
        np.linalg.norm(t.distortion_at(p, rotvec_to_matrix(np.array([a * DEG, 0, 0])) @ r)[0])
        for a in ang
    ]
    roll = [np.linalg.norm(t.distortion_at(p, r, a * DEG)[0]) for a in ang]
    ax.plot(ang, turn, "C0-", label="sensor turned (robot roll 0)")
    ax.plot(ang, roll, "C3-", label="robot roll (sensor fixed)")
    ax.set_xlabel("angle (deg)")
    ax.set_ylabel("position error |b| (mm)")
    ax.set_title(f"(d) field-distortion at one point (lambda {t.wavelength_mm:.0f} mm)")
    ax.legend(fontsize=7)


def main() -> None:
    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    loops(axes[0, 0])
    rate(axes[0, 1])
    plays(axes[1, 0])
    tracker(axes[1, 1])
    fig.tight_layout()
    path = HERE / "families.png"
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

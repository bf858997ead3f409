"""Shared helpers of the transmission tests: a known per-tendon model, synthetic catheters
that follow it, and a spin-like two-knob path."""

from __future__ import annotations

import math

import numpy as np

from icenav.calibration.transmission import CalibrationMotion
from icenav.compensation.knob_residual import KnobResidual
from icenav.compensation.transmission import PairTransmission, TendonTransmission
from icenav.geometry.kinematics import forward

DEG = math.pi / 180


def spin_like(a: float, n: int = 200) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * math.pi, n)
    path = np.zeros((n + 20, 4))
    path[:20, 0] = np.linspace(0.0, a, 21)[1:]
    path[20:, 0] = a * np.cos(t)
    path[20:, 1] = a * np.sin(t)
    path[20:, 2] = -t
    return path


def static_map(z: np.ndarray) -> np.ndarray:
    """The synthetic catheters' static map (n, 2) -> (n, 2) of the effective knobs (rad):
    gain, cross-coupling, a cubic and a product term."""
    return np.stack(
        [
            0.9 * z[:, 0] + 0.08 * z[:, 1] - 0.1 * z[:, 0] ** 3,
            -0.05 * z[:, 0] + 1.1 * z[:, 1] + 0.06 * z[:, 0] * z[:, 1],
        ],
        axis=-1,
    )


def synthetic_catheter(
    model: TendonTransmission, rng: np.random.Generator, path: np.ndarray, noise: float
) -> CalibrationMotion:
    """Tracked model knobs of a synthetic catheter: a known static map of the effective
    knobs (gain, cross-coupling, a cubic), plus tracker noise."""
    z = model.simulate(path, x_start=[0.0, 0.0])
    y = static_map(z)
    y += rng.normal(0.0, noise, y.shape)
    y[rng.uniform(size=y.shape[0]) < 0.03] = np.nan  # MISSING samples
    return CalibrationMotion(q_motor=path, observed=y)


TRUTH = TendonTransmission(
    ap=PairTransmission(slack=1.5 * DEG, seal_play=0.8 * DEG, tension_play=0.3, coupling=-0.4),
    rl=PairTransmission(slack=2.5 * DEG, seal_play=0.5 * DEG, tension_play=0.5, coupling=0.3),
    wrap=0.4,
    friction=0.6,
)


class SyntheticCatheter:
    """A catheter whose knobs reach the bending section through a known TendonTransmission
    and whose section bends by a known static map of the effective knobs; tracked exactly."""

    def __init__(self, model: TendonTransmission) -> None:
        self.model = model
        self.reset()

    def reset(self) -> None:
        self.x = [0.0, 0.0]
        self.d = self.model.relaxed_state([0.0, 0.0]).tolist()
        self.pose = forward(np.zeros(4))

    def move(self, q: np.ndarray) -> np.ndarray:
        self.d = self.model.step(self.d, self.x, [float(q[0]), float(q[1])])
        self.x = [float(q[0]), float(q[1])]
        z1, z2 = self.model.effective(self.d)
        bend = [0.9 * z1 + 0.06 * z2 - 0.08 * z1**3, -0.04 * z1 + 1.08 * z2, q[2], q[3]]
        self.pose = forward(np.array(bend), check=False)
        return self.pose

    def measure_tip2base(self, n_average: int = 1) -> np.ndarray:
        return self.pose.copy()


def wave_residual(
    amplitude: float = 3.0 * DEG,
    radii: tuple[float, ...] = (30 * DEG, 60 * DEG),
    grow: bool = True,
) -> KnobResidual:
    """A circle residual (KnobResidual, 2 harmonics) whose AP knob lags by a wave over the
    azimuth that flips with the sense of turning (growing with the radius if ``grow``), and
    whose RL knob has a static offset: a miss no capstan band makes."""
    table = np.zeros((len(radii), 2, 5, 2))
    for c, r in enumerate(radii):
        g = r / radii[-1] if grow else 1.0
        for s, sign in enumerate((1.0, -1.0)):
            table[c, s, 2, 0] = sign * amplitude * g  # AP: sin psi, flips with the sense
            table[c, s, 3, 0] = 0.5 * amplitude * g  # AP: cos 2 psi, static
            table[c, s, 0, 1] = 0.3 * amplitude * g  # RL: offset
    return KnobResidual(radii=radii, harmonics=2, coefficients=tuple(table.ravel()))


def spin_path_motion(
    model: TendonTransmission,
    rng: np.random.Generator,
    lag: tuple[float, float],
    noise: float,
    wobble: float = 0.0,
) -> CalibrationMotion:
    """The calibration's spin circle (10-deg steps) from (50 deg, 0) on a synthetic catheter
    of ``model`` and :func:`static_map`, tracked in the base frame: the model knobs turned by
    the motor roll plus a lag (rad) of ``lag[0]`` while the roll turns up and ``lag[1]``
    while it turns down, plus ``wobble * sin(knob direction)``, plus tracker noise (rad)."""
    from icenav.calibration.twist_circle import spin_circle_path

    path = spin_circle_path(step=10 * DEG)
    start = np.array([50 * DEG, 0.0, 0.0, 0.0])
    g = static_map(model.simulate(path, x_start=start[:2]))
    up = np.diff(np.concatenate([[0.0], path[:, 2]])) > 0
    turn = path[:, 2] + np.where(up, lag[0], lag[1])
    turn += wobble * np.sin(np.arctan2(path[:, 1], path[:, 0]))
    o = (g[:, 0] + 1j * g[:, 1]) * np.exp(1j * turn)
    y = np.stack([o.real, o.imag], axis=-1) + rng.normal(0.0, noise, g.shape)
    return CalibrationMotion(q_motor=path, observed=y, q_start=start)

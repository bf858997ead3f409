"""The paper's image-spinning test on the twin, and the elastic oracle used to tune the twin.

These are the checks behind the twin's calibration (docs/digital-twin.md, "Calibration"):

- :func:`spin_trajectory`: phi1 = a cos t, phi2 = a sin t, phi3 = -t, d4 = 0 (360 samples);
  the constant-curvature model keeps the tip position fixed while the image plane turns.
- :func:`spin_errors`: position RMSE (mm) between the measured and the intended tip position
  (the model position at the start), and rotation RMSE (deg): the angle of the rotation
  between the intended orientation ``forward(q_t)`` (which includes the intended roll of the
  image plane) and the measured one.
- :func:`elastic_oracle`: the motor knobs that the plant's own hysteresis-free, slack-free
  elastic response maps onto the model tip: a perfect *elastic* compensation. What it leaves
  is the dead-zone, the hysteresis, the roll play and (when tracked) the tracker error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from icenav._typing import Array
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward
from icenav.geometry.se3 import rotation_angle
from icenav.sim.params import PlantParams
from icenav.sim.plant import CatheterPlant
from icenav.sim.tracker import EMTracker

__all__ = [
    "SpinErrors",
    "SpinRun",
    "elastic_oracle",
    "run_spin",
    "spin_errors",
    "spin_trajectory",
]


@dataclass(frozen=True)
class SpinErrors:
    """RMSE of one spin against the intended pose."""

    position_rmse_mm: float
    """Root-mean-square distance between measured and intended tip position (mm)."""
    rotation_rmse_deg: float
    """Root-mean-square angle between measured and intended orientation (deg)."""


def spin_trajectory(bend_rad: float, n: int = 360) -> Array:
    """Model joint states of the paper's spin from an AP bend ``bend_rad``: shape (n, 4).

    t runs from 0 to 2 pi inclusive over ``n`` samples: phi1 = a cos t, phi2 = a sin t,
    phi3 = -t, d4 = 0 (model knob angles equal the bend with the default geometry).
    """
    t = np.linspace(0.0, 2.0 * math.pi, int(n))
    a = float(bend_rad)
    return np.stack([a * np.cos(t), a * np.sin(t), -t, np.zeros_like(t)], axis=-1)


def spin_errors(
    measured_tip2base: Array,
    q_model: Array,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> SpinErrors:
    """Errors of a spin, the paper's protocol (intended pose = model pose).

    Parameters
    ----------
    measured_tip2base : ndarray, shape (n, 4, 4)
        Measured (tracked or true) tip poses (mm, base frame); rows may be NaN (missing
        samples), which are skipped.
    q_model : ndarray, shape (n, 4)
        The model joint states of the spin; the intended position is the model position at
        the first sample, the intended orientation ``forward(q_model[i])``.
    """
    intended = forward(q_model, geometry, check=False)
    ok = np.all(np.isfinite(measured_tip2base.reshape(len(q_model), -1)), axis=1)
    m = measured_tip2base[ok]
    p0 = intended[0, :3, 3]
    pos = np.linalg.norm(m[:, :3, 3] - p0, axis=-1)
    rot = rotation_angle(intended[ok, :3, :3], m[:, :3, :3])
    return SpinErrors(
        position_rmse_mm=float(np.sqrt(np.mean(pos**2))),
        rotation_rmse_deg=float(np.degrees(np.sqrt(np.mean(rot**2)))),
    )


def _elastic_plant(params: PlantParams, geometry: CatheterGeometry) -> CatheterPlant:
    return CatheterPlant(params=params.elastic_only(), geometry=geometry)


def elastic_oracle(
    params: PlantParams,
    q_model: Array,
    geometry: CatheterGeometry = DEFAULT_GEOMETRY,
) -> Array:
    """Motor joint states that a perfect elastic compensation would command: shape (n, 4).

    For each model knob pair, solves for the motor knob pair whose elastic response (no slack,
    no friction; roll 0, d4 0) puts the image centre where the model puts it
    (least squares on the 3-D image-centre position, warm-started along the path). Roll and
    translation are passed through unchanged, as in the paper's compensation.
    """
    plant = _elastic_plant(params, geometry)
    out = np.array(q_model, dtype=np.float64, copy=True)
    lim = geometry.knob_limit
    guess = np.array(out[0, :2])
    for i, row in enumerate(np.asarray(q_model)):
        target = forward(np.array([row[0], row[1], 0.0, 0.0]), geometry, check=False)[:3, 3]

        def resid(x: Array, target: Array = target) -> Array:
            plant.reset(np.array([x[0], x[1], 0.0, 0.0]))
            return plant.state.tip2base[:3, 3] - target

        sol = least_squares(resid, guess, bounds=([-lim, -lim], [lim, lim]), xtol=1e-10)
        out[i, :2] = sol.x
        guess = sol.x
    return out


@dataclass(frozen=True)
class SpinRun:
    """One spin on the twin."""

    q_model: Array
    """(n, 4) model joint states (the intended trajectory)."""
    q_motor: Array
    """(n, 4) motor joint states commanded."""
    true_tip2base: Array
    """(n, 4, 4) true tip poses after each move (mm, base frame)."""
    tracked_tip2base: Array | None
    """(n, 4, 4) EM-tracked tip poses (NaN where the sample was missing), or None."""


def run_spin(
    plant: CatheterPlant,
    bend_rad: float,
    q_motor: Array | None = None,
    n: int = 360,
    tracker: EMTracker | None = None,
) -> SpinRun:
    """Run the spin on ``plant`` from a relaxed start.

    The plant is reset at zero and driven to the first motor state before the spin, as a
    robot would be. ``q_motor`` (e.g. from :func:`elastic_oracle`) defaults to the model
    states (no compensation). With a ``tracker``, each sample is also measured with
    ``tracker.measure_tip2base(1)`` (one EM sample per pose, as in the paper).
    """
    q_model = spin_trajectory(bend_rad, n)
    cmd = q_model if q_motor is None else np.asarray(q_motor, dtype=np.float64)
    plant.reset()
    plant.move(cmd[0])
    if tracker is None:
        return SpinRun(q_model, cmd, plant.move_along(cmd), None)
    true = np.empty((len(cmd), 4, 4))
    tracked = np.full((len(cmd), 4, 4), np.nan)
    for i, q in enumerate(cmd):
        true[i] = plant.move(q)
        meas = tracker.measure_tip2base(1)
        if meas is not None:
            tracked[i] = meas
    return SpinRun(q_model, cmd, true, tracked)

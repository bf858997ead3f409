"""The EM tracker's field bias in the *base* frame, separated from the catheter's elasticity by
rolling the catheter (beyond the paper).

Why: the map F (:mod:`icenav.compensation.elasticity`) is built from EM-tracked tips in the
*knob* frame (each sample's roll removed). A tracker measures ``m = p + b(p)``: the true tip
plus a smooth field distortion ``b`` that belongs to the *base* (tracker) frame (1-2 mm over a
catheter's workspace for an NDI 3D Guidance field). The raster is driven at roll 0, so F
learns ``b`` as if it were part of the bend, and when the spin turns the roll by ``r`` the
correction turns with it: the true tip orbits the model tip on a circle of radius ``|b_xy|``
and the tracker sees up to twice that (docs/calibration.md, section 4d).

What: an affine estimate ``b(x) = b0 + B x`` (base frame, mm), with an optional quadratic
term ``Q u(x - c)`` (Eq. TB2: the six monomials of the offset from a centre ``c``), fitted from
roll circles by :mod:`icenav.calibration.tracker_bias` (Eq. TB1 there; the quadratic term is
kept per catheter only where held-out roll circles say it predicts better).

Use (:class:`TrackerBias`):

- :meth:`TrackerBias.correct_calibration`: remove ``b`` from tracked calibration poses
  (solve ``p + b(p) = m``), so F becomes a pure knob-frame (elastic) map;
- :meth:`TrackerBias.shift_model_path`: for a model path, the model knobs whose model tip is
  ``p - b(p)`` (base frame, same roll and translation), so that the *tracked* tip lands on
  the intended tip: the consistent choice for a system registered through this tracker (the
  paper's protocol measures with it). The true tip then stands still at ``-b`` from the
  intended one instead of orbiting it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite
from icenav.compensation.elasticity import CalibrationSet
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry, forward

__all__ = [
    "TrackerBias",
    "quadratic_terms",
]


def quadratic_terms(u: ArrayLike) -> Array:
    """The six quadratic monomials (..., 6) of offsets u (..., 3) (mm):
    ``(ux^2, ux uy, ux uz, uy^2, uy uz, uz^2)`` (mm^2)."""
    v = np.asarray(u, dtype=np.float64)
    i, j = np.triu_indices(3)
    return np.asarray(v[..., i] * v[..., j], dtype=np.float64)


@dataclass(frozen=True)
class TrackerBias:
    """An estimate of the tracker's field bias in the base frame (Eq. TB2)::

        b(x) = b0 + B x + Q u(x - c)                                        # (TB2)

    with ``u`` the six quadratic monomials (:func:`quadratic_terms`). ``x`` and ``b`` in mm,
    base frame; ``Q`` None is the affine field. The zero bias (:meth:`none`) leaves
    everything as is.
    """

    offset_mm: Array
    """(3,) ``b0`` (mm)."""
    gradient: Array
    """(3, 3) ``B`` (mm/mm)."""
    rms_residual_mm: float = 0.0
    """RMS residual of the fit (mm): the tracker's jitter after averaging, plus what the affine
    field does not describe."""
    n_samples: int = 0
    """Tracked stops used."""
    quadratic: Array | None = None
    """(3, 6) ``Q`` (mm/mm^2), or None: the affine field."""
    centre_mm: Array | None = None
    """(3,) ``c`` (mm, base frame) of the quadratic term (None: the origin)."""

    def __post_init__(self) -> None:
        b0 = check_finite(self.offset_mm, "offset_mm", "mm")
        g = check_finite(self.gradient, "gradient", "mm/mm")
        if b0.shape != (3,):
            raise ShapeError(f"offset_mm must have shape (3,), got {b0.shape}")
        if g.shape != (3, 3):
            raise ShapeError(f"gradient must have shape (3, 3), got {g.shape}")
        if np.max(np.abs(g)) > 0.5:
            raise ConfigurationError(
                f"gradient entries must be within +-0.5 mm/mm (a field bias varies slowly), "
                f"got {np.max(np.abs(g)):.3g}"
            )
        object.__setattr__(self, "offset_mm", b0)
        object.__setattr__(self, "gradient", g)
        if self.quadratic is not None:
            q = check_finite(self.quadratic, "quadratic", "mm/mm^2")
            if q.shape != (3, 6):
                raise ShapeError(f"quadratic must have shape (3, 6), got {q.shape}")
            if np.max(np.abs(q)) > 0.01:
                raise ConfigurationError(
                    f"quadratic entries must be within +-0.01 mm/mm^2 (a field bias varies "
                    f"slowly), got {np.max(np.abs(q)):.3g}"
                )
            object.__setattr__(self, "quadratic", q)
        if self.centre_mm is not None:
            c = check_finite(self.centre_mm, "centre_mm", "mm")
            if c.shape != (3,):
                raise ShapeError(f"centre_mm must have shape (3,), got {c.shape}")
            object.__setattr__(self, "centre_mm", c)

    @classmethod
    def none(cls) -> TrackerBias:
        """No bias (the identity correction)."""
        return cls(np.zeros(3), np.zeros((3, 3)))

    def at(self, x: ArrayLike) -> Array:
        """Bias (..., 3) (mm) at base-frame points x (..., 3) (mm)."""
        p = np.asarray(x, dtype=np.float64)
        b = self.offset_mm + p @ self.gradient.T
        if self.quadratic is not None:  # (TB2)
            c = np.zeros(3) if self.centre_mm is None else self.centre_mm
            b = b + quadratic_terms(p - c) @ self.quadratic.T
        return np.asarray(b, dtype=np.float64)

    def correct_positions(self, measured: ArrayLike) -> Array:
        """True positions x (..., 3) for tracked ones m: the solution of ``x + b(x) = m``
        (fixed-point iteration; |B| << 1 makes it contract fast)."""
        m = np.asarray(measured, dtype=np.float64)
        x = m - self.at(m)
        for _ in range(3):
            x = m - self.at(x)
        return np.asarray(x, dtype=np.float64)

    def correct_poses(self, tip2base: ArrayLike) -> Array:
        """Tracked poses (..., 4, 4) with the position bias removed (NaN rows stay NaN)."""
        t = np.array(tip2base, dtype=np.float64, copy=True)
        t[..., :3, 3] = self.correct_positions(t[..., :3, 3])
        return t

    def correct_calibration(self, calibration: CalibrationSet) -> CalibrationSet:
        """The calibration set with the bias removed from its tracked tips."""
        if not isinstance(calibration, CalibrationSet):
            raise ConfigurationError(
                f"calibration must be a CalibrationSet, got {type(calibration).__name__}"
            )
        return CalibrationSet(
            q_motor=calibration.q_motor,
            tip2base=self.correct_poses(calibration.tip2base),
            catheter_id=calibration.catheter_id,
            vessel=calibration.vessel,
            created=calibration.created,
            method=f"{calibration.method}+bias-removed",
            notes=calibration.notes,
        )

    def shift_model_path(
        self,
        q_model: ArrayLike,
        geometry: CatheterGeometry = DEFAULT_GEOMETRY,
        iterations: int = 3,
    ) -> Array:
        """Model joint states (n, 4) whose model tip is ``p - b(p)`` for each ``p`` of
        ``q_model`` (n, 4), roll and translation kept.

        A compensation built on bias-free calibration data then puts the true tip at
        ``p - b(p)``, where the tracker reads ``p``. Gauss-Newton on the two knobs (the
        axial part of the shift, which the knobs cannot make, is left); knobs are clipped
        to the limits.
        """
        q = check_finite(q_model, "q_model")
        if q.ndim != 2 or q.shape[1] != 4:
            raise ShapeError(f"q_model must have shape (n, 4), got {q.shape}")
        p = forward(q, geometry, check=False)[:, :3, 3]
        target = p - self.at(p)
        out = q.copy()
        lim = geometry.knob_limit
        h = 1e-6
        for _ in range(int(iterations)):
            base = forward(out, geometry, check=False)[:, :3, 3]
            jac = np.empty((q.shape[0], 3, 2))
            for j in range(2):
                dq = out.copy()
                dq[:, j] += h
                jac[:, :, j] = (forward(dq, geometry, check=False)[:, :3, 3] - base) / h
            r = target - base
            jtj = np.einsum("nij,nik->njk", jac, jac) + 1e-9 * np.eye(2)
            step = np.linalg.solve(jtj, np.einsum("nij,ni->nj", jac, r)[..., None])[..., 0]
            out[:, :2] = np.clip(out[:, :2] + step, -lim, lim)
        return out

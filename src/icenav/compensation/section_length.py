"""The bending section's length, identified from tracked calibration poses (beyond the paper).

Why: the paper's F (:mod:`icenav.compensation.elasticity`) maps two knobs to two knobs. It
matches the real tip to the model tip, but a section longer or shorter than the model's
``L`` puts *every* tip of the bend further out or nearer by about ``(s - 1) L``, at every bend
and in every direction: no choice of knobs removes that (a 4 % longer section leaves
2.4 mm along the shaft at 20 deg). The translation joint can: it is the third degree of
freedom the tip's position needs.

What (constant-curvature arc with the ultrasound offset, Eq. (2); ``alpha`` the tip's bend
read from the tracked *orientation*, ``cos alpha = z_tip . e_z``, so the fit does not lean
on the position it explains)::

    rho_i = s L (1 - cos alpha_i) / alpha_i + off sin alpha_i                        (SL1)
    z_i   = s L sin alpha_i / alpha_i + off cos alpha_i + d0

``rho`` and ``z`` are the tracked tip's distance from the shaft's axis and its height (knob
frame: roll and translation removed), ``s`` the section's length scale, ``d0`` an axial
offset (the tracker's, or the rest position's). Linear least squares in ``(s, d0)``. The
model is chosen by held-out residual (:data:`N_FOLDS`-fold cross-validation over the
samples): the scaled arc only where it predicts held-out samples better than the model's own
length with the offset alone, so a catheter of the model's length keeps ``s = 1``. No bound
on ``s`` is assumed from a tolerance table; :data:`SCALE_RANGE` only rejects a fit no
catheter of this kind can give (it raises).

Use (:class:`SectionLength`): :meth:`~SectionLength.axial_excess` is the height the section
adds to the model tip at bend ``alpha`` (mm), ``(s - 1) L sin alpha / alpha``: the
compensation sends the translation ``d4 - axial_excess(alpha)`` and builds F on tracked tips
with that excess removed (:meth:`~SectionLength.correct`), so F matches the model tip in
the shaft's cross-section and the translation along it. The offset ``d0`` is not
compensated: at rest nothing of the section's length is in it, and a tracker's axial
offset is the tracker's, not the catheter's (docs/calibration.md, section 4f).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.compensation.calibration_set import CalibrationSet
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.kinematics import DEFAULT_GEOMETRY, CatheterGeometry

__all__ = [
    "MIN_SAMPLES",
    "N_FOLDS",
    "SCALE_RANGE",
    "SectionLength",
    "fit_section_length",
]

N_FOLDS = 5
"""Folds of the cross-validation that chooses between the model's length and the fitted one."""
MIN_SAMPLES = 5
"""Fewest tracked poses a fit takes (the 5-point search's)."""
SCALE_RANGE = (0.5, 1.5)
"""Length scales a fit may return; outside, the data are not of a bending section (raises)."""
_MIN_BEND = 1e-6  # rad: below it sin(a)/a = 1 and (1 - cos a)/a = 0


@dataclass(frozen=True)
class SectionLength:
    """The section's identified length scale and what chose it."""

    scale: float = 1.0
    """``s``: the section's length over the model's (1: the model's length)."""
    offset_mm: float = 0.0
    """``d0`` of (SL1) (mm; identified, not compensated)."""
    rms_residual_mm: float = 0.0
    """RMS residual of (SL1) over the samples (mm)."""
    cv_residual_mm: float = 0.0
    """Held-out RMS residual of the chosen model (mm)."""
    cv_residual_nominal_mm: float = 0.0
    """Held-out RMS residual of the model's length with ``d0`` alone (mm)."""
    n_samples: int = 0
    """Tracked poses used."""
    length_mm: float = DEFAULT_GEOMETRY.bending_length
    """The model's section length ``L`` (mm) the scale applies to."""

    def __post_init__(self) -> None:
        lo, hi = SCALE_RANGE
        if not (lo <= self.scale <= hi) or not math.isfinite(self.scale):
            raise ConfigurationError(
                f"section length scale must be within [{lo}, {hi}], got {self.scale}"
            )
        if not (self.length_mm > 0.0 and math.isfinite(self.length_mm)):
            raise ConfigurationError(f"length_mm must be > 0 mm, got {self.length_mm} mm")

    @classmethod
    def none(cls) -> SectionLength:
        """The model's own length (changes nothing)."""
        return cls()

    def axial_excess(self, bend: ArrayLike) -> Array:
        """Height (mm) the section's length adds to the model tip at ``bend`` (rad, any
        shape): ``(s - 1) L sin(alpha) / alpha``."""
        a = np.abs(np.asarray(bend, dtype=np.float64))
        sinc = np.sinc(a / math.pi)  # sin(a) / a
        return np.asarray((self.scale - 1.0) * self.length_mm * sinc)

    def correct_poses(self, tip2base: ArrayLike) -> Array:
        """Tracked poses (n, 4, 4) (base frame, mm, any roll and translation) with each tip
        lowered by :meth:`axial_excess` of its tracked bend (``alpha`` from the tip's
        orientation): the tips of a section of the model's length. Orientations unchanged."""
        t = np.array(tip2base, dtype=np.float64)
        if t.ndim != 3 or t.shape[1:] != (4, 4):
            raise ShapeError(f"tip2base must have shape (n, 4, 4), got {t.shape}")
        if self.scale != 1.0:
            t[:, 2, 3] -= self.axial_excess(tracked_bends(t))
        return t

    def correct(self, calibration: CalibrationSet) -> CalibrationSet:
        """``calibration`` with its tips corrected as :meth:`correct_poses` does."""
        if self.scale == 1.0:
            return calibration
        return replace(calibration, tip2base=self.correct_poses(calibration.tip2base))


def tracked_bends(tip2base: ArrayLike) -> Array:
    """Bend ``alpha`` (n,) (rad) of tracked poses (n, 4, 4): the angle between the tip's z
    axis and the shaft's (roll and translation do not change it)."""
    t = np.asarray(tip2base, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise ShapeError(f"tip2base must have shape (n, 4, 4), got {t.shape}")
    return np.arccos(np.clip(t[:, 2, 2], -1.0, 1.0))


def _design(alpha: Array, rho: Array, z: Array, geometry: CatheterGeometry) -> tuple[Array, Array]:
    """Rows of (SL1) as ``A [s, d0] = b``: (2n, 2) and (2n,), rho rows then z rows."""
    big_l, off = geometry.bending_length, geometry.us_offset
    a = np.maximum(alpha, _MIN_BEND)
    arc_r = big_l * (1.0 - np.cos(a)) / a
    arc_z = big_l * np.sin(a) / a
    n = alpha.size
    mat = np.zeros((2 * n, 2))
    mat[:n, 0] = arc_r
    mat[n:, 0] = arc_z
    mat[n:, 1] = 1.0
    rhs = np.concatenate([rho - off * np.sin(alpha), z - off * np.cos(alpha)])
    return mat, rhs


def _solve(mat: Array, rhs: Array, scaled: bool) -> Array:
    """``[s, d0]`` by least squares; ``s = 1`` fixed unless ``scaled``."""
    if scaled:
        return np.asarray(np.linalg.lstsq(mat, rhs, rcond=None)[0])
    d0 = float(np.mean((rhs - mat[:, 0])[mat[:, 1] > 0.0]))
    return np.array([1.0, d0])


def _cv_rms(mat: Array, rhs: Array, n: int, scaled: bool) -> float:
    """Held-out RMS residual (mm) over ``N_FOLDS`` interleaved folds of the n samples."""
    folds = np.arange(n) % min(N_FOLDS, n)
    sq = 0.0
    for k in np.unique(folds):
        test = np.concatenate([folds == k, folds == k])
        x = _solve(mat[~test], rhs[~test], scaled)
        sq += float(np.sum((mat[test] @ x - rhs[test]) ** 2))
    return math.sqrt(sq / rhs.size)


def fit_section_length(
    calibration: CalibrationSet, geometry: CatheterGeometry = DEFAULT_GEOMETRY
) -> SectionLength:
    """Fit (SL1) to tracked poses and choose, by held-out residual, between the fitted
    length and the model's.

    Parameters
    ----------
    calibration : CalibrationSet
        Tracked poses (n >= :data:`MIN_SAMPLES`, base frame, mm) at any roll and translation,
        preferably with the tracker's field bias removed
        (:meth:`icenav.compensation.tracker_bias.TrackerBias.correct_calibration`).
    geometry : CatheterGeometry
        The model's section length and ultrasound offset.
    """
    if not isinstance(calibration, CalibrationSet):
        raise ConfigurationError(
            f"calibration must be a CalibrationSet, got {type(calibration).__name__}"
        )
    ok = np.all(np.isfinite(calibration.tip2base.reshape(calibration.n_samples, -1)), axis=1)
    n = int(ok.sum())
    if n < MIN_SAMPLES:
        raise ConfigurationError(
            f"a section length fit needs at least {MIN_SAMPLES} tracked poses, got {n}"
        )
    p = calibration.positions_in_knob_frame()[ok]
    alpha = tracked_bends(calibration.tip2base[ok])
    mat, rhs = _design(alpha, np.hypot(p[:, 0], p[:, 1]), p[:, 2], geometry)
    cv_scaled = _cv_rms(mat, rhs, n, scaled=True)
    cv_nominal = _cv_rms(mat, rhs, n, scaled=False)
    scaled = cv_scaled < cv_nominal
    x = _solve(mat, rhs, scaled)
    rms = float(np.sqrt(np.mean((mat @ x - rhs) ** 2)))
    return SectionLength(
        scale=float(x[0]),
        offset_mm=float(x[1]),
        rms_residual_mm=rms,
        cv_residual_mm=cv_scaled if scaled else cv_nominal,
        cv_residual_nominal_mm=cv_nominal,
        n_samples=n,
        length_mm=geometry.bending_length,
    )

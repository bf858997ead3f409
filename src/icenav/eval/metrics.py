"""Image and pose metrics of the paper's view-recovery evaluation (Table II).

- :func:`ncc`, :func:`beat_similarity`, :func:`blurred_ncc`, :func:`match_by_phase`: the
  image similarity of :mod:`icenav.refinement.similarity` (re-exported: one NCC for the
  refinement and the evaluation).
- :func:`roi_centroid_distance`: Euclidean distance of ROI centroids (mm).
- :func:`geometric_median`, :func:`geometric_median_index`: the paper's reference return
  is the sample nearest the geometric median of the returns.
- :func:`error_stats`, :func:`rotation_angle`, :func:`pose_errors`: position and
  orientation error statistics (mean, sd, RMSE, max).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_finite, check_transform
from icenav.errors import ShapeError
from icenav.geometry.se3 import rotation_angle
from icenav.refinement.similarity import beat_similarity, blurred_ncc, match_by_phase, ncc

__all__ = [
    "ErrorStats",
    "PoseErrors",
    "beat_similarity",
    "blurred_ncc",
    "error_stats",
    "geometric_median",
    "geometric_median_index",
    "match_by_phase",
    "ncc",
    "pose_errors",
    "roi_centroid_distance",
    "rotation_angle",  # from icenav.geometry.se3
]


def roi_centroid_distance(a_mm: ArrayLike, b_mm: ArrayLike) -> float:
    """Euclidean distance (mm) between two ROI centroids (2-D image plane or 3-D)."""
    x = check_finite(a_mm, "ROI centroid a (mm)")
    y = check_finite(b_mm, "ROI centroid b (mm)")
    if x.shape != y.shape or x.shape not in ((2,), (3,)):
        raise ShapeError(
            f"ROI centroids must both have shape (2,) or (3,), got {x.shape}, {y.shape}"
        )
    return float(np.linalg.norm(x - y))


def geometric_median(
    points: ArrayLike, *, tol_mm: float = 1e-7, max_iterations: int = 500
) -> Array:
    """Geometric median (the point minimising the sum of distances) of ``points`` (n, d).

    Weiszfeld's algorithm with the Vardi-Zhang fix when an iterate lands on a sample.
    """
    p = check_finite(points, "points", "mm")
    if p.ndim != 2 or p.shape[0] < 1:
        raise ShapeError(f"points must have shape (n, d) with n >= 1, got {p.shape}")
    y = p.mean(axis=0)
    for _ in range(max_iterations):
        d = np.linalg.norm(p - y, axis=1)
        near = d < 1e-12
        w = 1.0 / np.where(near, 1.0, d)
        w[near] = 0.0
        t = (w[:, None] * p).sum(axis=0) / w.sum() if w.sum() > 0 else y
        n_near = int(near.sum())
        if n_near:
            r = np.linalg.norm((w[:, None] * (p - y)).sum(axis=0))
            gamma = min(1.0, float(n_near) / float(r)) if r > 0 else 1.0
            t = (1.0 - gamma) * t + gamma * y
        if float(np.linalg.norm(t - y)) < tol_mm:
            return t
        y = t
    return y


def geometric_median_index(points: ArrayLike) -> int:
    """Index of the sample nearest the geometric median (the paper's reference return)."""
    p = check_finite(points, "points", "mm")
    gm = geometric_median(p)
    return int(np.argmin(np.linalg.norm(p - gm, axis=1)))


@dataclass(frozen=True)
class ErrorStats:
    """Summary of a set of non-negative errors (one unit for all fields)."""

    mean: float
    """Mean error."""
    sd: float
    """Sample standard deviation (ddof = 1; 0 for a single value)."""
    rmse: float
    """Root mean square."""
    max: float
    """Largest error."""
    n: int
    """Number of errors."""


def error_stats(errors: ArrayLike) -> ErrorStats:
    """Mean, sample sd, RMSE and max of ``errors`` (shape (n,), n >= 1)."""
    e = check_finite(errors, "errors").ravel()
    if e.size == 0:
        raise ShapeError("error_stats needs at least one error")
    sd = float(np.std(e, ddof=1)) if e.size > 1 else 0.0
    return ErrorStats(
        mean=float(e.mean()),
        sd=sd,
        rmse=float(np.sqrt(np.mean(e * e))),
        max=float(e.max()),
        n=int(e.size),
    )


@dataclass(frozen=True)
class PoseErrors:
    """Position and orientation errors of a set of poses against one reference."""

    position_mm: Array
    """(n,) Euclidean position error of each pose (mm)."""
    orientation_rad: Array
    """(n,) rotation angle between each pose and the reference (rad)."""
    position: ErrorStats
    """Statistics of ``position_mm`` (mm)."""
    orientation: ErrorStats
    """Statistics of ``orientation_rad`` (rad)."""


def pose_errors(poses: ArrayLike, reference: ArrayLike) -> PoseErrors:
    """Errors of ``poses`` (n, 4, 4) against ``reference`` (4, 4); translations in mm."""
    p = check_transform(poses, "poses")
    ref = check_transform(reference, "reference")
    if p.ndim != 3 or ref.shape != (4, 4):
        raise ShapeError(
            f"poses must have shape (n, 4, 4) and reference (4, 4), got {p.shape}, {ref.shape}"
        )
    pos = np.linalg.norm(p[:, :3, 3] - ref[:3, 3], axis=1)
    ang = rotation_angle(p[:, :3, :3], ref[:3, :3])
    return PoseErrors(pos, ang, error_stats(pos), error_stats(ang))

"""Image and pose metrics of the paper's view-recovery evaluation (Table II).

- :func:`ncc`: zero-mean normalised cross-correlation of two images (the paper's "image
  cross-correlation"); :func:`beat_similarity`: frames of two one-beat clips matched by
  cardiac phase, NCC per matched pair, mean over the beat.
- :func:`blurred_ncc`: NCC of Gaussian-blurred, down-sampled images. Raw speckle
  decorrelates within a fraction of a millimetre, so raw NCC is rough in pose; the blurred
  version varies smoothly with pose and is the one to climb in a control loop.
- :func:`roi_centroid_distance`: Euclidean distance of ROI centroids (mm).
- :func:`geometric_median`, :func:`geometric_median_index`: the paper's reference return
  is the sample nearest the geometric median of the returns.
- :func:`error_stats`, :func:`rotation_angle`, :func:`pose_errors`: position and
  orientation error statistics (mean, sd, RMSE, max).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_positive, check_transform
from icenav.errors import InvalidValueError, ShapeError
from icenav.geometry.se3 import rotation_angle

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


def _pair(a: ArrayLike, b: ArrayLike, name: str) -> tuple[Array, Array]:
    x = check_finite(a, f"{name} a")
    y = check_finite(b, f"{name} b")
    if x.shape != y.shape or x.ndim < 1 or x.size < 2:
        raise ShapeError(
            f"{name}: images must have the same shape with >= 2 pixels, got {x.shape} and {y.shape}"
        )
    return x, y


def ncc(a: ArrayLike, b: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Zero-mean normalised cross-correlation of two images, in [-1, 1].

    Parameters
    ----------
    a, b : array-like, same shape
        Images (any numeric dtype).
    mask : array-like of bool, same shape, optional
        Pixels to use (e.g. the sector); all if omitted.

    Returns
    -------
    float
        sum((a - mean a)(b - mean b)) / sqrt(sum (a - mean a)^2 sum (b - mean b)^2);
        0 if either image is constant.
    """
    x, y = _pair(a, b, "ncc")
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != x.shape:
            raise ShapeError(f"ncc: mask shape {m.shape} differs from image shape {x.shape}")
        x, y = x[m], y[m]
    x = x.ravel() - x.mean()
    y = y.ravel() - y.mean()
    den = math.sqrt(float(x @ x) * float(y @ y))
    if den == 0.0:
        return 0.0
    return float(x @ y) / den


def blurred_ncc(
    a: ArrayLike,
    b: ArrayLike,
    *,
    sigma_px: float = 4.0,
    factor: int = 4,
    mask: ArrayLike | None = None,
) -> float:
    """NCC of Gaussian-blurred, down-sampled images (smooth in pose; for control loops).

    Parameters
    ----------
    a, b : array-like, shape (H, W)
        Images.
    sigma_px : float
        Gaussian sigma (pixels of the input) applied before down-sampling.
    factor : int
        Down-sampling factor (every ``factor``-th pixel in each direction).
    mask : array-like of bool, shape (H, W), optional
        Pixels to use, down-sampled with the images.
    """
    x, y = _pair(a, b, "blurred_ncc")
    if x.ndim != 2:
        raise ShapeError(f"blurred_ncc: images must be 2-D, got shape {x.shape}")
    check_positive(sigma_px, "sigma_px", "px")
    if not isinstance(factor, int) or factor < 1:
        raise InvalidValueError(f"factor must be an int >= 1, got {factor!r}")
    xs = ndi.gaussian_filter(x, sigma_px)[::factor, ::factor]
    ys = ndi.gaussian_filter(y, sigma_px)[::factor, ::factor]
    m = None if mask is None else np.asarray(mask, dtype=bool)[::factor, ::factor]
    return ncc(xs, ys, m)


def match_by_phase(phases_a: ArrayLike, phases_b: ArrayLike) -> NDArray[np.intp]:
    """For each phase in ``phases_b``, the index of the nearest phase in ``phases_a``.

    Phases are fractions of the beat in [0, 1) and wrap (0.98 is near 0.01).
    """
    pa = check_finite(phases_a, "phases_a").ravel()
    pb = check_finite(phases_b, "phases_b").ravel()
    if pa.size == 0 or pb.size == 0:
        raise ShapeError("match_by_phase: phase lists must not be empty")
    d = np.abs(np.mod(pb[:, None] - pa[None, :] + 0.5, 1.0) - 0.5)
    out: NDArray[np.intp] = np.argmin(d, axis=1)
    return out


def beat_similarity(
    clip: Sequence[ArrayLike],
    phases: ArrayLike,
    reference: Sequence[ArrayLike],
    reference_phases: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    blurred: bool = False,
) -> float:
    """Mean image similarity over one beat, frames matched by cardiac phase (the paper's).

    Each reference frame is compared (NCC) with the ``clip`` frame nearest in cardiac
    phase; the result is the mean over the reference frames.

    Parameters
    ----------
    clip, reference : sequences of images, shape (H, W) each
        One heart beat each.
    phases, reference_phases : array-like, shape (n,), (m,)
        Cardiac phase of each frame (fraction of the beat, 0 = R wave).
    mask : array-like of bool, shape (H, W), optional
        Pixels to compare (e.g. the sector).
    blurred : bool
        Use :func:`blurred_ncc` instead of raw :func:`ncc`.

    Returns
    -------
    float
        Mean NCC in [-1, 1] (multiply by 100 for the paper's %).
    """
    if len(clip) != np.size(phases) or len(reference) != np.size(reference_phases):
        raise ShapeError(
            f"beat_similarity: {len(clip)} frames with {np.size(phases)} phases, "
            f"{len(reference)} reference frames with {np.size(reference_phases)} phases"
        )
    idx = match_by_phase(phases, reference_phases)
    values = [
        blurred_ncc(clip[i], ref, mask=mask) if blurred else ncc(clip[i], ref, mask)
        for i, ref in zip(idx, reference, strict=True)
    ]
    return float(np.mean(values))


def roi_centroid_distance(a_mm: ArrayLike, b_mm: ArrayLike) -> float:
    """Euclidean distance (mm) between two ROI centroids (2-D image plane or 3-D)."""
    x, y = _pair(a_mm, b_mm, "roi_centroid_distance")
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

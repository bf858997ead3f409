"""Image similarity of ICE beats: one NCC, frames matched by cardiac phase.

- :func:`ncc_rows`: zero-mean normalised cross-correlation, row by row (the one NCC);
  :func:`ncc` of two images (the paper's "image cross-correlation") is one row of it.
- :func:`blurred_ncc`: NCC of Gaussian-blurred, down-sampled images. Raw speckle
  decorrelates within a fraction of a millimetre, so raw NCC is rough in pose; the blurred
  version varies smoothly with pose and is the one to climb in a control loop.
- :func:`match_by_phase`: nearest cardiac phase (wrapping) of one beat's frames for another's.
- :func:`beat_similarity`: frames of two one-beat clips matched by cardiac phase, NCC per
  matched pair, mean over the beat (the paper's measure); :func:`beat_score` the same on
  :class:`~icenav.recovery.beats.BeatClip` values with the blur done once per beat.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.ndimage as ndi
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_finite, check_positive
from icenav.errors import InvalidValueError, ShapeError
from icenav.recovery.beats import BeatClip

__all__ = [
    "beat_score",
    "beat_similarity",
    "blur_frames",
    "blurred_ncc",
    "match_by_phase",
    "ncc",
    "ncc_rows",
]


def ncc_rows(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Zero-mean NCC of each row of ``a`` with the same row of ``b``: (n, p), (n, p) ->
    (n,) in [-1, 1], ``sum((a - mean a)(b - mean b)) / sqrt(sum (a - mean a)^2 sum (b -
    mean b)^2)`` per row; 0 where a row is constant."""
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    den = np.sqrt(np.sum(a * a, axis=1) * np.sum(b * b, axis=1))
    num = np.sum(a * b, axis=1)
    out: NDArray[np.float64] = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    return out


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
    return float(ncc_rows(x.reshape(1, -1), y.reshape(1, -1))[0])


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


def blur_frames(images: NDArray[np.float64], sigma_px: float, factor: int) -> NDArray[np.float64]:
    """(n, H, W) frames Gaussian-blurred in-plane (sigma in px) and down-sampled by
    ``factor``: (n, ceil(H / factor), ceil(W / factor))."""
    out: NDArray[np.float64] = ndi.gaussian_filter(images, (0.0, sigma_px, sigma_px))[
        :, ::factor, ::factor
    ]
    return out


def beat_score(
    clip: BeatClip, reference: BeatClip, *, sigma_px: float = 2.0, factor: int = 2
) -> float:
    """Blurred beat similarity in [-1, 1]: each reference frame against the clip frame
    nearest in cardiac phase, blurred NCC over the reference's sector mask, mean over the
    reference beat (the same value as ``beat_similarity(..., blurred=True)`` with this
    blur)."""
    check_positive(sigma_px, "sigma_px", "px")
    if clip.images.shape[1:] != reference.images.shape[1:]:
        raise ShapeError(
            f"clip images {clip.images.shape[1:]} differ from the reference's "
            f"{reference.images.shape[1:]}"
        )
    idx = match_by_phase(clip.phases, reference.phases)
    a = blur_frames(clip.images[idx], sigma_px, factor)
    b = blur_frames(reference.images, sigma_px, factor)
    m = reference.mask
    if m is not None:
        ms = m[::factor, ::factor]
        return float(np.mean(ncc_rows(a[:, ms], b[:, ms])))
    return float(np.mean(ncc_rows(a.reshape(len(a), -1), b.reshape(len(b), -1))))

"""One heart beat of ICE images (a saved view's reference, a live measurement) and the
protocol of the sources that give them.

A view is recognised by its images as much as by its motor state: the refinement compares a
live beat with the beats saved with the view, frame by frame at the same cardiac phase.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from icenav._validation import check_finite
from icenav.errors import ConfigurationError, ShapeError

__all__ = ["BeatClip", "BeatImager"]


@dataclass(frozen=True)
class BeatClip:
    """One heart beat of ultrasound images from a still catheter."""

    images: NDArray[np.float64]
    """(n, H, W) grey images (any scale; NCC is scale free)."""
    phases: NDArray[np.float64]
    """(n,) cardiac phase of each frame (fraction of the beat, 0 = R wave)."""
    mask: NDArray[np.bool_] | None = None
    """(H, W) pixels inside the imaging sector, or None for all pixels."""
    t0: float = 0.0
    """Acquisition time of the first frame (s)."""
    frames: tuple[object, ...] = ()
    """The source frames with their ground truth (e.g. ``icenav.sim.ultrasound.Frame``),
    when the imager keeps them (evaluation only)."""
    times: NDArray[np.float64] | None = None
    """(n,) acquisition time of each frame (s), if known (needed for respiratory gating)."""

    def __post_init__(self) -> None:
        img = np.asarray(self.images, dtype=np.float64)
        ph = check_finite(self.phases, "phases").ravel()
        if img.ndim != 3 or img.shape[0] < 1:
            raise ShapeError(f"images must have shape (n >= 1, H, W), got {img.shape}")
        if ph.shape != (img.shape[0],):
            raise ShapeError(f"{img.shape[0]} images need {img.shape[0]} phases, got {ph.size}")
        if self.mask is not None:
            m = np.asarray(self.mask, dtype=bool)
            if m.shape != img.shape[1:]:
                raise ShapeError(f"mask shape {m.shape} differs from the images' {img.shape[1:]}")
            object.__setattr__(self, "mask", m)
        object.__setattr__(self, "images", img)
        object.__setattr__(self, "phases", ph)
        if self.times is not None:
            tt = check_finite(self.times, "times").ravel()
            if tt.shape != ph.shape:
                raise ShapeError(f"{ph.size} frames need {ph.size} times, got {tt.size}")
            object.__setattr__(self, "times", tt)

    def subsampled(self, k: int) -> BeatClip:
        """Every ``k``-th frame (k >= 1) of the beat, with its phases, times and frames."""
        if isinstance(k, bool) or int(k) != k or k < 1:
            raise ConfigurationError(f"k must be an int >= 1, got {k!r}")
        return BeatClip(
            self.images[::k],
            self.phases[::k],
            self.mask,
            self.t0,
            self.frames[::k],
            None if self.times is None else self.times[::k],
        )


class BeatImager(Protocol):
    """Source of live ultrasound beats for the refinement."""

    @property
    def beat_duration_s(self) -> float:
        """Length of one heart beat (s): how long the catheter is held still per measure."""
        ...

    def acquire_beat(self) -> BeatClip:
        """The heart beat recorded up to now from the current (still) catheter pose."""
        ...

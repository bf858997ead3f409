"""Refinement by measured re-approach: when the cycle-averaged EM pose says the return
missed, replay the view's recorded approach and measure again (beyond the paper).

Under the shaft's stick-slip a small corrective step is a new draw of the lost motion: it
may not move the tip at all (the shaft sticks) or jump past the target (it slips). The
roadmap's return with the recorded approach is the one move whose outcome was already close
to the saved pose; replaying it (back along the approach and forward again, through
recorded states only) is a fresh, *large and deliberate* move from the same side.

Rule (Eq. R2): with ``e_0`` the weighted error of the first measurement (Eq. R1 estimate
against the saved one; position mm plus ``w`` times the rotation, as the pose stage):

1. stop when ``e_k <= tolerance`` (the return is good as far as the estimator can tell);
2. otherwise re-approach (``reapproach()``) and measure ``e_(k+1)``, at most
   ``max_retries`` times;
3. if the last error is larger than the first by more than ``noise_mm``, re-approach once
   more (bounded: one extra move) so the result is a fresh draw, not the worst one seen; the
   result says whether it ended worse than it started.

Every move is a replay of recorded states (the roadmap's safety), bounded in number, each
followed by one measurement; ``abort()`` is polled before every move.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav._validation import check_positive
from icenav.errors import ConfigurationError
from icenav.geometry.se3 import body_pose_error

__all__ = ["RetryConfig", "RetryResult", "retry_return", "weighted_error"]


@dataclass(frozen=True)
class RetryConfig:
    """Settings of :func:`retry_return`."""

    tolerance_mm: float = 0.6
    """Weighted error (mm) below which the return is kept."""
    rotation_weight_mm_per_rad: float = 25.0
    """Weight of the rotation error (mm per rad: 1 deg counts as 0.44 mm)."""
    max_retries: int = 2
    """Re-approaches after the first measurement (each one measurement)."""
    noise_mm: float = 0.3
    """Scatter of the estimator (mm): a larger error than the first by more than this is
    'worse'."""

    def __post_init__(self) -> None:
        check_positive(self.tolerance_mm, "tolerance_mm", "mm")
        check_positive(self.rotation_weight_mm_per_rad, "rotation_weight_mm_per_rad", "mm/rad")
        check_positive(self.noise_mm, "noise_mm", "mm")
        n = self.max_retries
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 10:
            raise ConfigurationError(f"max_retries must be an int in [0, 10], got {n!r}")


@dataclass(frozen=True)
class RetryResult:
    """What :func:`retry_return` did."""

    errors_mm: tuple[float, ...]
    """Weighted error (mm) of each measurement, the first before any move."""
    position_mm: tuple[float, ...]
    """Position part of each measurement's error (mm)."""
    rotation_deg: tuple[float, ...]
    """Rotation part of each measurement's error (deg)."""
    moves: int
    """Re-approaches made."""
    ended_worse: bool
    """The last measurement is worse than the first by more than the noise."""
    aborted: bool = False
    """``abort()`` stopped it."""


def weighted_error(saved: ArrayLike, measured: ArrayLike, w: float) -> tuple[float, float, float]:
    """(weighted mm, position mm, rotation deg) of ``saved`` relative to ``measured``
    ((4, 4) each, mm): ``|dp| + w |dtheta|``."""
    e = body_pose_error(np.asarray(saved, np.float64), np.asarray(measured, np.float64), 1.0)
    p, r = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
    return p + w * r, p, math.degrees(r)


def retry_return(
    saved: ArrayLike,
    measure: Callable[[], Array | None],
    reapproach: Callable[[], None],
    *,
    config: RetryConfig | None = None,
    abort: Callable[[], bool] | None = None,
) -> RetryResult:
    """Eq. (R2): measure; re-approach while off, at most ``max_retries`` times; one more
    re-approach if it ended worse than it started.

    Parameters
    ----------
    saved : (4, 4)
        The pose saved with the view (the same estimator; mm).
    measure : callable -> (4, 4) or None
        The cycle-averaged EM pose now (holds the catheter for its window); None: no pose.
    reapproach : callable
        Replays the view's recorded approach (a roadmap return from where the robot is).
    """
    cfg = config if config is not None else RetryConfig()
    w = cfg.rotation_weight_mm_per_rad
    errs: list[float] = []
    pos: list[float] = []
    rot: list[float] = []

    def take() -> bool:
        m = measure()
        if m is None:
            return False
        e, p, r = weighted_error(saved, m, w)
        errs.append(e)
        pos.append(p)
        rot.append(r)
        return True

    moves = 0
    aborted = False
    if take():
        while errs[-1] > cfg.tolerance_mm and moves < cfg.max_retries:
            if abort is not None and abort():
                aborted = True
                break
            reapproach()
            moves += 1
            if not take():
                break
        worse_now = not aborted and errs[-1] > errs[0] + cfg.noise_mm
        if worse_now and (abort is None or not abort()):
            reapproach()
            moves += 1
            take()
    worse = bool(errs) and errs[-1] > errs[0] + cfg.noise_mm
    return RetryResult(tuple(errs), tuple(pos), tuple(rot), moves, worse, aborted)

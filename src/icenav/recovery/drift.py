"""Has the patient moved? The tracked tip against where the operator left it, with the
motors still, compared like with like (Eq. F5 of :mod:`icenav.recovery.force`).

A return replays motor states; when the patient moved on the table since the operator left
the catheter, the states no longer give the views and may push into a wall. With the motors
still the tip should stay where the operator left it, but it does not stand still: every
beat and every breath move it, by several millimetres where it touches a moving wall (on the
twin, up to 20 mm with each beat at the tricuspid annulus; `docs/view-recovery.md`).
Comparing the tip now with the single reading at the stop therefore compares two arbitrary
phases of that motion, and refuses returns the longer the operator looked at the image.

Eq. (F5), phase-matched: the reference is the tip's readings over the first
:data:`REST_WINDOW_S` of stillness after the operator's last motion, each with the cardiac
phase ``c`` in [0, 1) (ECG, 0 at the R wave) and the respiratory signal ``r`` (bellows or
ventilator) read with it. The tip now is compared with the mean of the :data:`NEIGHBOURS`
reference readings nearest in phase, among those older than :data:`GUARD_S`::

    d_k^2 = wrap(c_k - c)^2 + ((r_k - r) / (max_k r_k - min_k r_k))^2
    D     = | p_now - mean{ p_k : the NEIGHBOURS smallest d_k } |                   (F5)

(``wrap`` to [-0.5, 0.5); a signal that is missing, or flat over the reference, is left out
of ``d``). Without either signal, or with no reading but the stop's old enough (a return
started at once, or a reference restored after a restart), ``D`` is the distance to the
reading at the stop, the instantaneous form. A shift during the reference window, more than
:data:`GUARD_S` before the return, is partly taken into the reference and may be missed; one
before the stop, or after the window, or within :data:`GUARD_S` of the return, is seen at
its full size. What it reaches on the twin, by how long the operator looked before the
return: ``docs/view-recovery.md`` (session 8) and ``docs/results.md`` (the force check).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.errors import ShapeError

__all__ = [
    "DEFAULT_DRIFT_MM",
    "DRIFT_WINDOW_S",
    "GUARD_S",
    "NEIGHBOURS",
    "Phases",
    "REST_Q_TOLERANCE",
    "REST_WINDOW_S",
    "RestReference",
    "check_q",
    "tip_drift",
]

DEFAULT_DRIFT_MM = 5.0
"""Largest distance ``D`` of Eq. (F5) (mm) before a return refuses to start: chosen on the
development pairs (``docs/view-recovery.md``)."""

DRIFT_WINDOW_S = 0.1
"""A return holds at its first state this long, checking Eq. (F5) at every control cycle,
before it moves (s): a tracker's newest sample may be a frame old when the return starts
(an NDI Aurora gives one every 25 ms), and once the motors move the shaft may slip and the
tip jump with it (up to 16 mm in 40 ms on the twin)."""

REST_WINDOW_S = 6.0
"""Readings kept as the reference after the operator's last motion (s): more than one
breath (a ventilated patient breathes about every 4 s) and several beats."""

NEIGHBOURS = 3
"""Reference readings averaged at the nearest phase (Eq. F5)."""

GUARD_S = 1.0
"""Readings younger than this at the check (s) are not used as the reference: a patient who
moved just before the return (within the reference window) would otherwise be matched with
the readings of the moved tip itself."""

REST_Q_TOLERANCE = 1e-3
"""Largest difference per joint (rad or mm) between the motor state a session stored with
the rest pose and the one the robot reports after a restart for the rest pose to stand
(encoder counts of the robot's drives are finer than 1e-4)."""

Phases = tuple[float | None, float | None]
"""(respiratory signal, cardiac phase in [0, 1)) read with a tip reading, each None when
that channel is not connected."""


def check_q(q: ArrayLike, name: str) -> Array:
    """``q`` as (4,) finite joint values (rad, rad, rad, mm), else :class:`ShapeError`."""
    a = np.asarray(q, np.float64).reshape(-1)
    if a.shape != (4,) or not np.all(np.isfinite(a)):
        raise ShapeError(f"{name} must be 4 finite joint values (rad, rad, rad, mm), got {q!r}")
    return a.copy()


def _position(tip: ArrayLike, name: str) -> Array:
    """The position (3,) mm of a (4, 4) pose or a (3,) point, finite."""
    a = np.asarray(tip, np.float64)
    p = a[:3, 3] if a.shape == (4, 4) else a.reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ShapeError(f"{name} must be a finite (4, 4) pose or 3 mm, got shape {a.shape}")
    return p.copy()


def tip_drift(rest_tip: ArrayLike | None, tip2base: ArrayLike | None) -> float | None:
    """How far the tracked tip has moved since the rest reading (mm), Eq. (F5) in its
    instantaneous form::

        D = | p_now - p_rest |

    (``rest_tip`` (3,) mm; ``tip2base`` (4, 4) mm, base frame). None when either is
    unknown (no check)."""
    if rest_tip is None or tip2base is None:
        return None
    p = np.asarray(tip2base, np.float64)[:3, 3]
    return float(np.linalg.norm(p - np.asarray(rest_tip, np.float64).reshape(3)))


class RestReference:
    """Where the operator left the tip: the reading at the stop and the readings of the first
    :data:`REST_WINDOW_S` of stillness with their phases (Eq. F5, phase-matched).

    Parameters
    ----------
    t : float
        Time of the stop (s).
    tip : array-like
        (4, 4) tip pose or (3,) position at the stop (mm, base frame).
    q : array-like, optional
        (4,) motor state left (rad, rad, rad, mm); None: unknown (not kept across a restart).
    resp, cardiac : float, optional
        Respiratory signal and cardiac phase at the stop (None: not connected).
    """

    def __init__(
        self,
        t: float,
        tip: ArrayLike,
        q: ArrayLike | None = None,
        resp: float | None = None,
        cardiac: float | None = None,
    ) -> None:
        self.t0 = float(t)
        self.q = None if q is None else check_q(q, "q")
        self._rows = np.empty((16, 6))  # t, x, y, z (mm), respiratory signal, cardiac phase
        self._n = 0
        self._append(self.t0, tip, resp, cardiac)

    @property
    def tip(self) -> Array:
        """(3,) the reading at the stop (mm)."""
        return self._rows[0, 1:4].copy()

    @property
    def n_readings(self) -> int:
        return self._n

    def spread_mm(self) -> float:
        """How far the still tip strayed from its mean over the reference (mm, the 90th
        percentile of the readings' distances; 0 with one reading): what the beat, the
        breath and the shaft do at rest here, for the operator to weigh a refusal."""
        if self._n < 2:
            return 0.0
        ps = self._rows[: self._n, 1:4]
        return float(np.percentile(np.linalg.norm(ps - ps.mean(axis=0), axis=1), 90))

    def set_stop_phases(self, resp: float | None, cardiac: float | None) -> None:
        """The phases read with the stop's reading, when they are read after it (the loop
        reads them once the motors have stopped instead of at every moving cycle)."""
        self._rows[0, 4] = np.nan if resp is None else float(resp)
        self._rows[0, 5] = np.nan if cardiac is None else float(cardiac)

    def wants(self, t: float) -> bool:
        """Whether a reading at ``t`` (s) still belongs to the reference window."""
        return t - self.t0 <= REST_WINDOW_S

    def add(self, t: float, tip: ArrayLike, resp: float | None, cardiac: float | None) -> None:
        """A reading of the still tip at ``t`` (s) with its phases; ignored once the
        reference window is over."""
        if self.wants(t):
            self._append(t, tip, resp, cardiac)

    def _append(self, t: float, tip: ArrayLike, resp: float | None, cardiac: float | None) -> None:
        p = _position(tip, "tip")
        if self._n == len(self._rows):  # grown by doubling: appends stay O(1) on the loop
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        r = np.nan if resp is None else float(resp)
        c = np.nan if cardiac is None else float(cardiac)
        self._rows[self._n] = (float(t), p[0], p[1], p[2], r, c)
        self._n += 1

    def drift(
        self,
        tip2base: ArrayLike,
        resp: float | None = None,
        cardiac: float | None = None,
        t: float | None = None,
    ) -> float:
        """``D`` of Eq. (F5) for the tip now (``tip2base`` (4, 4) or (3,), mm) read at time
        ``t`` (s; None: every reading counts) with the respiratory signal ``resp`` and the
        cardiac phase ``cardiac`` (mm)."""
        p = _position(tip2base, "tip2base")
        n = self._n
        rows = self._rows[:n]
        if t is not None:  # readings older than the guard (the stop's always counts)
            n = max(1, int(np.searchsorted(rows[:, 0], float(t) - GUARD_S, side="right")))
        ps = rows[:n, 1:4]
        d2 = np.zeros(n)
        used = False
        c = rows[:n, 5]
        if cardiac is not None and np.all(np.isfinite(c)) and n > 1:
            d2 += ((c - float(cardiac) + 0.5) % 1.0 - 0.5) ** 2
            used = True
        r = rows[:n, 4]
        if resp is not None and np.all(np.isfinite(r)) and np.ptp(r) > 1e-12:
            d2 += ((r - float(resp)) / np.ptp(r)) ** 2
            used = True
        if not used:  # the instantaneous form: against the reading at the stop
            return float(np.linalg.norm(p - ps[0]))
        near = np.argsort(d2, kind="stable")[:NEIGHBOURS]
        return float(np.linalg.norm(p - ps[near].mean(axis=0)))

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

Where the still tip itself strays as far as a shift would move it (in vivo, a tip resting
against a wall that the beat and the breath move), no limit separates the two. The check
then says so instead of refusing: its resolution here is Eq. (F5) applied to each reading
of the reference against the others at least ``E`` = :data:`RESOLUTION_EXCLUDE_S` away
from it in time (not its own stretch of the beat)::

    R = P90_k | p_k - mean{ p_j : the NEIGHBOURS nearest in phase to k, |t_j - t_k| >= E } |
                                                                                      (F6)

(the instantaneous form: ``| p_k - p_stop |``). When ``D`` exceeds the limit and ``R``
exceeds :data:`RESOLUTION_FRACTION` of it, the check *cannot tell*: the return holds and
asks the operator to confirm (a second press within :data:`CONFIRM_S`), and then runs under
the force limit alone;
any drive of the operator makes a new reference and a new question.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.errors import ShapeError

__all__ = [
    "CONFIRM_S",
    "DEFAULT_DRIFT_MM",
    "DRIFT_WINDOW_S",
    "GUARD_S",
    "NEIGHBOURS",
    "Phases",
    "REST_Q_TOLERANCE",
    "RESOLUTION_FRACTION",
    "REST_WINDOW_S",
    "RestReference",
    "cannot_tell",
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

RESOLUTION_FRACTION = 0.5
"""The check can tell where its resolution ``R`` (Eq. F6, the 90th percentile of the still
tip's own ``D``) is at most this fraction of the limit ``L``: nine in ten still readings then
lie within ``L / 2`` of their phase-matched reference, so a tip beyond ``L`` is at least
``L / 2`` beyond what it does by itself. Above it a tip beyond ``L`` may be its own motion:
the check cannot tell (it asks instead of refusing). Chosen from that argument and looked at
on the development pairs (``docs/results.md``, the force check, session 9), not fitted."""

CONFIRM_S = 30.0
"""A second press within this time (s) of the question confirms a return the check could
not judge (Eq. F6); later, the return asks again (the patient may have moved since)."""

RESOLUTION_EXCLUDE_S = 0.3
"""Readings this close in time to the one judged are left out of its reference in Eq. (F6)
(s): its own stretch of the beat (a systole lasts about 0.3 s), which would match it
trivially. A longer exclusion leaves the window's edges poorly covered and overstates
``R`` against what Eq. (F5) then sees (a tip swung 5 mm by the beat and 5 mm by the breath:
``R`` 2.5 mm at 0.3 s, 5.6 mm at 1 s, against a 90th percentile of 2.0 mm of ``D`` at later
times; ``tests/recovery/test_drift.py``)."""

RESOLUTION_QUERIES = 64
"""Readings of the reference at which Eq. (F6) is evaluated (evenly spaced; all when
fewer): its cost stays about 0.3 ms whatever the tracker's rate."""

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
        self._resolution: tuple[int, float] = (-1, 0.0)
        self.asked_at: float | None = None
        """When a return asked the operator to confirm because the check could not tell
        from this reference (Eq. F6; s of the loop's clock, -inf without one), None if
        none has."""
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

    def resolution_mm(self, within: float = 1.0) -> float:
        """``R`` of Eq. (F6) (mm): how far Eq. (F5) puts the still tip from itself over the
        reference; 0 while no reading has :data:`NEIGHBOURS` others
        :data:`RESOLUTION_EXCLUDE_S` away (the check applies as it is). ``within`` < 1
        accepts the value last computed over at least that fraction of the readings (the
        status line, built every control cycle while the reference grows, so it costs a
        computation, about 1 ms, only as the readings grow by a quarter); the check takes
        the exact value. Safe to call from another thread than the one adding readings
        (the count is read before the rows, which only grow)."""
        n = self._n
        cached = self._resolution
        if cached[0] == n or (cached[0] >= 0 and cached[0] >= within * n):
            return cached[1]
        rows = self._rows[:n]
        value = _resolution(rows)
        self._resolution = (n, value)
        return value

    def ask(self, t: float | None) -> None:
        """A return asked the operator to confirm at ``t`` (s; None: no clock)."""
        self.asked_at = -np.inf if t is None else float(t)

    def confirmed(self, t: float | None) -> bool:
        """Whether a return at ``t`` (s; None: no clock) is the operator's confirmation:
        one asked from this reference at most :data:`CONFIRM_S` before (without a clock,
        any one asked before)."""
        if self.asked_at is None:
            return False
        return t is None or self.asked_at == -np.inf or t - self.asked_at <= CONFIRM_S

    def answered(self) -> None:
        """The operator's confirmation was taken by a return: a later one asks again."""
        self.asked_at = None

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
        rows = self._rows[: self._n]
        if t is not None:  # readings older than the guard (the stop's always counts)
            rows = rows[: max(1, int(np.searchsorted(rows[:, 0], float(t) - GUARD_S, "right")))]
        d2 = _phase_distances(
            rows,
            np.array([np.nan if resp is None else float(resp)]),
            np.array([np.nan if cardiac is None else float(cardiac)]),
        )
        if d2 is None:  # the instantaneous form: against the reading at the stop
            return float(np.linalg.norm(p - rows[0, 1:4]))
        near = np.argsort(d2[0], kind="stable")[:NEIGHBOURS]
        return float(np.linalg.norm(p - rows[near, 1:4].mean(axis=0)))


def cannot_tell(
    resolution_mm: float, limit_mm: float, fraction: float = RESOLUTION_FRACTION
) -> bool:
    """Eq. (F6)'s rule: the check cannot tell a moved patient from the still tip's own
    motion where its resolution (mm) exceeds ``fraction`` of the limit (mm)."""
    return resolution_mm > fraction * limit_mm


def _phase_distances(rows: Array, resp: Array, cardiac: Array) -> Array | None:
    """Squared phase distances (m, n) of Eq. (F5) between the m query phases ``resp`` and
    ``cardiac`` (m,) (NaN: not read) and the reference ``rows`` (n, 6); a signal is left
    out when a query or a reference reading lacks it, or it is flat over the reference;
    None when neither is left (the instantaneous form)."""
    d2 = np.zeros((len(resp), len(rows)))
    used = False
    c = rows[:, 5]
    if len(rows) > 1 and np.all(np.isfinite(cardiac)) and np.all(np.isfinite(c)):
        d2 += ((c[None, :] - cardiac[:, None] + 0.5) % 1.0 - 0.5) ** 2
        used = True
    r = rows[:, 4]
    if np.all(np.isfinite(resp)) and np.all(np.isfinite(r)) and np.ptp(r) > 1e-12:
        d2 += ((r[None, :] - resp[:, None]) / np.ptp(r)) ** 2
        used = True
    return d2 if used else None


def _resolution(rows: Array) -> float:
    """Eq. (F6) over reference rows (n, 6): t, x, y, z, respiratory signal, cardiac phase."""
    n = len(rows)
    if n < NEIGHBOURS + 1:
        return 0.0
    k = np.unique(np.linspace(0, n - 1, min(n, RESOLUTION_QUERIES)).round().astype(int))
    t, ps = rows[:, 0], rows[:, 1:4]
    far = np.abs(t[None, :] - t[k, None]) >= RESOLUTION_EXCLUDE_S  # (len(k), n)
    k_ok = far.sum(axis=1) >= NEIGHBOURS
    if not np.any(k_ok):
        return 0.0
    k, far = k[k_ok], far[k_ok]
    d2 = _phase_distances(rows, rows[k, 4], rows[k, 5])
    if d2 is None:  # the instantaneous form: against the reading at the stop
        return float(np.percentile(np.linalg.norm(ps[k] - ps[0], axis=1), 90))
    d2 = np.where(far, d2, np.inf)
    near = np.argsort(d2, axis=1, kind="stable")[:, :NEIGHBOURS]  # ties: the earliest, as F5
    d = np.linalg.norm(ps[k] - ps[near].mean(axis=1), axis=1)
    return float(np.percentile(d, 90))

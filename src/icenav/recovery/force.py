"""Returns that stay safe: the contact force the operator's own trace produced at each
recorded state, and the limit a return along the roadmap must keep (beyond the paper).

A return replays travelled states, which is safe only while the anatomy is where it was.
When the patient moved, the same motor states push the catheter into a wall. With a
contact-force channel on the robot (a load cell at the sheath, tendon tensions, or drive
currents: :class:`ForceSensor`, None when the robot has none), the roadmap's recorder keeps,
per vertex, the largest force read while the *operator* drove through it
(:class:`ForceMap`; states a return or a refinement commanded are not the operator's trace
and are not recorded). Along a return (Eq. F1), at path point ``i`` between vertices
``v_i`` and ``v_(i+1)``, with ``F_rec = max(F_rec(v_i), F_rec(v_(i+1)))`` and ``F_rec(v)``
the largest force recorded within epsilon of ``v`` (the operator passed those states at
other moments of the beat and the breath)::

    F_measured  <=  F_rec + margin_n + margin_fraction * F_rec                    (F1)

else the return stops, says so (the task fails with the reason) and the robot holds.
Vertices without a recorded force (never driven by the operator with the sensor on) take
the nearest recorded value along the path; a path with none has no check. Without a force
channel there is no check at all (documented in ``docs/view-recovery.md``).

With a tracker, the reference is also keyed by the measured tip pose (Eq. F2,
:class:`TipForceMap`); a return stops only when the force has stayed above its limit for a
hold time (Eq. F4, :class:`ForceCheck`), and it stops as it starts when the tracked tip has
moved with the motors still since the operator last moved them (Eq. F5,
:mod:`icenav.recovery.drift`, :attr:`ForceRecord.rest`): the patient moved and carried the
catheter.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.errors import ConfigurationError, ShapeError
from icenav.recovery.drift import REST_Q_TOLERANCE, Phases, RestReference, check_q
from icenav.recovery.roadmap import IntArray, Roadmap

__all__ = [
    "CHECK_MARGIN_FRACTION",
    "CHECK_MARGIN_N",
    "DEFAULT_ANGLE_DEG",
    "DEFAULT_MARGIN_FRACTION",
    "DEFAULT_MARGIN_N",
    "DEFAULT_HOLD_S",
    "DEFAULT_MIN_SPACING_MM",
    "DEFAULT_RADIUS_MM",
    "ForceCheck",
    "ForceMap",
    "ForceRecord",
    "ForceStop",
    "ForceSensor",
    "PathForces",
    "TipForceMap",
    "TipIndex",
    "TipTrace",
    "effective_offset",
    "force_excess",
    "force_limit",
    "shape_reference",
]

DEFAULT_MARGIN_N = 0.1
"""Absolute margin of Eq. (F1) (N)."""
DEFAULT_MARGIN_FRACTION = 1.0
"""Relative margin of Eq. (F1): the contact force at the same motor state varies with the
heart beat, breathing and the shaft's lost motion roughly in proportion to it (on the twin
in vivo a state the operator passed at 3.3 N read up to 5.7 N on a later return). Measured
false alarms and what a shift adds: ``docs/view-recovery.md``."""


class ForceSensor(Protocol):
    """A robot's contact-force channel (a real robot may estimate it from the drive currents,
    the tendon tensions or a load cell at the sheath)."""

    def contact_force_n(self) -> float | None:
        """Total contact force on the catheter now (N), None when unavailable."""
        ...


class ForceMap:
    """Per roadmap vertex, the largest contact force the operator's trace produced there (N).

    Parameters
    ----------
    capacity : int
        Initial number of vertex slots (grown by doubling).
    """

    def __init__(self, capacity: int = 1024) -> None:
        self._f = np.full(max(16, int(capacity)), np.nan)
        self._n = 0

    @property
    def n_recorded(self) -> int:
        """Vertices with a recorded force."""
        return int(np.count_nonzero(np.isfinite(self._f[: self._n])))

    def record(self, vertex: int, force_n: float | None) -> None:
        """Note ``force_n`` (N) read at ``vertex`` while the operator drove (ignored when the
        vertex is -1, not recorded, or the force is None)."""
        if vertex < 0 or force_n is None:
            return
        f = float(force_n)
        if not (math.isfinite(f) and f >= 0.0):
            raise ConfigurationError(f"a contact force must be finite and >= 0 N, got {force_n}")
        if vertex >= len(self._f):
            grown = np.full(max(2 * len(self._f), vertex + 1), np.nan)
            grown[: len(self._f)] = self._f
            self._f = grown
        old = self._f[vertex]
        self._f[vertex] = f if not np.isfinite(old) else max(float(old), f)
        self._n = max(self._n, vertex + 1)

    def at(self, vertices: ArrayLike) -> Array:
        """Recorded force (N) at each vertex id (NaN where none)."""
        ids = np.asarray(vertices, np.int64)
        out = np.full(ids.shape, np.nan)
        ok = (ids >= 0) & (ids < self._n)
        out[ok] = self._f[ids[ok]]
        return out

    def profile(
        self, roadmap: Roadmap, path: ArrayLike, radius: float | None = None
    ) -> Array | None:
        """The recorded force (N) at each state of a planned ``path`` (n, 4): the largest
        recorded at the vertices within ``radius`` of it (metric units; default the
        roadmap's epsilon: the operator passed them at other moments of the beat and the
        breath), gaps filled with the nearest recorded value along the path; None when no
        state of the path has one (no check)."""
        p = np.asarray(path, np.float64)
        if p.ndim != 2 or p.shape[1] != 4:
            raise ShapeError(f"path must have shape (n, 4), got {p.shape}")
        r = roadmap.epsilon if radius is None else float(radius)
        f = np.full(len(p), np.nan)
        for i, q in enumerate(p):
            ids, _ = roadmap.neighbours(q, r)
            vals = self.at(ids)
            if np.isfinite(vals).any():
                f[i] = float(np.nanmax(vals))
        known = np.flatnonzero(np.isfinite(f))
        if not len(known):
            return None
        nearest = known[np.abs(np.arange(len(p))[:, None] - known[None, :]).argmin(axis=1)]
        out: Array = f[nearest]
        return out


def force_limit(
    profile: Array,
    index: int,
    margin_n: float = DEFAULT_MARGIN_N,
    margin_fraction: float = DEFAULT_MARGIN_FRACTION,
) -> tuple[float, float]:
    """(recorded force, limit) of Eq. (F1) between path states ``index`` and ``index + 1``
    (N)."""
    i = min(max(int(index), 0), len(profile) - 1)
    j = min(i + 1, len(profile) - 1)
    rec = max(float(profile[i]), float(profile[j]))
    return rec, rec + float(margin_n) + float(margin_fraction) * rec


def force_excess(
    profile: Array,
    index: int,
    force_n: float,
    margin_n: float = DEFAULT_MARGIN_N,
    margin_fraction: float = DEFAULT_MARGIN_FRACTION,
) -> float:
    """How far ``force_n`` exceeds the limit of Eq. (F1) between path states ``index`` and
    ``index + 1`` (N; <= 0: within)."""
    return float(force_n) - force_limit(profile, index, margin_n, margin_fraction)[1]


DEFAULT_RADIUS_MM = 4.0
"""Radius of the tip positions whose recorded forces form the reference of Eq. (F2) (mm):
chosen on the development pairs among 4 and 8 mm with the hold of Eq. (F4)
(``icenav.eval.force_study``, ``docs/view-recovery.md``; 8 mm without the hold)."""
DEFAULT_ANGLE_DEG = 180.0
"""Largest angle between the tip's axis now and a recorded one for Eq. (F2) (deg); 180: the
position alone (30 deg did no better at 4 mm on the development pairs)."""
DEFAULT_MIN_SPACING_MM = 0.5
"""Tip readings of the controller's record closer than this to the last kept one, with no
larger force, are not kept (mm)."""


class TipForceMap:
    """The contact forces the operator's trace produced, keyed by where the catheter *was*:
    the measured tip position and axis (EM, base frame) of each reading.

    The force follows the catheter's shape, not its motor state: the same motor state with
    another lost motion of the shaft is another shape (the tip millimetres deeper into a
    wall), while the same tip pose reached by other motor states touches the same walls.
    Along a return, with ``p``, ``z`` the measured tip position (mm) and axis now::

        F_ref(p, z) = max { F_k : |p_k - p| <= r, angle(z_k, z) <= a }         (F2)

    over the operator's readings ``k`` (the operator passed there at other moments of the
    beat and the breath), and the check of Eq. (F1) uses the larger of ``F_ref`` and the
    motor state's recorded force. Where the operator never had the tip (no reading within
    ``r`` and ``a``) the motor state's reference of Eq. (F1) stands. The anatomy is fixed in the
    base frame unless the patient moves: then the same tip pose touches a moved wall, and
    the force rises above the reference.

    Parameters
    ----------
    radius_mm : float
        ``r`` (mm).
    angle_deg : float
        ``a`` (deg).
    min_spacing_mm : float
        A reading within this of the last one kept, with no larger force, is not kept (a
        still or slow catheter adds no rows; the controller uses 0.5 mm; 0: every reading).
    """

    def __init__(
        self,
        radius_mm: float = DEFAULT_RADIUS_MM,
        angle_deg: float = DEFAULT_ANGLE_DEG,
        min_spacing_mm: float = 0.0,
    ) -> None:
        if not (math.isfinite(radius_mm) and radius_mm > 0):
            raise ConfigurationError(f"radius_mm must be > 0 mm, got {radius_mm}")
        if not (math.isfinite(angle_deg) and 0 < angle_deg <= 180):
            raise ConfigurationError(f"angle_deg must be in (0, 180] deg, got {angle_deg}")
        if not (math.isfinite(min_spacing_mm) and 0 <= min_spacing_mm < radius_mm):
            raise ConfigurationError(
                f"min_spacing_mm must be in [0, radius_mm) mm, got {min_spacing_mm}"
            )
        self.radius_mm = float(radius_mm)
        self.angle_deg = float(angle_deg)
        self.min_spacing_mm = float(min_spacing_mm)
        self._buf = np.zeros((64, 7))
        self._n = 0
        self._cached: TipIndex | None = None

    @property
    def n_samples(self) -> int:
        """Readings recorded."""
        return self._n

    def record(self, tip2base: ArrayLike | None, force_n: float | None) -> None:
        """Note ``force_n`` (N) read with the tip at ``tip2base`` (4, 4) (mm) while the
        operator drove (ignored when either is None)."""
        if tip2base is None or force_n is None:
            return
        f = float(force_n)
        if not (math.isfinite(f) and f >= 0.0):
            raise ConfigurationError(f"a contact force must be finite and >= 0 N, got {force_n}")
        t = np.asarray(tip2base, np.float64)
        if t.shape != (4, 4) or not np.all(np.isfinite(t)):
            raise ShapeError(f"tip2base must be a finite (4, 4) pose, got shape {t.shape}")
        z = t[:3, 2] / max(float(np.linalg.norm(t[:3, 2])), 1e-12)
        if self.min_spacing_mm > 0 and self._n:
            last = self._buf[self._n - 1]
            near = math.dist(last[:3], t[:3, 3]) < self.min_spacing_mm
            if near and f <= last[6] and float(np.dot(last[3:6], z)) >= self._cos:
                return
        self._append(np.concatenate([t[:3, 3], z, [f]])[None, :])

    def _append(self, rows: Array) -> None:
        """Append (k, 7) rows; rows below the count never change (a reader may copy them
        from another thread)."""
        need = self._n + len(rows)
        if need > len(self._buf):
            grown = np.zeros((max(2 * len(self._buf), need), 7))
            grown[: self._n] = self._buf[: self._n]
            self._buf = grown
        self._buf[self._n : need] = rows
        self._n = need

    @property
    def _cos(self) -> float:
        return math.cos(math.radians(self.angle_deg))

    def samples(self, stop: int | None = None) -> Array:
        """(n, 7) the readings below ``stop`` (default all): tip position (mm), tip axis
        (unit), force (N)."""
        n = self._n if stop is None else min(int(stop), self._n)
        return self._buf[:n].copy()

    @classmethod
    def from_samples(
        cls,
        samples: ArrayLike,
        radius_mm: float = DEFAULT_RADIUS_MM,
        angle_deg: float = DEFAULT_ANGLE_DEG,
    ) -> TipForceMap:
        """A map holding ``samples`` (n, 7) as :meth:`samples` gives them."""
        a = np.asarray(samples, np.float64)
        if a.ndim != 2 or a.shape[1] != 7 or not np.all(np.isfinite(a)):
            raise ShapeError(f"samples must be finite with shape (n, 7), got {a.shape}")
        out = cls(radius_mm, angle_deg)
        out._append(a)
        return out

    def index(self, stop: int | None = None) -> TipIndex:
        """The readings below ``stop`` (default all) as a searchable, immutable index: may be
        built on another thread than the one recording (69,000 readings took 30-700 ms)."""
        return TipIndex(self.samples(stop), self.radius_mm, self.angle_deg)

    def reference(self, tip2base: ArrayLike | None) -> float | None:
        """``F_ref`` of Eq. (F2) at the tip pose ``tip2base`` (4, 4) (N); None when the
        operator never had the tip within the radius and angle (or no pose was read). The
        index is rebuilt here after new readings (see :meth:`index` to build it elsewhere)."""
        if self._cached is None or self._cached.n_samples != self._n:
            self._cached = self.index()
        return self._cached.reference(tip2base)


class TipIndex:
    """Eq. (F2) over a fixed set of tip readings (:meth:`TipForceMap.index`).

    Parameters
    ----------
    samples : (n, 7) array
        Tip position (mm), axis (unit), force (N).
    radius_mm, angle_deg : float
        ``r`` and ``a`` of Eq. (F2).
    """

    def __init__(self, samples: Array, radius_mm: float, angle_deg: float) -> None:
        from scipy.spatial import cKDTree  # a kept library for the radius queries

        self._data = np.asarray(samples, np.float64).reshape(-1, 7)
        self._tree = cKDTree(self._data[:, :3]) if len(self._data) else None
        self.radius_mm = float(radius_mm)
        self._cos = math.cos(math.radians(float(angle_deg)))

    @property
    def n_samples(self) -> int:
        """Readings indexed."""
        return len(self._data)

    def reference(self, tip2base: ArrayLike | None) -> float | None:
        """``F_ref`` of Eq. (F2) at ``tip2base`` (4, 4) (N); None without a reading near."""
        if self._tree is None or tip2base is None:
            return None
        t = np.asarray(tip2base, np.float64)
        if t.shape != (4, 4):
            raise ShapeError(f"tip2base must be a (4, 4) pose, got shape {t.shape}")
        ids = self._tree.query_ball_point(t[:3, 3], self.radius_mm)
        if not ids:
            return None
        rows = self._data[ids]
        z = t[:3, 2] / max(float(np.linalg.norm(t[:3, 2])), 1e-12)
        ok = rows[:, 3:6] @ z >= self._cos
        if not ok.any():
            return None
        return float(rows[ok, 6].max())


class TipTrace:
    """Per roadmap vertex, the mean measured tip position (EM, base frame, mm) of the
    operator's trace there: where the catheter *was* at that motor state.

    Parameters
    ----------
    capacity : int
        Initial number of vertex slots (grown by doubling).
    """

    def __init__(self, capacity: int = 1024) -> None:
        self._sum = np.zeros((max(16, int(capacity)), 3))
        self._count = np.zeros(len(self._sum), np.int64)
        self._n = 0

    @property
    def n_recorded(self) -> int:
        """Vertices with a recorded tip position."""
        return int(np.count_nonzero(self._count[: self._n]))

    def record(self, vertex: int, tip2base: ArrayLike | None) -> None:
        """Note the tip pose ``tip2base`` (4, 4) (mm) measured at ``vertex`` while the operator
        drove (ignored when the vertex is -1 or the pose is None)."""
        if vertex < 0 or tip2base is None:
            return
        t = np.asarray(tip2base, np.float64)
        if t.shape != (4, 4) or not np.all(np.isfinite(t[:3, 3])):
            raise ShapeError(f"tip2base must be a finite (4, 4) pose, got shape {t.shape}")
        self._grow(vertex)
        self._sum[vertex] += t[:3, 3]
        self._count[vertex] += 1
        self._n = max(self._n, vertex + 1)

    def rows(self) -> tuple[IntArray, Array, IntArray]:
        """(vertex ids (k,), position sums (k, 3) mm, counts (k,)) of the recorded vertices
        (what a session stores)."""
        ids = np.flatnonzero(self._count[: self._n]).astype(np.int64)
        return ids, self._sum[ids].copy(), self._count[ids].copy()

    def add_rows(self, ids: ArrayLike, sums: ArrayLike, counts: ArrayLike) -> None:
        """Merge rows as :meth:`rows` gives them (a session reopened)."""
        i = np.asarray(ids, np.int64).reshape(-1)
        s = np.asarray(sums, np.float64).reshape(-1, 3)
        c = np.asarray(counts, np.int64).reshape(-1)
        if not (len(i) == len(s) == len(c)) or (len(i) and (i.min() < 0 or c.min() < 1)):
            raise ShapeError("tip trace rows must be ids >= 0, (k, 3) sums and counts >= 1")
        for v, sv, cv in zip(i, s, c, strict=True):
            self._grow(int(v))
            self._sum[v] += sv
            self._count[v] += cv
            self._n = max(self._n, int(v) + 1)

    def _grow(self, vertex: int) -> None:
        if vertex >= len(self._sum):
            size = max(2 * len(self._sum), vertex + 1)
            s, c = np.zeros((size, 3)), np.zeros(size, np.int64)
            s[: len(self._sum)], c[: len(self._count)] = self._sum, self._count
            self._sum, self._count = s, c

    def mean_at(self, vertices: ArrayLike) -> Array:
        """(k, 3) mean tip position (mm) at each vertex id (NaN where none)."""
        ids = np.asarray(vertices, np.int64).reshape(-1)
        out = np.full((len(ids), 3), np.nan)
        ok = (ids >= 0) & (ids < self._n)
        ok[ok] = self._count[ids[ok]] > 0
        out[ok] = self._sum[ids[ok]] / self._count[ids[ok], None]
        return out


def effective_offset(tip_now: ArrayLike, tip_then: ArrayLike) -> tuple[float, float]:
    """The shaft's lost motion between the operator's pass and now, from the measured tip
    positions (mm, base frame) at the same motor state, Eq. (F3)::

        d_rho = atan2(y, x) - atan2(y', x')      (rad, roll about the base axis z)
        d_s   = z - z'                            (mm, along the base axis)

    The roll is 0 when either tip lies within 1 mm of the base axis."""
    p = np.asarray(tip_now, np.float64).reshape(3)
    p0 = np.asarray(tip_then, np.float64).reshape(3)
    d_rho = 0.0
    if math.hypot(p[0], p[1]) > 1.0 and math.hypot(p0[0], p0[1]) > 1.0:
        d_rho = math.atan2(p[1], p[0]) - math.atan2(p0[1], p0[0])
        d_rho = (d_rho + math.pi) % (2.0 * math.pi) - math.pi
    return d_rho, float(p[2] - p0[2])


def shape_reference(
    forces: ForceMap,
    tips: TipTrace,
    roadmap: Roadmap,
    q: ArrayLike,
    tip2base: ArrayLike | None,
    radius: float | None = None,
) -> float | None:
    """The operator's recorded force where the catheter's shape now was (N), Eq. (F3):
    the lost motion since the operator's pass at motor state ``q`` (4,) from the tip
    measured now (``tip2base``, (4, 4) mm) and the operator's mean tip at the vertices within
    ``radius`` (metric units; default the roadmap's epsilon) of ``q``, then the largest force
    recorded within ``radius`` of the effective state ``q + (0, 0, d_rho, d_s)``: the motor
    state at which the operator had this shape. None when either is unknown."""
    if tip2base is None:
        return None
    r = roadmap.epsilon if radius is None else float(radius)
    qa = np.asarray(q, np.float64).reshape(4)
    ids, _ = roadmap.neighbours(qa, r)
    then = tips.mean_at(ids)
    ok = np.isfinite(then[:, 0])
    if not ok.any():
        return None
    d_rho, d_s = effective_offset(np.asarray(tip2base, np.float64)[:3, 3], then[ok][0])
    q_eff = qa + np.array([0.0, 0.0, d_rho, d_s])
    eff_ids, _ = roadmap.neighbours(q_eff, r)
    vals = forces.at(eff_ids)
    if not np.isfinite(vals).any():
        return None
    return float(np.nanmax(vals))


class ForceRecord:
    """The operator's contact forces a session keeps: per roadmap vertex (:class:`ForceMap`,
    Eq. F1) and per measured tip pose (:class:`TipForceMap`, Eq. F2), with what a store has
    not written yet.

    Threads: :meth:`record` runs on the thread that drives (the control loop);
    :meth:`take_vertex_rows` may run on another (a lock guards the changed vertices); a
    writer may read :meth:`tip_rows` below a count taken before (the tip readings are
    append-only).

    Parameters
    ----------
    forces : ForceMap, optional
    tips : TipForceMap, optional
    """

    def __init__(self, forces: ForceMap | None = None, tips: TipForceMap | None = None) -> None:
        self.forces = forces if forces is not None else ForceMap()
        self.tips = tips if tips is not None else TipForceMap(min_spacing_mm=DEFAULT_MIN_SPACING_MM)
        self._dirty: set[int] = set()
        self._lock = threading.Lock()
        self.rest: RestReference | None = None
        """Where the operator's last motion left the tip (Eq. F5), None when unknown or
        when anything else moved the motors since."""
        self._stop_phases_due = False

    @property
    def rest_tip(self) -> Array | None:
        """(3,) where the tracked tip was (mm, base frame) when the operator last moved the
        motors, None when unknown or when anything else moved them since (Eq. F5)."""
        return None if self.rest is None else self.rest.tip

    @property
    def rest_q(self) -> Array | None:
        """(4,) the motor state (rad, rad, rad, mm) the operator left with the tip at
        :attr:`rest_tip`; None with it or when not known."""
        return None if self.rest is None or self.rest.q is None else self.rest.q.copy()

    def note_motion(
        self, tip2base: ArrayLike | None, operator: bool, q: ArrayLike | None = None,
        t: float = 0.0,
    ) -> None:  # fmt: skip
        """The motors moved this cycle (time ``t``, s): by the operator to motor state ``q``
        (4,) with the tip at ``tip2base`` (4, 4) (mm; None: no pose read), or by anything
        else (a return, a refinement: the rest pose is forgotten). The phases of this
        reading are read at the first still reading (:meth:`note_still`), not at every
        moving cycle."""
        self._stop_phases_due = False
        if not operator or tip2base is None:
            self.rest = None
            return
        pose = np.asarray(tip2base, np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose[:3, 3])):
            raise ShapeError(f"tip2base must be a finite (4, 4) pose, got shape {pose.shape}")
        self.rest = RestReference(t, pose, q)
        self._stop_phases_due = True

    def note_still(
        self, t: float, tip2base: ArrayLike | None, signals: Callable[[float], Phases]
    ) -> None:
        """A reading of the tip with the motors still at time ``t`` (s); ``signals(t)`` the
        respiratory signal and the cardiac phase at a time: part of the rest reference while
        its window lasts (Eq. F5, phase-matched), the stop's phases read with the first."""
        rest = self.rest
        if rest is None or tip2base is None or not rest.wants(t):
            return
        if self._stop_phases_due:
            rest.set_stop_phases(*signals(rest.t0))
            self._stop_phases_due = False
        rest.add(t, tip2base, *signals(t))

    def wants_still_readings(self, t: float) -> bool:
        """Whether :meth:`note_still` at ``t`` (s) would keep a reading."""
        return self.rest is not None and self.rest.wants(t)

    def restore_rest(self, rest_tip: ArrayLike, rest_q: ArrayLike) -> None:
        """The rest pose read back from a session (``rest_tip`` (3,) mm, ``rest_q`` (4,)):
        valid while the motors stand where the operator left them (:meth:`keep_rest_if_at`);
        a single reading, so Eq. (F5) takes its instantaneous form."""
        tip = np.asarray(rest_tip, np.float64).reshape(-1)
        if tip.shape != (3,) or not np.all(np.isfinite(tip)):
            raise ShapeError(f"rest_tip must be 3 finite mm, got {rest_tip!r}")
        self.rest = RestReference(-math.inf, tip, check_q(rest_q, "rest_q"))

    def keep_rest_if_at(self, q: ArrayLike, tolerance: float = REST_Q_TOLERANCE) -> bool:
        """Keep the rest pose only if the motors stand at ``q`` (4,) within ``tolerance``
        (rad or mm, per joint) of where the operator left them: after a restart, motors that
        moved meanwhile (homed, power-cycled, driven by hand) leave the tip anywhere, so Eq.
        (F5) has no reference until the operator drives again. Returns whether it is kept."""
        if self.rest is None:
            return False
        rest_q = self.rest.q
        if rest_q is not None and np.max(np.abs(check_q(q, "q") - rest_q)) <= tolerance:
            return True
        self.rest = None  # moved, or a rest without its motor state: not trusted
        return False

    def record(self, vertex: int, force_n: float | None, tip2base: ArrayLike | None) -> None:
        """Note a reading of the operator's trace: the force (N) at ``vertex`` and, with a
        tip pose (4, 4) (mm), at that pose."""
        if force_n is None:
            return
        self.forces.record(vertex, force_n)
        if vertex >= 0:
            with self._lock:
                self._dirty.add(int(vertex))
        self.tips.record(tip2base, force_n)

    def take_vertex_rows(self) -> list[tuple[int, float]]:
        """(vertex, force N) of the vertices changed since the last call (for the store)."""
        with self._lock:
            ids = sorted(self._dirty)
            self._dirty.clear()
        return [(v, float(f)) for v, f in zip(ids, self.forces.at(ids).tolist(), strict=True)]

    @property
    def n_tip_rows(self) -> int:
        """Tip readings recorded (append-only)."""
        return self.tips.n_samples

    def tip_rows(self, start: int, stop: int) -> list[tuple[float, ...]]:
        """Tip readings ``start .. stop - 1``: position (mm), axis, force (N)."""
        return [tuple(r) for r in self.tips.samples(stop)[start:].tolist()]

    @classmethod
    def from_rows(
        cls, vertex_rows: ArrayLike, tip_rows: ArrayLike, radius_mm: float = DEFAULT_RADIUS_MM,
        angle_deg: float = DEFAULT_ANGLE_DEG, rest: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> ForceRecord:  # fmt: skip
        """A record restored from a session: (k, 2) vertex / force rows, (n, 7) tip rows and
        the rest pose (tip (3,) mm, motor state (4,)) or None."""
        vr = np.asarray(vertex_rows, np.float64).reshape(-1, 2)
        tips = TipForceMap.from_samples(
            np.asarray(tip_rows, np.float64).reshape(-1, 7), radius_mm, angle_deg
        )
        tips.min_spacing_mm = DEFAULT_MIN_SPACING_MM
        out = cls(tips=tips)
        for v, f in vr.tolist():
            out.forces.record(int(v), f)
        if rest is not None:
            out.restore_rest(*rest)
        return out


class PathForces:
    """The recorded force of Eq. (F1) along a planned path, found as a return goes (a few
    roadmap queries per control cycle instead of the whole path at once: a path of 500
    states took 40-230 ms with :meth:`ForceMap.profile`, many control cycles).

    ``recorded(i)`` is ``max(F(i), F(i + 1))`` with ``F(j)`` the largest force recorded within
    ``radius`` of path state ``j``; a state without one takes the last one before it along
    the path, and before the first one the first found ahead within the states looked up so
    far (``ahead`` states beyond ``i``); None while none is known (no check).

    Parameters
    ----------
    forces : ForceMap
    roadmap : Roadmap
    path : array-like, shape (n, 4)
    radius : float, optional
        Metric units; default the roadmap's epsilon.
    ahead : int
        Path states looked up beyond the current one.
    """

    def __init__(
        self,
        forces: ForceMap,
        roadmap: Roadmap,
        path: ArrayLike,
        radius: float | None = None,
        ahead: int = 8,
    ) -> None:
        p = np.asarray(path, np.float64)
        if p.ndim != 2 or p.shape[1] != 4:
            raise ShapeError(f"path must have shape (n, 4), got {p.shape}")
        self._forces, self._roadmap, self._path = forces, roadmap, p
        self._r = roadmap.epsilon if radius is None else float(radius)
        self._ahead = max(1, int(ahead))
        self._raw = np.full(len(p), np.nan)
        self._n = 0  # states looked up

    def _look_up(self, upto: int) -> None:
        while self._n < min(upto, len(self._path)):
            ids, _ = self._roadmap.neighbours(self._path[self._n], self._r)
            vals = self._forces.at(ids)
            if np.isfinite(vals).any():
                self._raw[self._n] = float(np.nanmax(vals))
            self._n += 1

    def _at(self, j: int) -> float | None:
        if np.isfinite(self._raw[j]):
            return float(self._raw[j])
        before = np.flatnonzero(np.isfinite(self._raw[:j]))
        if len(before):
            return float(self._raw[before[-1]])
        after = np.flatnonzero(np.isfinite(self._raw[j : self._n]))
        return float(self._raw[j + after[0]]) if len(after) else None

    def recorded(self, index: int) -> float | None:
        """The operator's force (N) between path states ``index`` and ``index + 1``."""
        i = min(max(int(index), 0), len(self._path) - 1)
        j = min(i + 1, len(self._path) - 1)
        self._look_up(j + 1 + self._ahead)
        vals = [v for v in (self._at(i), self._at(j)) if v is not None]
        return max(vals) if vals else None


DEFAULT_HOLD_S = 0.5
"""Time the force must stay above the limit before a return stops, Eq. (F4) (s): chosen
on the development pairs among 0, 0.25 and 0.5 s (``docs/view-recovery.md``)."""
CHECK_MARGIN_N = 0.1
"""The product's absolute margin with the hold of Eq. (F4) (N), chosen on the development
pairs from 0.05 N up (about a force channel's resolution)."""
CHECK_MARGIN_FRACTION = 0.5
"""The product's relative margin with the hold of Eq. (F4), chosen on the development
pairs (0.5 and 1.0 considered)."""


@dataclass(frozen=True)
class ForceStop:
    """Why a return stops: the force above its limit for the hold time (Eq. F4)."""

    force_n: float
    """Contact force read when it stopped (N)."""
    recorded_n: float
    """The operator's reference there (N), Eq. (F1) or (F2)."""
    limit_n: float
    """The limit (N): reference + absolute margin + relative margin * reference."""
    held_s: float
    """How long the force had been above its limit (s)."""


class ForceCheck:
    """The stop rule of a return, Eq. (F4): the force read at each control cycle ``k`` is
    held against the limit of Eq. (F1) or (F2) there, and the return stops when it has been
    above it at every cycle of the last ``hold_s`` seconds::

        L_k = F_ref,k + margin_n + margin_fraction * F_ref,k
        stop at k  when  F_j > L_j  for every cycle j with  t_k - t_j < hold_s     (F4)

    A catheter slipping over a wall or the heart pushing it for a moment exceeds the
    reference briefly; a moved patient pushes it for as long as the return presses on.
    ``hold_s = 0`` stops at the first cycle above the limit (Eq. F1 as it was). Equivalent
    on a recorded series: the return stops iff the ``hold_s``-window minimum of
    ``F_k - (1 + margin_fraction) F_ref,k`` exceeds ``margin_n`` (what
    :mod:`icenav.eval.force_study` computes).

    Parameters
    ----------
    margin_n : float
        Absolute margin (N).
    margin_fraction : float
        Relative margin (fraction of the reference).
    hold_s : float
        Time above the limit before a stop (s).
    """

    def __init__(
        self,
        margin_n: float = DEFAULT_MARGIN_N,
        margin_fraction: float = DEFAULT_MARGIN_FRACTION,
        hold_s: float = DEFAULT_HOLD_S,
    ) -> None:
        for name, value in (("margin_n", margin_n), ("margin_fraction", margin_fraction),
                            ("hold_s", hold_s)):  # fmt: skip
            if not (math.isfinite(value) and value >= 0):
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")
        self.margin_n = float(margin_n)
        self.margin_fraction = float(margin_fraction)
        self.hold_s = float(hold_s)
        self._over_s = -1.0  # time above the limit so far (s); < 0: below it

    def limit(self, recorded_n: float) -> float:
        """The limit (N) over a reference ``recorded_n`` (N), Eq. (F1)."""
        return recorded_n + self.margin_n + self.margin_fraction * recorded_n

    def update(self, force_n: float, recorded_n: float | None, dt: float) -> ForceStop | None:
        """One control cycle ``dt`` (s) after the last: the force read (N) and the reference
        there (N; None: no reference, the cycle counts as below the limit). A ForceStop
        when the return must stop (Eq. F4), else None."""
        if recorded_n is None:
            self._over_s = -1.0
            return None
        limit = self.limit(float(recorded_n))
        if not float(force_n) > limit:
            self._over_s = -1.0
            return None
        self._over_s = 0.0 if self._over_s < 0 else self._over_s + max(float(dt), 0.0)
        if self._over_s + 1e-9 < self.hold_s:
            return None
        return ForceStop(float(force_n), float(recorded_n), limit, self._over_s)

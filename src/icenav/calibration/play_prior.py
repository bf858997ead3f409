"""A documented prior of a catheter model's roll and twist plays, for the short calibration
(beyond the paper; an explicit option, never a default).

The full calibration measures the roll's and the twist's plays over the knob plane (the
bend's size and direction, :class:`~icenav.compensation.bend_play.KnobPlanePlay`) with seven
roll sweeps; the short calibration has room for two (straight, and bent along the AP knob
at one bend) and reads each play as a line through one point. A lab that owns several
catheters of one product line can run the full calibration once on a few of them and store
the *shape* of their plays: for each catheter ``j`` the law normalised by its own value
along the AP knob at the reference bend ``b_ref`` (:data:`REFERENCE_BEND`), averaged over
the catheters on a grid of bends and directions::

    P(b, psi) = mean_j  e_j(b, psi) / e_j(b_ref, 0)                                 (P0)

A short calibration of another catheter of the same line then measures the level at its
one bent sweep, the play ``e_s`` at the tracked bend ``b_s`` along the AP knob, and uses::

    e(b, psi) = e_s * P(b, psi) / P(b_s, 0)                                          (P1)

per play (the roll's, the twist's). What it assumes: the catheters of the line share the
plays' shape over the bend and their ratio between directions (measured on the prior's own
catheters, the spread is stored); only the level differs from catheter to catheter, in the
same proportion at every bend and direction. What it does not assume: any level (it is the
short calibration's reading), the form of the friction (the full calibration's laws, chosen
by held-out residual, are tabulated). A catheter of another line, or one whose play shape
differs, is mis-compensated where the shapes differ; without a prior the short calibration
keeps its lines. The file is made by :func:`make_play_prior` from the full calibrations'
compensators and stored by :func:`save_play_prior` (JSON, :data:`PRIOR_VERSION`).

*The twist as a spin meets it* (version 3, optional): the full calibration reads the twist on
its spin circle over the whole knob plane (period 360 deg,
:mod:`icenav.calibration.twist_circle`), which the short calibration's bent sweep, held in one
direction, does not see; the twist it reads there differs from the circle's by more than a
level. So the prior may also store, for each catheter ``j``, the full calibration's twist law
``h_j(b, psi)`` divided by what the short calibration's own bent sweep read on the same
catheter, ``s_j`` (the short plan's pace and step, :func:`~icenav.calibration.short.
short_twist_reading`), averaged::

    T(b, psi) = mean_j  h_j(b, psi) / s_j,        h(b, psi) = s * T(b, psi)           (T0, T1)

on :data:`CIRCLE_TWIST_DIRECTIONS`; a short calibration reading ``s`` gets (T1) instead of
(P1)'s twist. It assumes the same as (P1): one proportion between the short reading and the
circle's law for every catheter of the line.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.calibration.map_prior import MapPrior, map_prior_from_dict
from icenav.compensation.bend_play import BendPlay, KnobPlanePlay
from icenav.compensation.hysteresis import HysteresisCompensator
from icenav.errors import ConfigurationError, FileFormatError, UnsupportedVersionError

__all__ = [
    "CIRCLE_TWIST_DIRECTIONS",
    "MIN_REFERENCE_PLAY",
    "MIN_SHAPE",
    "PRIOR_BENDS",
    "PRIOR_DIRECTIONS",
    "PRIOR_VERSION",
    "REFERENCE_BEND",
    "PlayPrior",
    "load_play_prior",
    "make_play_prior",
    "make_twist_circle",
    "save_play_prior",
]

PRIOR_VERSION = 3
"""Version of the prior's JSON file (3: with the circle's twist, ``twist_circle``; 2: with
the map prior, ``map``; 1, without either; all are read)."""
CIRCLE_TWIST_DIRECTIONS = tuple(2.0 * math.pi * k / 12 for k in range(12))
"""Directions (rad over the whole knob plane) of the circle's twist table (T0)."""
REFERENCE_BEND = math.radians(75.0)
"""Bend (rad) at which each catheter's AP law is normalised to 1 in (P0): about the tracked
bend of the short calibration's bent sweep (50 deg of knob)."""
PRIOR_BENDS = tuple(math.radians(b) for b in range(5, 125, 5))
"""The grid of bends (rad) the prior is tabulated on: 5-120 deg."""
PRIOR_DIRECTIONS = (0.0, math.pi / 4, math.pi / 2, 3 * math.pi / 4)
"""The directions of the bend (rad in the knob plane) the prior is tabulated in: those the
full calibration sweeps."""
MIN_REFERENCE_PLAY = math.radians(0.1)
"""A catheter whose AP play at :data:`REFERENCE_BEND` is below this (rad) has no shape to
normalise and is left out of (P0)."""
MIN_SHAPE = 1e-3
"""A short reading at a bend where the prior's AP shape is below this (dimensionless: 1 at
the reference bend) cannot set a level: :meth:`PlayPrior.law` gives None (the line)."""


def _table(values: Any, name: str, shape: tuple[int, int]) -> tuple[tuple[float, ...], ...]:
    a = np.asarray(values, dtype=np.float64)
    if a.shape != shape or not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise ConfigurationError(
            f"the prior's {name} table must be {shape[0]} x {shape[1]} finite values >= 0, "
            f"got shape {a.shape}"
        )
    if np.any(np.diff(a, axis=1) < -1e-12):
        raise ConfigurationError(f"the prior's {name} table must not decrease with the bend")
    return tuple(tuple(float(v) for v in row) for row in a)


@dataclass(frozen=True, eq=False)
class PlayPrior:
    """(P0) of one product line: the roll's and the twist's normalised plays, one row per
    direction of :attr:`directions`, one column per bend of :attr:`bends` (dimensionless:
    the AP law at :data:`REFERENCE_BEND` is 1 for each catheter before averaging)."""

    product: str
    """The catheter model (product line) it describes."""
    catheters: tuple[str, ...]
    """The catheters whose full calibrations made it."""
    directions: tuple[float, ...]
    """Directions of the bend (rad, ascending in [0, pi))."""
    bends: tuple[float, ...]
    """Bends of the grid (rad, ascending, > 0)."""
    roll: tuple[tuple[float, ...], ...]
    """(n_directions, n_bends) the roll's normalised extra play."""
    twist: tuple[tuple[float, ...], ...]
    """(n_directions, n_bends) the twist's normalised play."""
    spread: tuple[float, float] = (math.nan, math.nan)
    """The catheters' RMS deviation from the mean shape (roll, twist; dimensionless, over
    the grid): how far one catheter's shape is from the line's."""
    map: MapPrior | None = None
    """The line's mean elasticity map (:mod:`icenav.calibration.map_prior`), if stored."""
    twist_circle: tuple[tuple[float, ...], ...] | None = None
    """(T0): (12, n_bends) the full calibrations' twist over :data:`CIRCLE_TWIST_DIRECTIONS`
    divided by the short calibration's twist reading on the same catheter (None: not
    stored)."""

    def __post_init__(self) -> None:
        d = np.asarray(self.directions, dtype=np.float64)
        b = np.asarray(self.bends, dtype=np.float64)
        if d.ndim != 1 or d.size == 0 or np.any(d < 0.0) or np.any(d >= math.pi):
            raise ConfigurationError(f"prior directions must be in [0, 180) deg, got {d!r}")
        if b.ndim != 1 or b.size < 2 or np.any(b <= 0.0) or np.any(np.diff(b) <= 0.0):
            raise ConfigurationError(f"prior bends must be ascending and > 0 rad, got {b!r}")
        if np.any(np.diff(d) <= 0.0):
            raise ConfigurationError(f"prior directions must be ascending, got {d!r}")
        object.__setattr__(self, "roll", _table(self.roll, "roll", (d.size, b.size)))
        object.__setattr__(self, "twist", _table(self.twist, "twist", (d.size, b.size)))
        if self.twist_circle is not None:
            shape = (len(CIRCLE_TWIST_DIRECTIONS), b.size)
            object.__setattr__(
                self, "twist_circle", _table(self.twist_circle, "twist_circle", shape)
            )

    def circle_twist(self, reading: float) -> KnobPlanePlay | None:
        """(T1): the twist over the whole knob plane (period 360 deg) for the short
        calibration's twist reading ``reading`` (rad, clipped at 0); None without the table
        or for a reading that is not finite."""
        if self.twist_circle is None or not math.isfinite(reading):
            return None
        scale = max(float(reading), 0.0)
        laws = tuple(
            BendPlay("table", (), self.bends, row).scaled(scale) for row in self.twist_circle
        )
        return KnobPlanePlay(CIRCLE_TWIST_DIRECTIONS, laws, period=2.0 * math.pi)  # (T1)

    def law(self, which: str, bend: float, extra: float) -> KnobPlanePlay | None:
        """(P1): the play ``which`` (``"roll"`` or ``"twist"``) over the knob plane, scaled
        so that along the AP knob it passes through the short calibration's reading
        ``extra`` (rad, clipped at 0) at the tracked ``bend`` (rad). None when the prior's
        AP shape is below :data:`MIN_SHAPE` there or the reading is not finite
        (the caller keeps its line)."""
        table = {"roll": self.roll, "twist": self.twist}.get(which)
        if table is None:
            raise ConfigurationError(f"which must be 'roll' or 'twist', got {which!r}")
        if not (math.isfinite(bend) and bend > 0.0 and math.isfinite(extra)):
            return None
        laws = [BendPlay("table", (), self.bends, row) for row in table]
        level = float(laws[0].at(bend))
        if level < MIN_SHAPE:
            return None
        scale = max(float(extra), 0.0) / level  # (P1)
        return KnobPlanePlay(self.directions, tuple(law.scaled(scale) for law in laws))

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (angles in deg)."""
        return {
            "format": "icenav play prior",
            "version": PRIOR_VERSION,
            "product": self.product,
            "catheters": list(self.catheters),
            "reference_bend_deg": math.degrees(REFERENCE_BEND),
            "directions_deg": [math.degrees(x) for x in self.directions],
            "bends_deg": [math.degrees(x) for x in self.bends],
            "roll": [list(r) for r in self.roll],
            "twist": [list(r) for r in self.twist],
            "spread": list(self.spread),
            **({"map": self.map.to_dict()} if self.map is not None else {}),
            **(
                {"twist_circle": [list(r) for r in self.twist_circle]}
                if self.twist_circle is not None
                else {}
            ),
        }


def _normalised(comp: HysteresisCompensator, which: str, d: Array, b: Array) -> Array | None:
    """(n_directions, n_bends) one catheter's play normalised by its AP value at the
    reference bend; None below :data:`MIN_REFERENCE_PLAY`."""
    law = comp.roll_extra if which == "roll" else comp.twist_extra
    ref = float(law(REFERENCE_BEND, 0.0))
    if ref < MIN_REFERENCE_PLAY:
        return None
    return np.array([np.asarray(law(b, psi), dtype=np.float64) for psi in d]) / ref  # (P0)


def make_play_prior(
    compensators: Sequence[HysteresisCompensator],
    product: str,
    catheters: Sequence[str],
    directions: Sequence[float] = PRIOR_DIRECTIONS,
    bends: Sequence[float] = PRIOR_BENDS,
) -> PlayPrior:
    """(P0) over the full calibrations' roll and twist plays (``compensators``, one per
    catheter of ``catheters``; e.g. ``fit_catheter(...).hysteresis.compensator``)."""
    if len(compensators) == 0 or len(compensators) != len(catheters):
        raise ConfigurationError(
            f"need one or more compensators and one name each, got {len(compensators)} and "
            f"{len(catheters)}"
        )
    d = np.asarray(directions, dtype=np.float64)
    b = np.asarray(bends, dtype=np.float64)
    tables: dict[str, Array] = {}
    spread: list[float] = []
    for which in ("roll", "twist"):
        shapes = [s for c in compensators if (s := _normalised(c, which, d, b)) is not None]
        if not shapes:
            raise ConfigurationError(
                f"no catheter has a {which} play of at least "
                f"{math.degrees(MIN_REFERENCE_PLAY):.1f} deg at "
                f"{math.degrees(REFERENCE_BEND):.0f} deg of bend: no shape to store"
            )
        stack = np.stack(shapes)
        mean = np.maximum.accumulate(np.mean(stack, axis=0), axis=1)
        tables[which] = mean
        spread.append(float(np.sqrt(np.mean((stack - mean) ** 2))))
    return PlayPrior(
        product=str(product),
        catheters=tuple(str(c) for c in catheters),
        directions=tuple(float(x) for x in d),
        bends=tuple(float(x) for x in b),
        roll=tables["roll"],  # type: ignore[arg-type]
        twist=tables["twist"],  # type: ignore[arg-type]
        spread=(spread[0], spread[1]),
    )


def make_twist_circle(
    compensators: Sequence[HysteresisCompensator],
    readings: Sequence[float],
    bends: Sequence[float] = PRIOR_BENDS,
) -> tuple[tuple[float, ...], ...]:
    """(T0) over the full calibrations' twist laws (``compensators``) and the short
    calibration's twist readings on the same catheters (``readings``, rad); a catheter whose
    reading is below :data:`MIN_REFERENCE_PLAY` is left out."""
    if len(compensators) == 0 or len(compensators) != len(readings):
        raise ConfigurationError(
            f"need one or more compensators and one reading each, got {len(compensators)} "
            f"and {len(readings)}"
        )
    b = np.asarray(bends, dtype=np.float64)
    rows = [
        np.array([np.asarray(c.twist_extra(b, psi)) for psi in CIRCLE_TWIST_DIRECTIONS]) / s
        for c, s in zip(compensators, readings, strict=True)
        if math.isfinite(s) and s >= MIN_REFERENCE_PLAY
    ]  # (T0)
    if not rows:
        raise ConfigurationError(
            f"no short twist reading of at least {math.degrees(MIN_REFERENCE_PLAY):.1f} deg: "
            "no circle twist to store"
        )
    mean = np.maximum.accumulate(np.mean(np.stack(rows), axis=0), axis=1)
    return tuple(tuple(float(v) for v in row) for row in mean)


def save_play_prior(prior: PlayPrior, path: str | Path) -> None:
    """Write ``prior`` as JSON to ``path`` (compact: one line)."""
    Path(path).write_text(json.dumps(prior.to_dict()) + "\n", encoding="utf-8")


def load_play_prior(path: str | Path) -> PlayPrior:
    """Read a prior written by :func:`save_play_prior`; raises FileFormatError (naming the
    file) on anything else and UnsupportedVersionError on a newer version."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{p}: not a readable play prior ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != "icenav play prior":
        raise FileFormatError(f"{p}: not an icenav play prior")
    if doc.get("version") not in (1, 2, PRIOR_VERSION):
        raise UnsupportedVersionError(
            f"{p}: play prior version {doc.get('version')!r}, this icenav reads {PRIOR_VERSION}"
        )
    ref = float(doc.get("reference_bend_deg", math.nan))
    if not math.isclose(ref, math.degrees(REFERENCE_BEND)):
        raise FileFormatError(
            f"{p}: reference bend {ref} deg, this icenav normalises at "
            f"{math.degrees(REFERENCE_BEND):.0f} deg"
        )
    try:
        return PlayPrior(
            product=str(doc["product"]),
            catheters=tuple(str(c) for c in doc["catheters"]),
            directions=tuple(math.radians(float(x)) for x in doc["directions_deg"]),
            bends=tuple(math.radians(float(x)) for x in doc["bends_deg"]),
            roll=doc["roll"],
            twist=doc["twist"],
            spread=(float(doc["spread"][0]), float(doc["spread"][1])),
            map=map_prior_from_dict(doc["map"], str(p)) if "map" in doc else None,
            twist_circle=doc.get("twist_circle"),
        )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise FileFormatError(f"{p}: malformed play prior ({exc})") from exc

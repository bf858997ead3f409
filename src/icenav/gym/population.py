"""Seeded catheters and patients of the gymnasium environments.

Seeds
-----
The twin's catheters are seeds of :class:`icenav.sim.CatheterPlant` (parameters within
manufacturing tolerance). The project's seed discipline: catheters 0-9 tuned the twin,
50-52 and 100-109 developed the methods, 110-119 are held out for the paper's results. The
environments draw their training catheters from a new population,
:data:`TRAINING_CATHETERS` (1000-1999), disjoint from all of these; evaluate a trained
policy on :data:`EVALUATION_CATHETERS` (2000-2099), never seen in training, and leave 110-119
to the paper's tables.

Patients
--------
A patient is a seed too (:func:`sample_patient`): the default heart phantom with the
patient's own heart rate and breathing, and the robot base seated slightly differently in
the inferior vena cava (how the sheath lies is never the same twice). Ranges:

- heart rate 60-80 beats/min (the paper's subjects and phantom);
- breathing period 3-5 s (12-20 breaths/min, a resting adult) and 0.5-1.5 times the
  phantom's respiratory excursion;
- base seat: turned about the IVC axis (anatomy z) by up to +-10 deg and shifted by up to
  +-2 mm across the IVC (radius 11 mm in the phantom) and +-5 mm along it. These are our
  assumptions (no measured distribution), small enough that the views of
  :data:`icenav.sim.anatomy.EXAMPLE_VIEWS` stay inside the right atrium.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from icenav._typing import Array
from icenav.errors import ConfigurationError
from icenav.sim.anatomy import BASE2ANATOMY, CardiacMotion, HeartPhantom, default_phantom

__all__ = [
    "EVALUATION_CATHETERS",
    "PlantFactory",
    "Patient",
    "TRAINING_CATHETERS",
    "check_seed_range",
    "default_plant_factory",
    "sample_patient",
]

TRAINING_CATHETERS = (1000, 2000)
"""Half-open range of the catheter seeds the environments draw by default."""
EVALUATION_CATHETERS = (2000, 2100)
"""Half-open range of catheter seeds kept for evaluating trained policies."""

PlantFactory = Callable[[int, str], tuple[Any, Any]]
"""``factory(seed, vessel) -> (plant, tracker)``: the twin's plug-in convention (a plant with
``move``, ``reset`` and ``state.tip2base``; a tracker with ``measure_tip2base``)."""


def default_plant_factory(seed: int, vessel: str) -> tuple[Any, Any]:
    """The twin's catheter ``seed`` in ``vessel`` with its EM tracker (seeded alike, as
    ``icenav eval spin`` builds them)."""
    from icenav.sim import CatheterPlant, EMTracker

    plant = CatheterPlant(seed=seed, vessel=vessel)
    return plant, EMTracker(plant, seed=seed)


def check_seed_range(value: Any, name: str) -> tuple[int, int]:
    """A half-open seed range ``(start, stop)`` of non-negative ints with start < stop."""
    try:
        lo, hi = (int(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f"{name} must be two ints (start, stop), got {value!r}") from exc
    if not 0 <= lo < hi:
        raise ConfigurationError(f"{name} must satisfy 0 <= start < stop, got ({lo}, {hi})")
    return lo, hi


@dataclass(frozen=True)
class Patient:
    """One simulated patient (see the module docstring for the ranges)."""

    seed: int
    """The patient's seed."""
    heart_rate_bpm: float
    """Heart rate (beats/min)."""
    respiratory_period_s: float
    """Breathing period (s)."""
    respiratory_scale: float
    """Respiratory excursion relative to the phantom's default."""
    seat_roll_rad: float
    """Turn of the robot base about the IVC axis (anatomy z; rad)."""
    seat_offset_mm: tuple[float, float, float]
    """Shift of the robot base (anatomy x, y, z; mm)."""

    def phantom(self) -> HeartPhantom:
        """The default heart with this patient's heart rate and breathing."""
        base = CardiacMotion()
        amp = tuple(self.respiratory_scale * a for a in base.respiratory_amplitude_mm)
        motion = replace(
            base,
            heart_rate_bpm=self.heart_rate_bpm,
            respiratory_period_s=self.respiratory_period_s,
            respiratory_amplitude_mm=amp,  # type: ignore[arg-type]
        )
        return default_phantom(motion)

    @property
    def base2anatomy(self) -> Array:
        """(4, 4) pose of the robot base in the anatomy frame (mm): the phantom's
        :data:`~icenav.sim.anatomy.BASE2ANATOMY` turned about anatomy z and shifted."""
        c, s = math.cos(self.seat_roll_rad), math.sin(self.seat_roll_rad)
        seat = np.eye(4)
        seat[:2, :2] = [[c, -s], [s, c]]
        seat[:3, 3] = self.seat_offset_mm
        out: Array = seat @ BASE2ANATOMY
        return out


def sample_patient(seed: int) -> Patient:
    """Patient ``seed`` (any int >= 0): its parameters drawn uniformly in the ranges of the
    module docstring from ``numpy.random.default_rng([seed, 0x9A71])``."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigurationError(f"patient seed must be an int >= 0, got {seed!r}")
    rng = np.random.default_rng([int(seed), 0x9A71])
    u = rng.uniform(-1.0, 1.0, size=4)
    return Patient(
        seed=int(seed),
        heart_rate_bpm=float(rng.uniform(60.0, 80.0)),
        respiratory_period_s=float(rng.uniform(3.0, 5.0)),
        respiratory_scale=float(rng.uniform(0.5, 1.5)),
        seat_roll_rad=math.radians(10.0) * float(u[0]),
        seat_offset_mm=(2.0 * float(u[1]), 2.0 * float(u[2]), 5.0 * float(u[3])),
    )

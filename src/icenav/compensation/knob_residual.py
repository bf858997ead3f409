"""A residual of the per-tendon model's effective knobs along knob circles, by sense of
turning (beyond the paper); identified by :mod:`icenav.calibration.knob_residual`.

The per-tendon transmission (:mod:`icenav.compensation.transmission`) predicts the effective
knobs ``z`` from the motor commands through a capstan band. Where the plant's band is not of
that form, the prediction along a knob circle misses by a slow wave over the azimuth that
depends on the sense of turning (docs/calibration.md, section 4c). This module holds that
miss as a table learned from the calibration's knob circles, with no law assumed for it: per
circle of radius ``R_c`` (rad of effective knob) and per sense of turning ``s`` (+1
counter-clockwise, -1 clockwise), a short Fourier series over the azimuth ``psi`` of ``z``::

    delta_c,s(psi) = a0 + sum_k (a_k cos k psi + b_k sin k psi),  k = 1..K     # (KR1), (2,) rad
    delta(z, s) = interpolated linearly in |z| between the circles' radii,       # (KR2)
                  constant beyond the largest, tapered to 0 at |z| = 0 below the smallest
    z_eff = z + delta(z, s)                                                      # (KR3)

with ``s = 0`` (never turned: a path from rest along a ray) the mean of both senses. The
sense is a state: it is set by each command whose model knobs turn about the centre by more
than :data:`TURN_THRESHOLD` at a radius of at least :data:`MIN_RADIUS`, and kept otherwise
(:func:`update_sense`). What it assumes: the miss of a path is the miss of a circle of the
same radius turned the same way; it cannot hold for paths that are not circles about the
knob plane's centre (a raster line, a radial move, a small circle off the centre), where the
sense of turning does not describe the band's history.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icenav._typing import Array
from icenav.errors import ConfigurationError, ShapeError

__all__ = ["MIN_RADIUS", "TURN_THRESHOLD", "KnobResidual", "update_sense"]

TURN_THRESHOLD = 1e-3
"""Smallest turn of the model knobs about the centre (rad of azimuth) that sets the sense."""
MIN_RADIUS = math.radians(2.0)
"""Smallest radius of the model knobs (rad) at which a turn sets the sense."""


def update_sense(sense: float, z_from: tuple[float, float], z_to: tuple[float, float]) -> float:
    """The sense of turning (+1, -1 or 0) after the model knobs move from ``z_from`` to
    ``z_to`` (rad): the sign of the turn about the centre if it exceeds
    :data:`TURN_THRESHOLD` at a radius of at least :data:`MIN_RADIUS`, else ``sense``."""
    a0, b0 = z_from
    a1, b1 = z_to
    if math.hypot(a1, b1) < MIN_RADIUS or math.hypot(a0, b0) < MIN_RADIUS:
        return sense
    turn = math.atan2(a0 * b1 - b0 * a1, a0 * a1 + b0 * b1)
    if abs(turn) <= TURN_THRESHOLD:
        return sense
    return 1.0 if turn > 0.0 else -1.0


@dataclass(frozen=True)
class KnobResidual:
    """The effective knobs' residual along knob circles (KR1-KR3)."""

    radii: tuple[float, ...]
    """R_c (m,): the circles' radii in effective knobs (rad), increasing, > 0."""
    harmonics: int
    """K: harmonics of the azimuth per circle and sense (>= 0)."""
    coefficients: tuple[float, ...]
    """(m * 2 * (2K + 1) * 2,) flattened (circle, sense (+1, -1), term (a0, a1, b1, ...),
    knob (AP, RL)): rad."""

    def __post_init__(self) -> None:
        r = tuple(float(v) for v in self.radii)
        if not r or any(not (0.0 < v <= math.pi) for v in r) or list(r) != sorted(set(r)):
            raise ConfigurationError(
                f"radii must be increasing values in (0, pi] rad, got {self.radii!r}"
            )
        k = int(self.harmonics)
        if not (0 <= k <= 8):
            raise ConfigurationError(f"harmonics must be in [0, 8], got {self.harmonics!r}")
        c = tuple(float(v) for v in self.coefficients)
        if len(c) != len(r) * 2 * (2 * k + 1) * 2:
            raise ShapeError(
                f"coefficients must have {len(r) * 2 * (2 * k + 1) * 2} values "
                f"({len(r)} circles, 2 senses, {2 * k + 1} terms, 2 knobs), got {len(c)}"
            )
        if any(not math.isfinite(v) or abs(v) > 1.0 for v in c):
            raise ConfigurationError("coefficients must be finite and within +-1 rad")
        object.__setattr__(self, "radii", r)
        object.__setattr__(self, "harmonics", k)
        object.__setattr__(self, "coefficients", c)

    @property
    def table(self) -> Array:
        """The coefficients as (m, 2, 2K + 1, 2) (circle, sense +1 / -1, term, knob), rad."""
        k = 2 * self.harmonics + 1
        return np.array(self.coefficients).reshape(len(self.radii), 2, k, 2)

    def _circle(self, c: int, psi: float, sense: float) -> tuple[float, float]:
        """(KR1) of circle ``c`` at azimuth ``psi`` (rad) for ``sense`` (0: both senses'
        mean)."""
        k = 2 * self.harmonics + 1
        basis = [1.0]
        for h in range(1, self.harmonics + 1):
            basis += [math.cos(h * psi), math.sin(h * psi)]
        co = self.coefficients
        out = [0.0, 0.0]
        senses = (0,) if sense > 0.0 else (1,) if sense < 0.0 else (0, 1)
        for s in senses:
            base = ((c * 2 + s) * k) * 2
            for t in range(k):
                out[0] += basis[t] * co[base + 2 * t]
                out[1] += basis[t] * co[base + 2 * t + 1]
        n = len(senses)
        return out[0] / n, out[1] / n

    def delta(self, z1: float, z2: float, sense: float) -> tuple[float, float]:
        """delta(z, s) (KR2) (rad, (2,)) at the model's effective knobs (z1, z2) (rad)."""
        r = math.hypot(z1, z2)
        if r == 0.0:
            return 0.0, 0.0
        psi = math.atan2(z2, z1)
        radii = self.radii
        if r <= radii[0]:
            a, b = self._circle(0, psi, sense)
            f = r / radii[0]  # tapered to 0 at the centre, where the azimuth is undefined
            return f * a, f * b
        if r >= radii[-1]:
            return self._circle(len(radii) - 1, psi, sense)
        i = next(j for j in range(1, len(radii)) if r < radii[j])
        f = (r - radii[i - 1]) / (radii[i] - radii[i - 1])
        a0, b0 = self._circle(i - 1, psi, sense)
        a1, b1 = self._circle(i, psi, sense)
        return a0 + f * (a1 - a0), b0 + f * (b1 - b0)

    def along(
        self, z: Array, sense0: float = 0.0, z_start: tuple[float, float] | None = None
    ) -> Array:
        """delta (n, 2) (rad) along a sequence of model effective knobs ``z`` (n, 2), the
        sense updated sample by sample (:func:`update_sense`) from ``sense0`` at ``z_start``
        (2,) (default: the first sample)."""
        zz = np.asarray(z, dtype=np.float64)
        if zz.ndim != 2 or zz.shape[1] != 2:
            raise ShapeError(f"z must have shape (n, 2), got {zz.shape}")
        out = np.zeros_like(zz)
        s = float(sense0)
        rows = zz.tolist()
        prev = (
            (float(z_start[0]), float(z_start[1]))
            if z_start is not None
            else (tuple(rows[0]) if rows else (0.0, 0.0))
        )
        for i, row in enumerate(rows):
            s = update_sense(s, (prev[0], prev[1]), (row[0], row[1]))
            out[i] = self.delta(row[0], row[1], s)
            prev = (row[0], row[1])
        return out

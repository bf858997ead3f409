"""The pose stage's step: a damped least-squares solve with joints that must not reverse held,
and a secant (Broyden) update of the step's Jacobian from the stage's own measured moves."""

from __future__ import annotations

import numpy as np

from icenav._typing import Array

__all__: list[str] = []


def held_dls(jw: Array, ew: Array, damping: float, no_reverse: Array, engaged: Array) -> Array:
    """Damped least-squares joint step (4,) for the weighted error ``ew`` (6,) with the
    weighted Jacobian ``jw`` (6, 4)::

        dq = (J^T W J + lambda^2 I)^-1 J^T W e

    solved again with a joint held (its step 0) while the solution would move a joint of
    ``no_reverse`` (4, bool) against its ``engaged`` direction (4, in -1 / 0 / 1)."""
    free = np.ones(4, dtype=bool)
    dq = np.zeros(4)
    for _ in range(4):
        a = jw[:, free]
        lhs = a.T @ a + damping**2 * np.eye(int(free.sum()))
        dq = np.zeros(4)
        dq[free] = np.linalg.solve(lhs, a.T @ ew)
        bad = free & no_reverse & (dq * engaged < 0)
        if not np.any(bad):
            break
        free &= ~bad
        if not np.any(free):
            return np.zeros(4)
    return dq


def secant_update(jac: Array, dq: Array, moved: Array, scale: Array, weight: float) -> Array:
    """Broyden's ("good") rank-one update of a Jacobian (6, 4) from one measured move.

    ``dq`` (4,) is the commanded change (rad, rad, rad, mm), ``moved`` (6,) the measured
    change of the tip's body pose over it (mm, rad: the measured error before the move less
    the one after), ``scale`` (4,) the joints' units (e.g. the largest steps), so that the
    update is the least change of the Jacobian in joint steps of equal size::

        J+ = J + w (y - J dq) (S^-2 dq)^T / (dq^T S^-2 dq)

    with ``w = weight`` in (0, 1] (1: the new Jacobian maps ``dq`` exactly onto ``y``; less
    keeps part of the model's, since one move's response carries the scatter of the
    shaft's lost motion). Unchanged when ``dq`` is zero."""
    s = dq / scale**2
    den = float(dq @ s)
    if den <= 0.0:
        return jac
    out: Array = jac + weight * np.outer(moved - jac @ dq, s) / den
    return out

"""Shared by the ablation scripts of this folder: one variant's spin errors and their row
as text."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from icenav.eval import spin as S
from icenav.geometry.kinematics import forward
from icenav.geometry.trajectories import spin_trajectory


def spin_runs(
    rig: Any, tracker: Any, commands: Callable[[Any], Any]
) -> Iterator[tuple[list[float], Any, Any]]:
    """The eval's spin (20 / 40 / 60 deg, 360 samples) on ``rig`` with ``commands(q_model)``
    -> (n, 4) motor commands; per bend (EM mm, EM deg, true mm, true deg), the true poses
    (n, 4, 4) and the intended ones (n, 4, 4)."""
    for bend in S.BENDS_DEG:
        sp = spin_trajectory([math.radians(bend), 0.0, 0.0, 0.0], 360, include_end=True)
        intended = forward(sp.q_model, check=False)
        true, em = S.run_spin(rig, tracker, commands(sp.q_model))
        ok = np.all(np.isfinite(em.reshape(len(em), -1)), axis=1)
        ep, er = S._rmse(em[ok], intended[ok])
        tp, tr = S._rmse(true, intended)
        yield [ep, er, tp, tr], true, intended


def spin_errors(rig: Any, tracker: Any, commands: Callable[[Any], Any]) -> list[float]:
    """:func:`spin_runs`' errors per bend, flattened (the order :func:`error_row` reads)."""
    return [e for errs, _, _ in spin_runs(rig, tracker, commands) for e in errs]


def error_row(e: Sequence[float]) -> str:
    """``e`` = (EM mm, EM deg, true mm, true deg) per bend of 20 / 40 / 60 deg, flattened."""

    def part(k: int) -> str:
        return " / ".join(f"{e[4 * i + k]:.2f}" for i in range(3))

    return f"EM {part(0)} mm, {part(1)} deg | true {part(2)} mm, {part(3)} deg"


def _ours_commands(ours: Any, q_model: Any) -> Any:
    """Ours' commands for ``q_model``: a fresh (stateful) map for every spin, as the eval
    does."""
    return S.knob_map_commands(ours.knob_map(), S._approach_path(q_model))


def variant_rows(
    rig: Any,
    tracker: Any,
    variants: dict[str, Any],
    ours: Any,
    short_commands: Callable[[Any, Any], Any] = S.short_ring_commands,
    label: str = "",
    width: int = 12,
) -> dict[str, list[float]]:
    """Spin every short calibration of ``variants`` (name -> calibration, commanded by
    ``short_commands(cal, q_model)``) and then ``ours`` (a full calibration, skipped when
    None; a fresh stateful map for every spin, as the eval does) on ``rig``; prints one
    :func:`error_row` a variant (prefixed by ``label``) and returns name -> errors."""
    rows: dict[str, list[float]] = {}
    names = [*variants, *(["ours"] if ours is not None else [])]
    for name in names:
        commands: Callable[[Any], Any]
        if name == "ours":
            commands = functools.partial(_ours_commands, ours)
        else:
            commands = functools.partial(short_commands, variants[name])
        errs = spin_errors(rig, tracker, commands)
        rows[name] = errs
        print(f"{label}{name:{width}s} " + error_row(errs), flush=True)
    return rows

"""Shared by the ablation scripts of this folder: one variant's row of errors as text."""

from __future__ import annotations

from collections.abc import Sequence


def error_row(e: Sequence[float]) -> str:
    """``e`` = (EM mm, EM deg, true mm, true deg) per bend of 20 / 40 / 60 deg, flattened."""

    def part(k: int) -> str:
        return " / ".join(f"{e[4 * i + k]:.2f}" for i in range(3))

    return f"EM {part(0)} mm, {part(1)} deg | true {part(2)} mm, {part(3)} deg"

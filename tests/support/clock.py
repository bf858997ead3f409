"""A clock the test advances: what the controller, the robot and the twin read as time."""

from __future__ import annotations


class Clock:
    """Simulated time (s): ``clock()`` reads it, the test advances ``clock.t``."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

"""Cost of the disturbed twin's contact solve (``docs/digital-twin.md`` section 8).

An in-vivo ``eval recovery`` solves flow and contact some 14,000 times a 2-round run, each
solve asking the moving walls (the heart's displacement field and the signed distances of
the RA, IVC and SVC) two or three times. Baseline, measured in the same run: the same solves
with the fast paths of the walls swapped for the implementations they replaced (the
breathing level and the beat's bumps through the array code, the beat index by
``np.searchsorted``, the chamber distance through its bounded subset path), which give the
same numbers to the bit: the deflected poses of both are checked equal. Not swapped (no
reference kept): the signed distances' constants made once, the free and flow-bent nodes in
one call of the walls, the shaft's memo of the wall (``sim/introducer.py``).
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from benchmarks.common import Result, time_per_call
from icenav.geometry.kinematics import forward
from icenav.sim.anatomy import phantom as phantom_module
from icenav.sim.anatomy.shapes import Chamber
from icenav.sim.conditions import build_twin
from icenav.sim.physiology import Breathing, CardiacRhythm


@contextlib.contextmanager
def reference_paths() -> Iterator[None]:
    """Swap the walls' fast paths for the array implementations they replaced."""
    saved: list[tuple[Any, str, Any]] = []

    def swap(owner: Any, name: str, value: Any) -> None:
        saved.append((owner, name, getattr(owner, name)))
        setattr(owner, name, value)

    sdf = Chamber.sdf
    bump = phantom_module._bump  # noqa: SLF001 - the reference of _bump_at

    def level(self: Breathing, t: float) -> float:
        return float(self.signal(t))

    def beat_index(self: CardiacRhythm, t: float) -> int:
        self._extend(t)  # noqa: SLF001
        return int(np.searchsorted(np.asarray(self._starts), t, side="right") - 1)  # noqa: SLF001

    def bounded_sdf(self: Chamber, points: Any, *, beyond_mm: float = np.inf) -> Any:
        return sdf(self, points, beyond_mm=1e300 if beyond_mm == np.inf else beyond_mm)

    swap(Breathing, "level", level)
    swap(CardiacRhythm, "beat_index", beat_index)
    swap(Chamber, "sdf", bounded_sdf)
    swap(phantom_module, "_bump_at", lambda p, a, b: float(bump(p, a, b)))
    try:
        yield
    finally:
        for owner, name, value in reversed(saved):
            setattr(owner, name, value)


def main() -> list[Result]:
    twin = build_twin("in-vivo", 100, 0, lambda: 0.0)
    model = twin.plant.contact
    assert model is not None
    assert model.walls is not None
    rng = np.random.default_rng(0)
    states = []
    for _ in range(30):  # bends of +-50 deg, rolls and translations around the RA
        q = np.array([*rng.uniform(-0.9, 0.9, 2), rng.uniform(-1.0, 1.0), rng.uniform(-20, 10)])
        tip = forward(q)
        states.append((model.shape(tip), tip))
    times = rng.uniform(0.0, 60.0, 20)

    def solve_all() -> list[np.ndarray]:
        return [model.solve(s, tip, float(t)).tip2base for s, tip in states for t in times]

    n = len(states) * len(times)
    fast = solve_all()
    t_fast = time_per_call(solve_all, min_time=0.5, repeat=3) / n
    with reference_paths():
        ref = solve_all()
        t_ref = time_per_call(solve_all, min_time=0.5, repeat=3) / n
    same = all(np.array_equal(a, b) for a, b in zip(fast, ref, strict=True))
    in_contact = np.mean([bool(model.solve(s, tip, float(t)).contacts) for s, tip in states
                          for t in times])  # fmt: skip

    points = states[0][0].points
    t0 = float(times[0])
    walls = model.walls
    t_walls = time_per_call(lambda: walls.distance(points, t0))
    with reference_paths():
        t_walls_ref = time_per_call(lambda: walls.distance(points, t0))

    # the end-to-end cost of the walls' paths: a reduced in-vivo eval recovery (CPU time)
    from icenav.eval.recovery import main as recovery_main

    args = ["--condition", "in-vivo", "--seed", "100", "--patient", "0", "--quick",
            "--open-loop-only"]  # fmt: skip
    sink = io.StringIO()  # the run's table and progress bar
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        c0 = time.process_time()
        recovery_main(args)
        c_fast = time.process_time() - c0
        with reference_paths():
            c0 = time.process_time()
            recovery_main(args)
            c_ref = time.process_time() - c0

    return [
        Result(
            f"contact solve, in-vivo twin ({100 * in_contact:.0f} % of states in contact; "
            f"poses {'equal' if same else 'DIFFER'} to the reference's)",
            t_fast * 1e6,
            "us/solve",
            t_ref * 1e6,
            "the same solves, reference paths",
            "poses equal to the bit",
            same,
        ),
        Result(
            "walls at 8 nodes (displacement field + signed distances)",
            t_walls * 1e6,
            "us/call",
            t_walls_ref * 1e6,
            "reference paths",
        ),
        Result(
            "eval recovery --quick --open-loop-only, in-vivo 100/0",
            c_fast,
            "s CPU",
            c_ref,
            "reference paths",
        ),
    ]


if __name__ == "__main__":
    from benchmarks.common import print_results

    print_results(main())

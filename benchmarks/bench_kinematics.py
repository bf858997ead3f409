"""Kinematics speed: one FK, one IK, FK+IK, one body Jacobian, and batch FK of 1,000,000
configurations.

Baseline, measured in the same run: the paper's formula written the straightforward way
(4x4 matrices composed with numpy, Rodrigues via the matrix exponential form), called once
per configuration. Targets (issue 2): FK+IK < 30 us; batch FK > 5 M configurations/s.
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Result, time_per_call
from icenav.geometry.jacobian import jacobian
from icenav.geometry.kinematics import CatheterGeometry, forward, inverse

G = CatheterGeometry()


def naive_forward(q: np.ndarray, g: CatheterGeometry = G) -> np.ndarray:
    """Literal T_trans(d4) T_roll(phi3) T_tilt T_US (paper Sec. III-B), one call per q."""
    k = g.knob_ratio
    alpha = k * math.hypot(q[0], q[1])
    theta = math.atan2(q[1], q[0])
    t_tilt = np.eye(4)
    if alpha > 1e-12:
        r = g.bending_length / alpha
        t_tilt[:3, 3] = [
            r * (1 - math.cos(alpha)) * math.cos(theta),
            r * (1 - math.cos(alpha)) * math.sin(theta),
            r * math.sin(alpha),
        ]
        n = np.array([-math.sin(theta), math.cos(theta), 0.0])
        kx = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
        t_tilt[:3, :3] = np.eye(3) + math.sin(alpha) * kx + (1 - math.cos(alpha)) * kx @ kx
    else:
        t_tilt[2, 3] = g.bending_length
    t_trans = np.eye(4)
    t_trans[2, 3] = q[3]
    c, s = math.cos(q[2]), math.sin(q[2])
    t_roll = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    t_us = np.eye(4)
    t_us[2, 3] = g.us_offset
    return t_trans @ t_roll @ t_tilt @ t_us


def main() -> list[Result]:
    rng = np.random.default_rng(0)
    q = np.array([0.6, -0.3, 0.4, 5.0])
    t = forward(q)
    assert np.allclose(naive_forward(q), t)
    fk = time_per_call(lambda: forward(q, check=False))
    fk_checked = time_per_call(lambda: forward(q))
    ik = time_per_call(lambda: inverse(t, check=False))
    naive = time_per_call(lambda: naive_forward(q))
    both = time_per_call(lambda: inverse(forward(q, check=False), check=False))
    n = 1_000_000
    qs = np.column_stack(
        [rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(-3, 3, n), rng.uniform(-50, 50, n)]
    )
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        forward(qs, check=False)
        best = min(best, time.perf_counter() - t0)
    loop_n = 20_000
    t0 = time.perf_counter()
    for row in qs[:loop_n]:
        naive_forward(row)
    loop_per = (time.perf_counter() - t0) / loop_n
    rate = n / best / 1e6
    jac = time_per_call(lambda: jacobian(q, check=False))
    jac_batch = time_per_call(lambda: jacobian(q[None], check=False))
    return [
        Result("FK, one call (check=False)", fk * 1e6, "us", naive * 1e6, "naive numpy FK"),
        Result("FK, one call (validated)", fk_checked * 1e6, "us", naive * 1e6, "naive numpy FK"),
        Result("IK, one call (check=False)", ik * 1e6, "us"),
        Result(
            "FK + IK, one call each",
            both * 1e6,
            "us",
            target="< 30 us",
            met=both * 1e6 < 30,
        ),
        Result(
            "body Jacobian, one call (scalar path, check=False)",
            jac * 1e6,
            "us",
            jac_batch * 1e6,
            "the batch path on one configuration",
        ),
        Result(
            "batch FK of 1e6, time per configuration",
            best / n * 1e9,
            "ns",
            loop_per * 1e9,
            "per-call naive loop (20k calls, per configuration)",
            target=f"> 5 M configs/s (measured {rate:.1f} M/s)",
            met=rate > 5,
        ),
    ]

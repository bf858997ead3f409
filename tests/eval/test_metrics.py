"""Image similarity, geometric median and pose error metrics."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.ndimage as ndi
from scipy.optimize import minimize

from icenav.errors import InvalidValueError, ShapeError
from icenav.eval.metrics import (
    beat_similarity,
    blurred_ncc,
    error_stats,
    geometric_median,
    geometric_median_index,
    match_by_phase,
    ncc,
    pose_errors,
    roi_centroid_distance,
    rotation_angle,
)


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def test_ncc_analytic_cases() -> None:
    rng = np.random.default_rng(0)
    a = rng.random((32, 32))
    assert ncc(a, a) == pytest.approx(1.0)
    assert ncc(a, 3.0 * a + 7.0) == pytest.approx(1.0)
    assert ncc(a, -a) == pytest.approx(-1.0)
    assert abs(ncc(a, rng.random((32, 32)))) < 0.1
    assert ncc(a, np.ones_like(a)) == 0.0
    # the mask selects pixels: equal where it is true, whatever elsewhere
    b = a.copy()
    b[:, 16:] = rng.random((32, 16))
    mask = np.zeros_like(a, dtype=bool)
    mask[:, :16] = True
    assert ncc(a, b, mask) == pytest.approx(1.0)
    # against numpy's Pearson coefficient
    c = a + 0.5 * rng.random((32, 32))
    assert ncc(a, c) == pytest.approx(np.corrcoef(a.ravel(), c.ravel())[0, 1])


def test_ncc_rejects_mismatched_images() -> None:
    with pytest.raises(ShapeError, match="same shape"):
        ncc(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(ShapeError, match="mask"):
        ncc(np.zeros((4, 4)), np.zeros((4, 4)), np.ones((3, 3), dtype=bool))
    with pytest.raises(InvalidValueError, match="factor"):
        blurred_ncc(np.zeros((8, 8)), np.zeros((8, 8)), factor=0)


def test_blurred_ncc_is_smooth_where_raw_speckle_is_not() -> None:
    # a smooth structure plus fine speckle, shifted by 2 pixels
    rng = np.random.default_rng(1)
    structure = ndi.gaussian_filter(rng.random((128, 128)), 8.0)
    structure = (structure - structure.mean()) / structure.std()
    speckle = rng.standard_normal((128, 128))
    img = structure + speckle
    shifted = np.roll(img, 2, axis=1)
    assert blurred_ncc(img, shifted) > 0.9
    assert ncc(img, shifted) < 0.6


def test_match_by_phase_wraps_around_the_beat() -> None:
    phases = np.array([0.0, 0.25, 0.5, 0.75])
    np.testing.assert_array_equal(match_by_phase(phases, [0.98, 0.26, 0.6, 0.7]), [0, 1, 2, 3])


def test_beat_similarity_matches_frames_by_phase() -> None:
    rng = np.random.default_rng(2)
    frames = [rng.random((16, 16)) for _ in range(6)]
    phases = np.arange(6) / 6.0
    order = rng.permutation(6)
    shuffled = [frames[i] for i in order]
    assert beat_similarity(shuffled, phases[order], frames, phases) == pytest.approx(1.0)
    # a clip matched at the wrong phase is not similar
    rolled = frames[1:] + frames[:1]
    assert beat_similarity(rolled, phases, frames, phases) < 0.3
    with pytest.raises(ShapeError, match="phases"):
        beat_similarity(frames, phases[:3], frames, phases)


def test_geometric_median_known_sets() -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    np.testing.assert_allclose(geometric_median(square), [1.0, 1.0], atol=1e-6)
    line = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    np.testing.assert_allclose(geometric_median(line), [1.0, 0.0, 0.0], atol=1e-5)
    # a majority at one point pins the median there (Weiszfeld must not get stuck)
    pinned = np.array([[1.0, 1.0]] * 3 + [[5.0, 1.0], [1.0, 9.0]])
    np.testing.assert_allclose(geometric_median(pinned), [1.0, 1.0], atol=1e-6)


def test_geometric_median_agrees_with_direct_minimisation() -> None:
    rng = np.random.default_rng(4)
    for _ in range(10):
        pts = rng.normal(size=(rng.integers(3, 20), 3)) * rng.uniform(0.5, 5.0)
        gm = geometric_median(pts)

        def cost(y: np.ndarray, pts: np.ndarray = pts) -> float:
            return float(np.linalg.norm(pts - y, axis=1).sum())

        ref = minimize(cost, pts.mean(axis=0), method="Nelder-Mead", options={"xatol": 1e-9})
        assert cost(gm) <= cost(ref.x) + 1e-6


def test_geometric_median_index_picks_the_central_return() -> None:
    # seven returns, one outlier: the reference is the sample nearest the median
    pts = np.array(
        [[0.1, 0, 0], [-0.1, 0, 0], [0, 0.1, 0], [0, -0.1, 0], [0.02, 0.01, 0], [0, 0, 0.1]]
        + [[5.0, 5.0, 5.0]]
    )
    assert geometric_median_index(pts) == 4
    with pytest.raises(ShapeError, match=r"\(n, d\)"):
        geometric_median(np.zeros(3))


def test_rotation_angle_of_known_rotations() -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        r0 = _rot(rng.normal(size=3), rng.uniform(0, math.pi))
        angle = rng.uniform(0.0, math.pi)
        r1 = r0 @ _rot(rng.normal(size=3), angle)
        assert float(rotation_angle(r0, r1)) == pytest.approx(angle, abs=1e-9)
    assert float(rotation_angle(np.eye(3), np.eye(3))) == 0.0


def test_error_stats_and_pose_errors() -> None:
    s = error_stats([3.0, 4.0])
    assert (s.mean, s.max, s.n) == (3.5, 4.0, 2)
    assert s.sd == pytest.approx(math.sqrt(0.5))
    assert s.rmse == pytest.approx(math.sqrt(12.5))
    assert error_stats([2.0]).sd == 0.0
    with pytest.raises(ShapeError, match="at least one"):
        error_stats([])
    ref = np.eye(4)
    poses = np.stack([np.eye(4)] * 3)
    poses[0, :3, 3] = [1.0, 0.0, 0.0]
    poses[1, :3, :3] = _rot(np.array([0.0, 0.0, 1.0]), math.radians(2.0))
    poses[2, :3, 3] = [0.0, 3.0, 4.0]
    errs = pose_errors(poses, ref)
    np.testing.assert_allclose(errs.position_mm, [1.0, 0.0, 5.0])
    np.testing.assert_allclose(errs.orientation_rad, [0.0, math.radians(2.0), 0.0], atol=1e-12)
    assert errs.position.mean == pytest.approx(2.0)
    assert roi_centroid_distance([0.0, 0.0], [3.0, 4.0]) == pytest.approx(5.0)

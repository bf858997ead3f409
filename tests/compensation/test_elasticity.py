"""Tests of icenav.compensation.elasticity: calibration sets, their files, and the map F."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from icenav.compensation.elasticity import (
    CALIBRATION_VERSION,
    CalibrationSet,
    ElasticityMap,
    grid_subset_indices,
)
from icenav.errors import ConfigurationError, FileFormatError, UnsupportedVersionError
from icenav.geometry.kinematics import forward

LIM = math.pi / 2
DEG = math.pi / 180


def grid(step_deg: float = 10.0) -> np.ndarray:
    ax = np.radians(np.arange(-90.0, 90.0 + 1e-9, step_deg))
    a, b = np.meshgrid(ax, ax, indexing="ij")
    q = np.zeros((a.size, 4))
    q[:, 0] = a.ravel()
    q[:, 1] = b.ravel()
    return q


def distortion(k: np.ndarray) -> np.ndarray:
    """A smooth, invertible synthetic elasticity: motor knobs (..., 2) -> effective model
    knobs. Turns the bending plane by 8 deg, bends 15 % more at small angles and less at
    large ones (so the model's workspace stays mostly reachable)."""
    c, s = math.cos(8 * DEG), math.sin(8 * DEG)
    rot = np.array([[c, -s], [s, c]])
    r2 = np.sum(k * k, axis=-1, keepdims=True) / LIM**2
    return (k @ rot.T) * (1.15 - 0.12 * r2)


def undistort(m: np.ndarray) -> np.ndarray:
    """Independent inverse of :func:`distortion` by Newton iterations (the true F)."""
    k = m.copy()
    for _ in range(50):
        f = distortion(k) - m
        h = 1e-7
        ja = (distortion(k + [h, 0]) - distortion(k - [h, 0])) / (2 * h)
        jb = (distortion(k + [0, h]) - distortion(k - [0, h])) / (2 * h)
        jac = np.stack([ja, jb], axis=-1)
        k = k - np.linalg.solve(jac, f[..., None])[..., 0]
    return k


def synthetic_set(q_motor: np.ndarray, distort: bool = True) -> CalibrationSet:
    qe = q_motor.copy()
    if distort:
        qe[:, :2] = distortion(q_motor[:, :2])
    return CalibrationSet(
        q_motor=q_motor, tip2base=forward(qe, check=False), catheter_id="syn", method="test"
    )


@pytest.fixture(scope="module")
def dense_map() -> ElasticityMap:
    return ElasticityMap.build(synthetic_set(grid()), smoothing=0.0)


def random_model_knobs(n: int, max_deg: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, (n, 2)) * max_deg * DEG


# --- F -------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_points", [5, 9, 361])
def test_map_is_identity_on_an_ideal_catheter(n_points: int) -> None:
    full = synthetic_set(grid(), distort=False)
    cal = full.subset(grid_subset_indices(full.q_motor, n_points))
    fmap = ElasticityMap.build(cal)
    k = random_model_knobs(500, 85.0, 1)
    a, b = fmap.model_to_motor_knobs(k[:, 0], k[:, 1])
    assert np.max(np.abs(np.stack([a, b], -1) - k)) < 1e-6


def test_dense_map_recovers_a_known_distortion(dense_map: ElasticityMap) -> None:
    k = random_model_knobs(2000, 70.0, 2)
    a, b = dense_map.model_to_motor_knobs(k[:, 0], k[:, 1])
    expected = undistort(k)
    err = np.degrees(np.abs(np.stack([a, b], -1) - expected))
    assert np.sqrt(np.mean(err**2)) < 0.05
    assert np.max(err) < 0.3
    # and the real tip lands on the model tip
    q_eff = np.zeros((k.shape[0], 4))
    q_eff[:, :2] = distortion(np.stack([a, b], -1))
    q_model = np.zeros_like(q_eff)
    q_model[:, :2] = k
    p_err = np.linalg.norm(
        forward(q_eff, check=False)[:, :3, 3] - forward(q_model)[:, :3, 3], axis=-1
    )
    assert np.max(p_err) < 0.5


def test_map_then_inverse_is_identity(dense_map: ElasticityMap) -> None:
    k = random_model_knobs(2000, 70.0, 3)
    a, b = dense_map.model_to_motor_knobs(k[:, 0], k[:, 1])
    c, d = dense_map.motor_to_model_knobs(a, b)
    assert np.max(np.abs(np.stack([c, d], -1) - k)) < 2e-3 * DEG * 100  # < 0.2 deg


def test_scalar_fast_path_equals_batch(dense_map: ElasticityMap) -> None:
    k = random_model_knobs(200, 90.0, 4)
    a, b = dense_map.model_to_motor_knobs(k[:, 0], k[:, 1])
    for i in range(k.shape[0]):
        x, y = dense_map.model_to_motor_knobs(float(k[i, 0]), float(k[i, 1]), check=False)
        assert x == pytest.approx(a[i], abs=1e-12)
        assert y == pytest.approx(b[i], abs=1e-12)


def test_map_is_smooth_no_jumps(dense_map: ElasticityMap) -> None:
    t = np.linspace(0.0, 2 * math.pi, 3600)
    a, b = dense_map.model_to_motor_knobs(1.0 * np.cos(t), 1.0 * np.sin(t))
    step = np.hypot(np.diff(a), np.diff(b))
    # model steps are 1.0 rad * 2 pi / 3600 = 1.7e-3 rad; the map's slope is ~1.2
    assert np.max(step) < 3 * 2 * math.pi / 3600


def test_compensated_kinematics_round_trip(dense_map: ElasticityMap) -> None:
    rng = np.random.default_rng(5)
    q = np.zeros((300, 4))
    q[:, :2] = rng.uniform(-60, 60, (300, 2)) * DEG
    q[:, 2] = rng.uniform(-3, 3, 300)
    q[:, 3] = rng.uniform(-20, 20, 300)
    q_motor = dense_map.model_to_motor(q)
    assert np.allclose(q_motor[:, 2:], q[:, 2:])
    t = dense_map.forward(q_motor)
    assert np.allclose(t, forward(q), atol=0.05)
    back = dense_map.inverse(t, phi3_near=q[:, 2])
    assert np.allclose(back, q_motor, atol=2e-3)


def test_sparse_maps_reduce_the_error() -> None:
    full = synthetic_set(grid())
    k = random_model_knobs(1000, 60.0, 6)
    truth = undistort(k)
    none = np.sqrt(np.mean(np.sum((k - truth) ** 2, -1)))
    errors = {}
    for n in (5, 9, 13, 25):
        cal = full.subset(grid_subset_indices(full.q_motor, n))
        fmap = ElasticityMap.build(cal)
        assert fmap.report.interpolant == ("spline" if n == 25 else "rbf")
        a, b = fmap.model_to_motor_knobs(k[:, 0], k[:, 1])
        errors[n] = np.sqrt(np.mean(np.sum((np.stack([a, b], -1) - truth) ** 2, -1)))
    assert all(e < 0.5 * none for e in errors.values()), (none, errors)
    assert errors[25] < errors[5]


def test_refinement_beats_nearest_neighbour(dense_map: ElasticityMap) -> None:
    r = dense_map.report
    assert r.refined_match_rms_mm < r.nn_match_rms_mm


def test_dead_zone_is_flagged() -> None:
    q = grid(5.0)
    qe = q.copy()
    d = 8 * DEG  # dead-zone half-width of the AP knob
    qe[:, 0] = np.sign(q[:, 0]) * np.maximum(np.abs(q[:, 0]) - d, 0.0)
    cal = CalibrationSet(q_motor=q, tip2base=forward(qe, check=False))
    fmap = ElasticityMap.build(cal, smoothing=0.0)
    inside = fmap.in_dead_zone(np.zeros(5), np.radians([-60, -30, 0, 30, 60]))
    outside = fmap.in_dead_zone(np.full(5, 45 * DEG), np.radians([-60, -30, 0, 30, 60]))
    assert np.all(inside)
    assert not np.any(outside)
    # F stays single-valued and finite across the dead-zone, with a steep slope there
    a, _ = fmap.model_to_motor_knobs(np.radians([-2.0, 0.0, 2.0]), np.zeros(3))
    assert np.all(np.diff(a) > 0)


def test_map_rejects_bad_input(dense_map: ElasticityMap) -> None:
    with pytest.raises(ConfigurationError, match=r"model phi1 = .* outside the map's range"):
        dense_map.model_to_motor_knobs(2.0, 0.0)
    scattered = synthetic_set(grid()).subset([0, 5, 40, 100, 200, 300])
    with pytest.raises(ConfigurationError, match="rectangular knob grid"):
        ElasticityMap.build(scattered, interpolant="spline")
    with pytest.raises(ConfigurationError, match="interpolant must be"):
        ElasticityMap.build(scattered, interpolant="cubic")  # type: ignore[arg-type]


# --- calibration files -----------------------------------------------------------------------


def test_calibration_file_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    q = grid(30.0)
    q[:, 2] = rng.uniform(-1, 1, q.shape[0])
    q[:, 3] = rng.uniform(-5, 5, q.shape[0])
    cal = CalibrationSet(
        q_motor=q,
        tip2base=forward(q),
        catheter_id="AcuNav-123",
        vessel="moderate",
        method="dense-raster",
        notes="bench 3",
    )
    path = tmp_path / "cal.json"
    cal.save(path)
    back = CalibrationSet.load(path)
    assert np.array_equal(back.q_motor, cal.q_motor)
    assert np.array_equal(back.tip2base, cal.tip2base)
    for key in ("catheter_id", "vessel", "created", "method", "notes"):
        assert getattr(back, key) == getattr(cal, key)
    assert json.loads(path.read_text())["version"] == CALIBRATION_VERSION
    # roll and translation are removed before fitting
    p = back.positions_in_knob_frame()
    q0 = q.copy()
    q0[:, 2:] = 0.0
    assert np.allclose(p, forward(q0)[:, :3, 3], atol=1e-9)


def _doc(tmp_path: Path) -> dict[str, object]:
    cal = synthetic_set(grid(45.0))
    return cal.to_dict()


@pytest.mark.parametrize(
    ("mutate", "error", "match"),
    [
        (
            lambda d: d.update(version=CALIBRATION_VERSION + 1),
            UnsupportedVersionError,
            f"version {CALIBRATION_VERSION + 1} is not supported",
        ),
        (lambda d: d.update(version=0), UnsupportedVersionError, "version 0 is not supported"),
        (lambda d: d.update(version="1"), FileFormatError, "version must be an integer"),
        (
            lambda d: d.update(format="something.else"),
            FileFormatError,
            "not an icenav calibration file",
        ),
        (lambda d: d.pop("tip2base"), FileFormatError, "missing field"),
        (
            lambda d: d.update(q_motor=d["q_motor"][:-1]),
            FileFormatError,  # type: ignore[index]
            "inconsistent calibration set",
        ),
        (lambda d: d.update(q_motor=[[0.0, 0.0, 0.0]] * 25), FileFormatError, r"shape \(n, 4\)"),
        (
            lambda d: d["q_motor"][0].__setitem__(0, float("nan")),  # type: ignore[index]
            FileFormatError,
            "must be finite",
        ),
        (
            lambda d: d["tip2base"][0][0].__setitem__(0, 3.0),  # type: ignore[index]
            FileFormatError,
            "not a rigid transform",
        ),
        (lambda d: d.update(catheter_id=5), FileFormatError, "catheter_id must be a string"),
    ],
)
def test_corrupt_calibration_files_are_refused(
    tmp_path: Path, mutate: object, error: type[Exception], match: str
) -> None:
    doc = _doc(tmp_path)
    mutate(doc)  # type: ignore[operator]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(error, match=match):
        CalibrationSet.load(path)


def test_truncated_and_binary_files_are_refused(tmp_path: Path) -> None:
    good = tmp_path / "good.json"
    synthetic_set(grid(45.0)).save(good)
    trunc = tmp_path / "trunc.json"
    trunc.write_text(good.read_text()[:200])
    with pytest.raises(FileFormatError, match="not valid JSON"):
        CalibrationSet.load(trunc)
    binary = tmp_path / "bin.json"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(FileFormatError):
        CalibrationSet.load(binary)
    lst = tmp_path / "list.json"
    lst.write_text("[1, 2]")
    with pytest.raises(FileFormatError, match="expected a JSON object"):
        CalibrationSet.load(lst)


def test_grid_subsets() -> None:
    q = grid()
    for n in (5, 9, 13, 25, 361):
        idx = grid_subset_indices(q, n)
        assert len(set(idx.tolist())) == n
    five = q[grid_subset_indices(q, 5), :2]
    assert {tuple(np.round(np.degrees(r)).astype(int)) for r in five} == {
        (0, 0),
        (90, 0),
        (-90, 0),
        (0, 90),
        (0, -90),
    }
    with pytest.raises(ConfigurationError, match="n_points must be"):
        grid_subset_indices(q, 7)

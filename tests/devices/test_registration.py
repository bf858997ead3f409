"""Registration of the tracker to the robot base."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from icenav.calibration.files import CalibrationFile
from icenav.compensation.elasticity import CalibrationSet
from icenav.devices.registration import (
    Registration,
    kabsch_umeyama,
    register_tracker,
    registration_joint_states,
)
from icenav.errors import (
    FileFormatError,
    InvalidValueError,
    ShapeError,
    StoreError,
    UnsupportedVersionError,
)
from icenav.geometry.kinematics import forward
from icenav.geometry.se3 import rotvec_to_matrix
from icenav.persistence.store import SessionStore
from icenav.sim import CatheterPlant, EMTracker, TrackerConfig


def _random_transform(rng: np.random.Generator) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rotvec_to_matrix(rng.normal(size=3))
    t[:3, 3] = rng.uniform(-300, 300, 3)
    return t


def test_kabsch_recovers_a_known_transform_exactly() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        a2b = _random_transform(rng)
        a = rng.uniform(-50, 50, size=(int(rng.integers(3, 30)), 3))
        b = a @ a2b[:3, :3].T + a2b[:3, 3]
        np.testing.assert_allclose(kabsch_umeyama(a, b), a2b, atol=1e-9)


def test_kabsch_never_returns_a_reflection() -> None:
    rng = np.random.default_rng(1)
    a = rng.normal(size=(10, 3))
    b = a * [1, 1, -1]  # a mirror image: the best proper rotation, not the reflection
    assert np.linalg.det(kabsch_umeyama(a, b)[:3, :3]) == pytest.approx(1.0)


def test_kabsch_rejects_bad_point_sets() -> None:
    with pytest.raises(InvalidValueError, match="collinear"):
        line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
        kabsch_umeyama(line, line)
    with pytest.raises(InvalidValueError, match="at least 3 point pairs"):
        kabsch_umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ShapeError, match=r"shape \(n, 3\)"):
        kabsch_umeyama(np.zeros((4, 3)), np.zeros((5, 3)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_registration_recovers_the_trackers_pose_on_the_twin(seed: int) -> None:
    rng = np.random.default_rng(seed)
    truth = _random_transform(rng)
    # place the field generator so the tip is inside its volume: tracker origin ~300 mm away
    truth[:3, 3] = -truth[:3, :3] @ np.array([0.0, 0.0, 300.0]) + [0.0, 0.0, 60.0]
    cfg = TrackerConfig(tracker2base=truth, dropout_probability=0.02)
    plant = CatheterPlant(seed=seed)
    tracker = EMTracker(plant, seed=seed, config=cfg)
    q = registration_joint_states()
    poses = []
    for row in q:
        plant.move(row)
        tip = tracker.measure_tip2base(n_average=8)
        poses.append(
            np.full((4, 4), np.nan)
            if tip is None
            else np.linalg.inv(truth) @ tip @ cfg.sensor2tip  # the tracked sensor2tracker
        )
    reg = register_tracker(q, np.stack(poses), cfg.sensor2tip)
    assert reg.n_points >= len(q) - 3
    rot_err = math.degrees(
        math.acos(np.clip((np.trace(truth[:3, :3].T @ reg.tracker2base[:3, :3]) - 1) / 2, -1, 1))
    )
    # the tracker error (1.4 mm, 0.5 deg) and the roll play limit the accuracy
    assert rot_err < 1.0
    centre = np.array([0.0, 0.0, 70.0, 1.0])  # a point near the working tip, base frame
    moved = reg.tracker2base @ np.linalg.inv(truth) @ centre
    assert np.linalg.norm(moved[:3] - centre[:3]) < 2.0
    assert reg.rms_residual_mm < 3.0


def test_register_tracker_rejects_mismatched_shapes() -> None:
    with pytest.raises(ShapeError, match=r"q_model must be \(n, 4\)"):
        register_tracker(np.zeros((3, 4)), np.zeros((2, 4, 4)), np.eye(4))


def _a_registration() -> Registration:
    rng = np.random.default_rng(9)
    return Registration(
        tracker2base=_random_transform(rng),
        rms_residual_mm=0.42,
        max_residual_mm=0.9,
        n_points=36,
        sensor2tip=_random_transform(rng),
    )


def test_a_registration_round_trips_through_its_dict_and_json() -> None:
    reg = _a_registration()
    again = Registration.from_dict(json.loads(json.dumps(reg.to_dict())))
    assert again == reg
    assert again.to_dict()["format"] == 1
    assert not again.tracker2base.flags.writeable


def test_a_registration_round_trips_through_the_session_file(tmp_path: Path) -> None:
    reg = _a_registration()
    path = tmp_path / "session.icenav"
    with SessionStore(path) as store:
        assert store.registration() is None
        store.save_registration(reg, created_s=12.5)
    with SessionStore(path) as store:  # reopened: committed at once
        assert store.registration() == reg
        with pytest.raises(StoreError, match="must be a Registration"):
            store.save_registration("reg", created_s=0.0)  # type: ignore[arg-type]


def test_a_registration_round_trips_through_a_calibration_file(tmp_path: Path) -> None:
    q = np.zeros((3, 4))
    q[:, 0] = [0.0, 0.3, 0.6]
    cal = CalibrationSet(q_motor=q, tip2base=forward(q), catheter_id="c7", method="dense-raster")
    reg = _a_registration()
    path = tmp_path / "cal.json"
    CalibrationFile(cal, reg).save(path)
    loaded = CalibrationFile.load(path)
    assert loaded.registration == reg
    np.testing.assert_array_equal(loaded.calibration.tip2base, cal.tip2base)
    assert CalibrationSet.load(path).catheter_id == "c7"  # the samples alone read too
    # a version 1 file (before registrations were stored) still loads, without one
    old = cal.to_dict()
    old["version"] = 1
    (tmp_path / "old.json").write_text(json.dumps(old))
    assert CalibrationFile.load(tmp_path / "old.json").registration is None


@pytest.mark.parametrize(
    ("change", "error", "match"),
    [
        (lambda d: d.update(format=2), UnsupportedVersionError, "format 2 is not known"),
        (lambda d: d.pop("sensor2tip"), FileFormatError, "lacks 'sensor2tip'"),
        (lambda d: d.update(tracker2base=[[1.0, 2.0]]), FileFormatError, "bad registration"),
        (lambda d: d.update(rms_residual_mm=-1.0), FileFormatError, r"rms_residual_mm .* >= 0 mm"),
    ],
)
def test_a_bad_registration_document_is_refused_with_its_source(
    change: Any, error: type[Exception], match: str
) -> None:
    doc = _a_registration().to_dict()
    change(doc)
    with pytest.raises(error, match=match) as info:
        Registration.from_dict(doc, source="cal.json: registration")
    assert "cal.json: registration" in str(info.value)
    with pytest.raises(ShapeError, match=r"one \(4, 4\) transform"):
        Registration.given(np.tile(np.eye(4), (2, 1, 1)), np.eye(4))

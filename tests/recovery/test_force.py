"""The operator's contact forces per roadmap vertex and the limit of a return, Eqs. (F1)-(F5)."""

from __future__ import annotations

import numpy as np
import pytest

from icenav.errors import ConfigurationError, ShapeError
from icenav.recovery.drift import REST_Q_TOLERANCE, tip_drift
from icenav.recovery.force import (
    ForceCheck,
    ForceMap,
    ForceRecord,
    PathForces,
    TipForceMap,
    TipTrace,
    effective_offset,
    force_excess,
    force_limit,
    shape_reference,
)
from icenav.recovery.roadmap import Roadmap


def test_the_map_keeps_the_largest_force_per_vertex_and_fills_gaps_along_a_path() -> None:
    rm = Roadmap(epsilon=1.0)
    forces = ForceMap(capacity=2)
    qs = np.zeros((6, 4))
    qs[:, 3] = np.arange(6) * 0.9  # mm: a straight trace, one vertex per state
    for i, q in enumerate(qs):
        v = rm.add(q)
        forces.record(v, None if i == 4 else 0.1 * i)
    forces.record(rm.vertex_of(qs[2]), 0.05)  # a lower reading later: the larger stays
    forces.record(-1, 3.0)  # not recorded: ignored
    assert forces.n_recorded == 5
    np.testing.assert_allclose(forces.at([0, 2, 4, 99]), [0.0, 0.2, np.nan, np.nan])
    profile = forces.profile(rm, qs[::-1], radius=0.5)  # each state's own vertex
    assert profile is not None
    np.testing.assert_allclose(profile, [0.5, 0.5, 0.3, 0.2, 0.1, 0.0])  # state 4 from 5
    near = forces.profile(rm, qs[::-1])  # the largest within epsilon (1 mm here)
    np.testing.assert_allclose(near, [0.5, 0.5, 0.3, 0.3, 0.2, 0.1])
    assert ForceMap().profile(rm, qs) is None  # nothing recorded: no check
    with pytest.raises(ConfigurationError):
        forces.record(0, -0.1)


def test_the_limit_is_the_larger_end_of_the_segment_plus_the_margin() -> None:
    profile = np.array([0.1, 0.4, 0.2])
    assert force_excess(profile, 0, 0.6, 0.25, 0.0) == pytest.approx(-0.05)
    assert force_excess(profile, 1, 0.7, 0.25, 0.0) == pytest.approx(0.05)
    assert force_excess(profile, 2, 0.5, 0.25, 0.0) == pytest.approx(0.05)  # the end: itself
    assert force_limit(profile, 1, 0.05, 0.5) == pytest.approx((0.4, 0.65))


def _pose(p: list[float], z: list[float] | None = None) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = p
    if z is not None:  # a rotation taking the z axis to ``z`` (about x)
        zz = np.asarray(z, float) / np.linalg.norm(z)
        t[:3, 2] = zz
        t[:3, 1] = np.cross(zz, t[:3, 0])
    return t


def test_the_tip_reference_is_the_largest_force_where_the_operator_had_the_tip() -> None:
    tips = TipForceMap(radius_mm=2.0, angle_deg=10.0)
    assert tips.reference(_pose([0, 0, 0])) is None  # nothing recorded
    tips.record(_pose([0, 0, 0]), 0.5)
    tips.record(_pose([1.5, 0, 0]), 0.8)
    tips.record(_pose([0, 3.0, 0]), 2.0)  # 3 mm away: outside the radius
    tips.record(_pose([0.5, 0, 0], [0, 0.5, 1.0]), 5.0)  # tilted 27 deg: outside the angle
    tips.record(None, 9.0)
    tips.record(_pose([0, 0, 0]), None)
    assert tips.n_samples == 4
    assert tips.reference(_pose([0.5, 0, 0])) == pytest.approx(0.8)
    assert tips.reference(_pose([0, 2.5, 0])) == pytest.approx(2.0)
    assert tips.reference(_pose([10, 0, 0])) is None
    assert tips.reference(None) is None
    again = TipForceMap.from_samples(tips.samples(), 2.0, 10.0)
    assert again.reference(_pose([0.5, 0, 0])) == pytest.approx(0.8)
    with pytest.raises(ConfigurationError):
        tips.record(_pose([0, 0, 0]), float("nan"))
    with pytest.raises(ShapeError):
        tips.record(np.eye(3), 1.0)
    with pytest.raises(ConfigurationError):
        TipForceMap(radius_mm=0.0)


def test_the_effective_state_offsets_roll_and_translation_from_the_tips() -> None:
    d_rho, d_s = effective_offset([0.0, 10.0, 5.0], [10.0, 0.0, 3.0])
    assert d_rho == pytest.approx(np.pi / 2) and d_s == pytest.approx(2.0)
    assert effective_offset([0.5, 0.0, 1.0], [10.0, 0.0, 0.0])[0] == 0.0  # on the axis
    rm = Roadmap(epsilon=1.0)
    forces, trace = ForceMap(), TipTrace(capacity=1)
    for d4 in (0.0, 3.0):  # two vertices 3 mm apart, the tip 3 mm further at the second
        v = rm.add([0.0, 0.0, 0.0, d4])
        forces.record(v, 0.2 if d4 == 0.0 else 1.5)
        trace.record(v, _pose([10.0, 0.0, 50.0 + d4]))
    assert trace.n_recorded == 2
    # at the first motor state with the tip where the second put it (3 mm of lost motion):
    # the force the operator produced with that shape
    now = _pose([10.0, 0.0, 53.0])
    assert shape_reference(forces, trace, rm, [0, 0, 0, 0], now) == pytest.approx(1.5)
    assert shape_reference(forces, trace, rm, [0, 0, 0, 0], None) is None
    ids, sums, counts = trace.rows()
    copy = TipTrace()
    copy.add_rows(ids, sums, counts)
    np.testing.assert_allclose(copy.mean_at([0, 1, 7]), trace.mean_at([0, 1, 7]))


def test_the_record_hands_the_store_each_changed_vertex_once() -> None:
    rec = ForceRecord()
    rec.record(3, 0.4, _pose([0, 0, 0]))
    rec.record(3, 0.2, None)
    rec.record(5, None, _pose([0, 0, 0]))  # no force: nothing
    assert rec.take_vertex_rows() == [(3, 0.4)]
    assert rec.take_vertex_rows() == []
    assert rec.n_tip_rows == 1 and len(rec.tip_rows(0, 1)[0]) == 7
    back = ForceRecord.from_rows([(3, 0.4)], np.array(rec.tip_rows(0, 1)))
    assert back.forces.at([3])[0] == pytest.approx(0.4)
    assert back.tips.reference(_pose([0.1, 0, 0])) == pytest.approx(0.4)


def test_the_path_forces_are_found_as_the_return_goes() -> None:
    rm = Roadmap(epsilon=1.0)
    forces = ForceMap()
    qs = np.zeros((6, 4))
    qs[:, 3] = np.arange(6) * 0.9
    for i, q in enumerate(qs):
        forces.record(rm.add(q), None if i == 4 else 0.1 * i)
    back = PathForces(forces, rm, qs[::-1], radius=0.5, ahead=1)
    assert [back.recorded(i) for i in range(3)] == pytest.approx([0.5, 0.5, 0.3])
    gap_first = PathForces(forces, rm, qs[4:], radius=0.5)
    assert gap_first.recorded(0) == pytest.approx(0.5)  # the first one ahead
    assert PathForces(ForceMap(), rm, qs).recorded(2) is None  # nothing recorded: no check


def test_a_still_catheter_adds_no_tip_rows_unless_the_force_rises() -> None:
    tips = TipForceMap(radius_mm=8.0, angle_deg=180.0, min_spacing_mm=0.5)
    for k in range(50):
        tips.record(_pose([0.001 * k, 0, 0]), 0.3)
    tips.record(_pose([0.06, 0, 0]), 0.9)  # larger: kept
    tips.record(_pose([1.0, 0, 0]), 0.1)  # moved: kept
    assert tips.n_samples == 3
    assert tips.reference(_pose([0, 0, 0])) == pytest.approx(0.9)


def test_the_hold_stops_exactly_where_the_window_minimum_first_exceeds_the_margin() -> None:
    """Eq. (F4) streamed (ForceCheck) against its batch form (the study's sliding-window
    minimum of F - (1 + c) F_ref): the same first stop on random series."""
    rng = np.random.default_rng(7)
    dt, hold, c, m = 0.01, 0.05, 0.5, 0.05
    w = round(hold / dt) + 1
    for _ in range(200):
        ref = rng.uniform(0.0, 1.0, 60)
        f = (1 + c) * ref + m + rng.normal(0.02, 0.05, 60)
        check = ForceCheck(margin_n=m, margin_fraction=c, hold_s=hold)
        streamed = next((k for k in range(60) if check.update(f[k], ref[k], dt)), None)
        ex = f - (1 + c) * ref
        windows = np.lib.stride_tricks.sliding_window_view(ex, w).min(axis=1)
        batch = next((k + w - 1 for k in range(len(windows)) if windows[k] > m), None)
        assert streamed == batch
    check = ForceCheck(margin_n=0.1, margin_fraction=0.0, hold_s=0.0)
    stop = check.update(0.5, 0.2, dt)  # hold 0: the first cycle above stops (F1 as it was)
    assert stop is not None and stop.limit_n == pytest.approx(0.3) and stop.held_s == 0.0
    assert ForceCheck(hold_s=0.0).update(5.0, None, dt) is None  # no reference: no check
    with pytest.raises(ConfigurationError):
        ForceCheck(hold_s=-1.0)


def test_the_rest_tip_is_where_the_operator_last_moved_and_anything_else_forgets_it() -> None:
    """Eq. (F5): the tip where the operator's last motion left it; a return or refinement
    moving the motors (operator False) or a motion without a pose forgets it."""
    rec = ForceRecord()
    assert rec.rest_tip is None
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 40.0]
    rec.note_motion(pose, operator=True)
    np.testing.assert_array_equal(rec.rest_tip, [1.0, 2.0, 40.0])
    moved = pose.copy()
    moved[1, 3] += 6.0
    assert tip_drift(rec.rest_tip, moved) == pytest.approx(6.0)
    assert tip_drift(rec.rest_tip, None) is None
    rec.note_motion(pose, operator=False)
    assert rec.rest_tip is None and tip_drift(rec.rest_tip, moved) is None
    rec.note_motion(pose, operator=True)
    rec.note_motion(None, operator=True)
    assert rec.rest_tip is None
    with pytest.raises(ShapeError):
        rec.note_motion(np.eye(3), operator=True)


def test_a_restored_rest_pose_stands_only_while_the_motors_stand_where_it_was_left() -> None:
    """After a restart (Eq. F5 across a crash): the stored rest tip is kept when the robot
    reports the stored motor state within the tolerance, and forgotten otherwise or when it
    was stored without one; a bad stored value is refused with its name."""
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 40.0]
    q = np.array([0.1, -0.2, 0.3, 12.0])
    rec = ForceRecord()
    rec.note_motion(pose, operator=True, q=q)
    np.testing.assert_array_equal(rec.rest_q, q)
    back = ForceRecord.from_rows(
        np.zeros((0, 2)), np.zeros((0, 7)), rest=(rec.rest_tip, rec.rest_q)
    )
    kept = back.rest
    assert back.keep_rest_if_at(q + 0.5 * REST_Q_TOLERANCE) and back.rest is kept
    np.testing.assert_array_equal(back.rest_tip, [1.0, 2.0, 40.0])
    assert not back.keep_rest_if_at(q + [0.0, 0.0, 0.0, 2.0 * REST_Q_TOLERANCE])
    assert back.rest_tip is None and back.rest_q is None and back.rest is None
    no_q = ForceRecord()
    no_q.note_motion(pose, operator=True)  # an older caller: no motor state
    assert not no_q.keep_rest_if_at(q) and no_q.rest_tip is None
    with pytest.raises(ShapeError, match="rest_q"):
        ForceRecord().restore_rest([1.0, 2.0, 3.0], [0.0, 0.0, np.nan, 0.0])
    with pytest.raises(ShapeError, match="rest_tip"):
        ForceRecord().restore_rest([1.0, 2.0], q)


def test_a_question_of_the_drift_check_lasts_only_while_the_operator_leaves_the_motors() -> None:
    """Eq. (F6)'s question belongs to the reference it was asked from: the operator's next
    drive makes a new reference that asks anew; any other motion (the return itself)
    forgets the reference, so the check is armed again only by the operator."""
    record = ForceRecord()
    pose = np.eye(4)
    record.note_motion(pose, True, np.zeros(4), 0.0)
    assert record.rest is not None
    record.rest.ask(1.0)
    assert record.rest.confirmed(2.0)
    record.note_motion(pose, True, np.zeros(4), 3.0)
    assert record.rest is not None and not record.rest.confirmed(4.0)
    record.rest.ask(4.0)
    record.note_motion(pose, False, None, 5.0)
    assert record.rest is None

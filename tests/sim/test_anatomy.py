"""The heart phantom: registration, labels, valves, motion, catheter workspace."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from icenav._validation import check_transform
from icenav.errors import ConfigurationError, NonFiniteError, ShapeError
from icenav.geometry.kinematics import CatheterGeometry
from icenav.sim.anatomy import (
    ACOUSTICS,
    BASE2ANATOMY,
    BLOOD_LABELS,
    ECHOGENICITY,
    EXAMPLE_VIEWS,
    PATIENT_DIRECTIONS,
    ROI_LABELS,
    CardiacMotion,
    Region,
    Tissue,
    default_phantom,
    tip2anatomy,
)
from icenav.sim.anatomy.phantom import _bump, _bump_at
from icenav.sim.ultrasound import UltrasoundRenderer

STILL = CardiacMotion(
    ventricular_contraction=0.0,
    atrial_filling=0.0,
    valve_plane_descent_mm=0.0,
    respiratory_amplitude_mm=(0.0, 0.0, 0.0),
)


def test_base2anatomy_is_rigid_and_images_anteriorly_up_the_ra() -> None:
    check_transform(BASE2ANATOMY)
    t = tip2anatomy(np.zeros(4))
    # catheter axis superior, image facing anterior (-y in LPS)
    np.testing.assert_allclose(t[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(t[:3, 0], [0.0, -1.0, 0.0], atol=1e-12)


def test_ra_dimensions_match_typical_adult_values() -> None:
    ra = default_phantom().chamber("ra")
    axes = 2.0 * np.asarray(ra.semi_axes)
    # short axis ~36-44 mm, long axis ~42-53 mm (Bommer 1979; ASE/EACVI 2015 upper normal)
    assert 36.0 <= min(axes) <= 44.0
    assert 42.0 <= max(axes) <= 53.0


def test_known_points_have_their_labels() -> None:
    ph = default_phantom(STILL)
    pts = np.array(
        [
            ph.chamber("ra").centre,
            ph.chamber("la").centre,
            ph.chamber("lv").centre,
            ph.septum_centre,
            (200.0, 200.0, 200.0),
            (0.0, 3.0, -40.0),  # in the IVC, on the catheter's path
        ]
    )
    labels = ph.labels_at(pts, 0.0)
    assert labels.tolist() == [
        Tissue.RA_BLOOD,
        Tissue.LA_BLOOD,
        Tissue.LV_BLOOD,
        Tissue.SEPTUM,
        Tissue.SURROUNDING,
        Tissue.CAVA_BLOOD,
    ]


def test_labels_keep_the_batch_shape_and_reject_bad_input() -> None:
    ph = default_phantom()
    assert ph.labels_at(np.zeros((2, 5, 3)), 0.3).shape == (2, 5)
    with pytest.raises(ShapeError, match=r"\(\.\.\., 3\)"):
        ph.labels_at(np.zeros((4, 2)), 0.0)
    with pytest.raises(NonFiniteError, match="points"):
        ph.labels_at(np.array([0.0, np.nan, 0.0]), 0.0)


def test_blood_is_darker_than_every_tissue() -> None:
    blood = max(ECHOGENICITY[b] for b in BLOOD_LABELS)
    for tissue, value in ECHOGENICITY.items():
        if tissue not in BLOOD_LABELS:
            assert value > 2.0 * blood, tissue
    assert set(ECHOGENICITY) == set(Tissue)


@pytest.mark.parametrize(
    ("valve", "open_phase", "closed_phase"),
    [
        ("aortic_valve", 0.2, 0.7),
        ("mitral_valve", 0.7, 0.2),
        ("tricuspid_valve", 0.7, 0.2),
    ],
)
def test_valves_open_and_close_over_the_beat(
    valve: str, open_phase: float, closed_phase: float
) -> None:
    ph = default_phantom()
    period = ph.motion.period_s
    t_open, t_closed = open_phase * period, closed_phase * period
    assert ph.valve_opening(valve, t_open) == 1.0
    assert ph.valve_opening(valve, t_closed) == 0.0
    # closed leaflets meet at the annulus centre; open, the centre is blood
    centre_closed = ph.roi_centroid(valve, t_closed)
    centre_open = ph.roi_centroid(valve, t_open)
    assert ph.labels_at(centre_closed, t_closed) == ROI_LABELS[valve]
    assert int(ph.labels_at(centre_open, t_open)) in {int(b) for b in BLOOD_LABELS}


def test_the_unbounded_chamber_distance_is_the_bounded_formula_to_the_bit() -> None:
    """The contact solve's unbounded distance (every point, no subsets) equals the bounded
    path with a bound no point reaches; a non-finite point stays at the bound."""
    rng = np.random.default_rng(7)
    pts = rng.normal(0.0, 40.0, (500, 3))
    for ch in default_phantom().chambers:  # axis-aligned and rotated chambers
        fast = ch.sdf(pts)
        assert np.array_equal(fast, ch.sdf(pts, beyond_mm=1e300))
        near = ch.sdf(pts, beyond_mm=5.0)
        assert np.array_equal(near[near < 5.0], fast[near < 5.0])
        assert ch.sdf(np.array([[np.nan, 0.0, 0.0]]))[0] == np.inf


def test_the_scalar_bump_is_the_array_bump_to_the_bit() -> None:
    """The displacement field's bumps of one phase equal the array form exactly."""
    phases = np.concatenate([np.random.default_rng(8).uniform(-2.0, 3.0, 4000), [0.0, 0.45]])
    for p in phases:
        for start, end in ((0.0, 0.45), (0.82, 0.98)):
            assert _bump_at(float(p), start, end) == float(_bump(float(p), start, end))


def test_material_and_spatial_points_round_trip() -> None:
    ph = default_phantom()
    rng = np.random.default_rng(3)
    for _ in range(20):
        x_mat = rng.uniform(-30.0, 70.0, 3)
        t = float(rng.uniform(0.0, 10.0))
        x = ph.spatial_point(x_mat, t)
        np.testing.assert_allclose(ph.material_points(x, t), x_mat, atol=1e-5)


def test_motion_is_a_few_mm_and_periodic_in_the_heart_beat() -> None:
    ph = default_phantom(CardiacMotion(respiratory_amplitude_mm=(0.0, 0.0, 0.0)))
    period = ph.motion.period_s
    ts = np.linspace(0.0, period, 25)
    for name in ph.roi_names:
        track = np.array([ph.roi_centroid(name, t) for t in ts])
        excursion = np.linalg.norm(track - track[0], axis=1).max()
        assert 1.0 < excursion < 15.0, (name, excursion)
        np.testing.assert_allclose(track[-1], track[0], atol=1e-9)
    breathing = default_phantom()
    p0 = breathing.roi_centroid("aortic_valve", 0.0)
    quarter = breathing.motion.respiratory_period_s / 4.0
    # at a quarter breath, in a beat's same phase, the respiratory shift is the amplitude
    t_q = round(quarter / period) * period
    shift = breathing.roi_centroid("aortic_valve", t_q) - p0
    expected = np.asarray(breathing.motion.respiratory_amplitude_mm) * math.sin(
        2.0 * math.pi * t_q / breathing.motion.respiratory_period_s
    )
    np.testing.assert_allclose(shift, expected, atol=1e-6)


def test_the_valve_plane_descends_towards_the_apex_in_systole() -> None:
    """The atrioventricular plane moves towards the apex in systole (long-axis shortening,
    MAPSE / TAPSE), so the mitral annulus at peak systole lies nearer the LV apex."""
    still_breath = CardiacMotion(
        ventricular_contraction=0.0, atrial_filling=0.0, respiratory_amplitude_mm=(0, 0, 0)
    )
    ph = default_phantom(still_breath)
    lv = next(c for c in ph.chambers if c.name == "lv")
    apex = np.asarray(lv.centre) + 42.0 * np.asarray(lv.long_axis) / np.linalg.norm(lv.long_axis)
    period = ph.motion.period_s
    for name in ("mitral_valve", "aortic_valve", "tricuspid_valve"):
        diastole = ph.roi_centroid(name, 0.7 * period)
        systole = ph.roi_centroid(name, 0.225 * period)  # the peak of the systolic bump
        towards = float(np.linalg.norm(diastole - apex) - np.linalg.norm(systole - apex))
        assert towards > 2.0, (name, towards)


def test_unknown_structures_are_rejected() -> None:
    ph = default_phantom()
    with pytest.raises(ConfigurationError, match="unknown valve 'pulmonary_valve'"):
        ph.valve_opening("pulmonary_valve", 0.0)
    with pytest.raises(ConfigurationError, match="unknown chamber"):
        ph.chamber("la_appendage")


def test_heart_rate_outside_range_is_rejected() -> None:
    with pytest.raises(ConfigurationError, match="heart_rate_bpm"):
        CardiacMotion(heart_rate_bpm=10.0)
    assert 60.0 <= CardiacMotion().heart_rate_bpm <= 80.0


def _workspace(max_bend_deg: float) -> np.ndarray:
    knobs = np.radians(np.arange(-90.0, 91.0, 10.0))
    d4 = np.arange(-20.0, 21.0, 5.0)
    p1, p2, dd = np.meshgrid(knobs, knobs, d4, indexing="ij")
    q = np.stack([p1.ravel(), p2.ravel(), np.zeros(p1.size), dd.ravel()], axis=-1)
    keep = np.degrees(np.hypot(q[:, 0], q[:, 1])) <= max_bend_deg + 1e-9
    return q[keep]


def test_catheter_workspace_lies_in_the_right_atrium() -> None:
    ph = default_phantom()
    # straight catheter: transducer in RA blood (at the top, the SVC orifice)
    d4 = np.arange(-20.0, 21.0, 2.0)
    straight = np.stack([np.zeros_like(d4)] * 3 + [d4], axis=-1)
    labels = ph.labels_at(tip2anatomy(straight)[:, :3, 3], 0.0)
    assert np.all(labels[np.abs(d4) <= 10.0] == Tissue.RA_BLOOD)
    assert np.all(np.isin(labels, [int(Tissue.RA_BLOOD), int(Tissue.CAVA_BLOOD)]))
    # the working range of bends (<= 30 deg) over d4 in [-20, 20] mm: mostly in RA blood
    q = _workspace(30.0)
    labels = ph.labels_at(tip2anatomy(q)[:, :3, 3], 0.0)
    assert np.mean(labels == Tissue.RA_BLOOD) > 0.6
    assert np.mean(np.isin(labels, [int(b) for b in BLOOD_LABELS])) > 0.65
    # the full +-90 deg knob grid reaches beyond a normal RA (documented, not hidden)
    full = ph.labels_at(tip2anatomy(_workspace(180.0))[:, :3, 3], 0.0)
    assert np.mean(full == Tissue.RA_BLOOD) < 0.5


@pytest.mark.parametrize("valve", sorted(EXAMPLE_VIEWS))
def test_each_valve_is_seen_from_a_reachable_pose_in_the_ra(valve: str) -> None:
    ph = default_phantom()
    q = np.asarray(EXAMPLE_VIEWS[valve])
    geometry = CatheterGeometry()
    t = tip2anatomy(q, geometry)  # validates the joint limits
    # the transducer is in RA blood, clear of walls and leaflets by 3.5 mm, all beat long
    # (the valve plane's systolic descent brings the wall nearest the aortic view to 3.75 mm)
    around = t[:3, 3] + np.vstack([np.zeros(3), 3.5 * np.eye(3), -3.5 * np.eye(3)])
    for phase in np.linspace(0.0, 1.0, 8, endpoint=False):
        assert np.all(ph.labels_at(around, phase * ph.motion.period_s) == Tissue.RA_BLOOD)
    renderer = UltrasoundRenderer(ph)
    for phase in (0.1, 0.6):
        frame = renderer.render(t, phase * ph.motion.period_s)
        roi = frame.rois[valve]
        assert roi.n_pixels >= 30, (valve, phase, roi.n_pixels)
        assert renderer.in_sector(ph.roi_centroid(valve, frame.t), t)


def test_the_heart_sits_in_a_pericardium_between_the_lungs() -> None:
    ph = default_phantom(STILL)
    ra = np.asarray(ph.chamber("ra").centre)
    # from the RA centre towards the patient's right: RA blood, wall, fat, pericardium, lung
    xs = np.arange(0.0, 60.0, 0.25)
    labels = ph.labels_at(ra - xs[:, None] * np.array([1.0, 0.0, 0.0]), 0.0)
    order = [int(k) for k, _ in itertools.groupby(labels.tolist())]
    assert order == [
        Tissue.RA_BLOOD,
        Tissue.MYOCARDIUM,
        Tissue.SURROUNDING,
        Tissue.PERICARDIUM,
        Tissue.SURROUNDING,
        Tissue.LUNG,
    ]
    thick = np.count_nonzero(labels == Tissue.PERICARDIUM) * 0.25
    assert thick == pytest.approx(ph.pericardium_mm, abs=0.5)
    # adjacent chambers share their walls: between RV and LV cavities, no fat
    rv, lv = np.asarray(ph.chamber("rv").centre), np.asarray(ph.chamber("lv").centre)
    between = ph.labels_at(rv + np.linspace(0.0, 1.0, 400)[:, None] * (lv - rv), 0.0)
    assert Tissue.SURROUNDING not in between.tolist()


def test_landmarks_name_every_structure_inside_it() -> None:
    ph = default_phantom(STILL)
    marks = {m.key: m for m in ph.landmarks()}
    wanted = {"ra", "rv", "la", "lv", "aorta", "ivc", "svc", "interatrial_septum"}
    wanted |= {"tricuspid_valve", "mitral_valve", "aortic_valve"}
    assert wanted <= set(marks)
    assert [marks[k].label for k in ("ra", "rv", "la", "lv", "ivc", "svc")] == [
        "RA",
        "RV",
        "LA",
        "LV",
        "IVC",
        "SVC",
    ]
    inside = {
        "ra": Tissue.RA_BLOOD,
        "rv": Tissue.RV_BLOOD,
        "la": Tissue.LA_BLOOD,
        "lv": Tissue.LV_BLOOD,
        "aorta": Tissue.AORTA_BLOOD,
        "ivc": Tissue.CAVA_BLOOD,
        "svc": Tissue.CAVA_BLOOD,
        "pa": Tissue.PA_BLOOD,
        "interatrial_septum": Tissue.SEPTUM,
    }
    for key, tissue in inside.items():
        assert ph.labels_at(marks[key].point, 0.0) == tissue, key


def test_patient_directions_are_the_lps_axes() -> None:
    for a, b in (("L", "R"), ("A", "P"), ("S", "I")):
        np.testing.assert_allclose(PATIENT_DIRECTIONS[a], -np.asarray(PATIENT_DIRECTIONS[b]))
    # the straight catheter images anteriorly: tip x is the patient's anterior
    np.testing.assert_allclose(tip2anatomy(np.zeros(4))[:3, 0], PATIENT_DIRECTIONS["A"], atol=1e-12)


def test_acoustic_table_is_complete_and_physical() -> None:
    assert set(ACOUSTICS) == set(Tissue)
    z = {t: p.impedance_mrayl for t, p in ACOUSTICS.items()}
    # soft tissues within 1.3-2.1 MRayl; lung far below, calcification far above
    for t, v in z.items():
        if t not in (Tissue.LUNG, Tissue.CALCIFICATION):
            assert 1.3 < v < 2.1, t
    assert z[Tissue.LUNG] < 0.5 and z[Tissue.CALCIFICATION] > 4.0
    with pytest.raises(ConfigurationError, match="nodule semi-axis"):
        Region("nodule", (0.0, 0.0, 0.0), (1.0, -1.0, 1.0), Tissue.CALCIFICATION)

"""The ICE B-mode renderer: geometry, tissue-fixed speckle, similarity behaviour."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.ndimage as ndi

from icenav.errors import ConfigurationError, TransformError
from icenav.eval.metrics import beat_similarity, blurred_ncc, ncc
from icenav.sim.anatomy import (
    ACOUSTICS,
    BLOOD_LABELS,
    EXAMPLE_VIEWS,
    STANDARD_VIEWS,
    CardiacMotion,
    Chamber,
    HeartPhantom,
    Region,
    Tissue,
    default_phantom,
    tip2anatomy,
)
from icenav.sim.ultrasound import SPECKLE_REDUCTION_MM, Frame, ProbeConfig, UltrasoundRenderer

STILL = CardiacMotion(
    ventricular_contraction=0.0,
    atrial_filling=0.0,
    valve_plane_descent_mm=0.0,
    respiratory_amplitude_mm=(0.0, 0.0, 0.0),
)


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(0.0, math.pi)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = rng.uniform(-50.0, 50.0, 3)
    return pose


def _detail(img: np.ndarray) -> np.ndarray:
    """The image minus its 3-pixel Gaussian blur (the speckle pattern)."""
    f = img.astype(np.float64)
    out: np.ndarray = f - ndi.gaussian_filter(f, 3.0)
    return out


def _sphere_phantom(centre: np.ndarray) -> HeartPhantom:
    """A single 2 mm bright ball (its 'wall') in dark surroundings, nothing else."""
    ball = Chamber("ra", tuple(centre.tolist()), (0.5, 0.5, 0.5), 1.5, Tissue.RA_BLOOD)
    return HeartPhantom((ball,), (), (), septum_radius_mm=1e-3, septum_mm=1e-3, motion=STILL)


@pytest.mark.parametrize("seed", range(4))
def test_a_known_point_appears_at_the_expected_pixel(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = _random_pose(rng)
    depth, lateral = rng.uniform(30.0, 100.0), rng.uniform(-20.0, 20.0)
    point = pose[:3, :3] @ np.array([depth, 0.0, lateral]) + pose[:3, 3]
    # no clutter; TGC compensating the surrounding fat's attenuation (0.63 dB/cm/MHz, 7 MHz)
    quiet = ProbeConfig(noise_level=0.0, clutter_db=-120.0, tgc_db_per_cm=2 * 0.63 * 7.0)
    renderer = UltrasoundRenderer(_sphere_phantom(point), quiet)
    frame = renderer.render(pose, 0.0)
    # expected pixel, from the documented pixel geometry
    s = renderer.config.pixel_mm
    row_exp = depth / s - 0.5
    col_exp = lateral / s - 0.5 + renderer.config.image_size / 2
    # the label map and the brightest blob put the ball there
    rows, cols = np.nonzero(frame.labels == Tissue.MYOCARDIUM)
    assert abs(rows.mean() - row_exp) < 1.0 and abs(cols.mean() - col_exp) < 1.0
    peak = np.unravel_index(np.argmax(frame.image), frame.image.shape)
    assert abs(peak[0] - row_exp) <= 3.0 and abs(peak[1] - col_exp) <= 3.0
    # the projection helper agrees
    px, off = renderer.project(point, pose)
    np.testing.assert_allclose(px, [row_exp, col_exp], atol=1e-9)
    assert abs(off) < 1e-9


def test_pixel_and_plane_coordinates_round_trip() -> None:
    r = UltrasoundRenderer()
    rng = np.random.default_rng(0)
    rows, cols = rng.uniform(0, 255, 50), rng.uniform(0, 255, 50)
    x, z = r.pixel_to_plane(rows, cols)
    back = r.plane_to_pixel(x, z)
    np.testing.assert_allclose(back[0], rows, atol=1e-12)
    np.testing.assert_allclose(back[1], cols, atol=1e-12)


def test_frame_layout_and_sector() -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS["aortic_valve"]))
    frame = r.render(pose, 0.1)
    assert isinstance(frame, Frame)
    assert frame.image.shape == frame.labels.shape == (256, 256)
    assert frame.image.dtype == np.uint8
    outside = frame.labels < 0
    assert np.all(frame.image[outside] == 0)
    # sector area ~ (pi/4) depth^2 of the 90 deg sector, in pixels
    expected = (math.pi / 4) * (r.config.depth_mm / r.config.pixel_mm) ** 2
    assert abs((~outside).sum() / expected - 1.0) < 0.03
    assert 0.12 <= r.config.depth_mm / 1000 <= 0.16
    # valves are brighter than blood in the picture
    valve = frame.image[frame.labels == Tissue.AORTIC_VALVE].mean()
    blood = frame.image[frame.labels == Tissue.RA_BLOOD].mean()
    assert valve > blood + 60


def test_speckle_is_fixed_to_tissue() -> None:
    # no noise, no motion: the same pose at another time gives the same picture;
    # a different scatterer texture gives a different one
    ph = default_phantom(STILL)
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS["tricuspid_valve"]))
    fixed = ProbeConfig(noise_level=0.0, flow_speckle=False)
    quiet = UltrasoundRenderer(ph, fixed)
    p = ph.motion.period_s
    a = quiet.render(pose, 0.2 * p).image
    b = quiet.render(pose, 3.2 * p).image
    np.testing.assert_array_equal(a, b)
    other = UltrasoundRenderer(ph, replace(fixed, seed=7)).render(pose, 0.2 * p)
    tissue = ndi.binary_erosion(
        np.isin(other.labels, [int(Tissue.SURROUNDING), int(Tissue.MYOCARDIUM)]), iterations=4
    )
    # the speckle (detail above the 3-pixel scale) differs; the anatomy does not
    assert ncc(_detail(a), _detail(other.image), tissue) < 0.7
    # flowing blood: its scatterers change between frames, the tissue's do not
    flowing = UltrasoundRenderer(ph, replace(fixed, flow_speckle=True))
    c, d = flowing.render(pose, 0.2 * p), flowing.render(pose, 3.2 * p)
    blood = np.isin(c.labels, [int(x) for x in BLOOD_LABELS])
    assert not np.array_equal(c.image[blood], d.image[blood])


def test_rendering_is_deterministic_and_noise_differs_between_frames() -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS["aortic_valve"]))
    f1 = r.render(pose, 0.5)
    f2 = r.render(pose, 0.5)
    np.testing.assert_array_equal(f1.image, f2.image)
    f3 = r.render(pose, 0.5, noise_seed=123)
    assert not np.array_equal(f1.image, f3.image)
    assert ncc(f1.image, f3.image) > 0.9


def _clip(r: UltrasoundRenderer, pose: np.ndarray, beat: int, n: int = 8) -> tuple[list, list]:
    period = r.phantom.motion.period_s
    frames = [r.render(pose, (beat + k / n) * period) for k in range(n)]
    return [f.image for f in frames], [f.cardiac_phase for f in frames]


@pytest.mark.parametrize("view", ["aortic_valve", "mitral_valve"])
def test_still_catheter_similarity_is_high_but_not_perfect_and_beats_moved(view: str) -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS[view]))
    mask = r.render(pose, 0.0).labels >= 0
    ref, ref_ph = _clip(r, pose, 0)
    still, still_ph = _clip(r, pose, 1)
    moved_pose = pose.copy()
    moved_pose[:3, 3] += pose[:3, :3] @ np.array([0.0, 3.0, 0.0])  # 3 mm out of plane
    moved, moved_ph = _clip(r, moved_pose, 1)
    s_still = beat_similarity(still, still_ph, ref, ref_ph, mask=mask)
    s_moved = beat_similarity(moved, moved_ph, ref, ref_ph, mask=mask)
    assert 0.8 < s_still < 0.99
    assert s_moved < s_still - 0.03


@pytest.mark.parametrize(
    ("view", "direction"),
    [
        ("aortic_valve", (0.0, 1.0, 0.0)),
        ("tricuspid_valve", (0.0, -1.0, 0.0)),
        ("mitral_valve", (1.0, 0.0, 0.0)),
    ],
)
def test_blurred_similarity_falls_monotonically_as_the_catheter_moves_away(
    view: str, direction: tuple[float, float, float]
) -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS[view]))
    t = 0.3 * r.phantom.motion.period_s
    ref = r.render(pose, t)
    mask = ref.labels >= 0
    values = []
    for step_mm in np.arange(0.5, 4.01, 0.5):
        moved = pose.copy()
        moved[:3, 3] += pose[:3, :3] @ (step_mm * np.asarray(direction))
        values.append(blurred_ncc(ref.image, r.render(moved, t).image, mask=mask))
    assert np.all(np.diff(values) < 0.0), np.round(values, 4)
    # the fall over 4 mm stands far above the frame-to-frame noise of the measure
    # (electronic noise, flowing blood: the same pose and time with another noise seed)
    noise = 1.0 - blurred_ncc(ref.image, r.render(pose, t, noise_seed=99).image, mask=mask)
    assert values[0] > 0.9 and values[0] - values[-1] > 10.0 * noise, (values, noise)


def test_render_clip_is_a_still_catheter_over_time() -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(EXAMPLE_VIEWS["mitral_valve"]))
    clip = r.render_clip(pose, 1.0, 3, 0.05)
    assert [f.t for f in clip] == pytest.approx([1.0, 1.05, 1.1])
    np.testing.assert_array_equal(clip[2].image, r.render(pose, 1.1).image)
    with pytest.raises(ConfigurationError, match="frame_time_s"):
        r.render_clip(pose, 0.0, 3, 0.0)


def test_bad_input_is_rejected() -> None:
    r = UltrasoundRenderer()
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(TransformError, match="tip2anatomy"):
        r.render(bad, 0.0)
    with pytest.raises(ConfigurationError, match="depth_mm"):
        ProbeConfig(depth_mm=5.0)
    with pytest.raises(ConfigurationError, match="sector_angle"):
        ProbeConfig(sector_angle=4.0)
    with pytest.raises(ConfigurationError, match="n_beams"):
        ProbeConfig(n_beams=3)


def _eroded(labels: np.ndarray, tissues: list[int], px: int) -> np.ndarray:
    out: np.ndarray = ndi.binary_erosion(np.isin(labels, tissues), iterations=px)
    return out


BLOOD_OVER_MYOCARDIUM = 0.35
"""Blood is anechoic: its mean grey is below this fraction of myocardium's (region
interiors: blood 3 px and myocardium 1 px inside their label-map outlines)."""


@pytest.mark.parametrize("key", sorted(STANDARD_VIEWS))
def test_standard_views_show_their_structures_with_dark_blood(key: str) -> None:
    view = STANDARD_VIEWS[key]
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(view.q))
    for phase in (0.15, 0.65):
        f = r.render(pose, phase * r.phantom.motion.period_s)
        for tissue in view.structures:
            assert np.count_nonzero(f.labels == tissue) >= 30, (key, phase, tissue)
        blood = _eroded(f.labels, [int(b) for b in BLOOD_LABELS], 3)
        myo = _eroded(f.labels, [int(Tissue.MYOCARDIUM)], 1)
        assert blood.sum() > 300 and myo.sum() > 100
        ratio = f.image[blood].mean() / f.image[myo].mean()
        assert ratio < BLOOD_OVER_MYOCARDIUM, (key, phase, ratio)


def test_echo_field_follows_reflection_transmission_and_attenuation() -> None:
    """Eqs. (I1)-(I4) on one beam through fat, a calcified layer and fat again."""
    r = UltrasoundRenderer(config=ProbeConfig(n_beams=16, n_samples=64, depth_mm=64.0))
    lab = np.full((16, 64), int(Tissue.SURROUNDING), dtype=np.int8)
    lab[:, 20:24] = int(Tissue.CALCIFICATION)
    _, transmitted = r.echo_field(lab, np.ones((16, 64), dtype=np.complex64))
    z_fat = ACOUSTICS[Tissue.SURROUNDING].impedance_mrayl
    z_ca = ACOUSTICS[Tissue.CALCIFICATION].impedance_mrayl
    gamma2 = ((z_ca - z_fat) / (z_ca + z_fat)) ** 2
    f_mhz, dr_cm = r.config.frequency_mhz, r.dr_mm / 10.0
    alpha = {t: 2.0 * ACOUSTICS[t].attenuation_db_cm_mhz * f_mhz * dr_cm for t in Tissue}
    # two-way loss to the middle of sample 30: 20 fat + 4 calcium + 6.5 fat samples
    loss_db = 26.5 * alpha[Tissue.SURROUNDING] + 4 * alpha[Tissue.CALCIFICATION]
    expected = (1.0 - gamma2) ** 2 * 10.0 ** (-loss_db / 20.0)
    np.testing.assert_allclose(transmitted[:, 30], expected, rtol=1e-4)


def test_a_strong_reflector_casts_a_shadow() -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(STANDARD_VIEWS["home"].q))
    t = 0.65 * r.phantom.motion.period_s
    depth_mm, lateral_mm = 45.0, -8.0
    centre = pose[:3, :3] @ np.array([depth_mm, 0.0, lateral_mm]) + pose[:3, 3]
    ph = r.phantom
    nodule = Region("nodule", tuple(centre.tolist()), (3.0, 3.0, 3.0), Tissue.CALCIFICATION)
    calcified = HeartPhantom(
        ph.chambers, ph.vessels, ph.valves, motion=ph.motion, pericardium_mm=2.0,
        lungs=ph.lungs, inclusions=(nodule,),
    )  # fmt: skip
    plain = r.render(pose, t).image.astype(float)
    shadowed = UltrasoundRenderer(calcified).render(pose, t).image.astype(float)
    # behind the nodule: 10-60 mm deeper, on the beams within 1 mm of its centre (beams
    # fan out from the apex, so the shadow widens with depth)
    rows, cols = np.mgrid[0:256, 0:256]
    x, z = r.pixel_to_plane(rows, cols)
    rng_mm, ang = np.hypot(x, z), np.arctan2(z, x)
    d0 = math.hypot(depth_mm, lateral_mm)
    a0 = math.atan2(lateral_mm, depth_mm)
    behind = (rng_mm > d0 + 10) & (rng_mm < d0 + 60) & (np.abs(ang - a0) * d0 < 1.0)
    assert behind.sum() > 40
    assert shadowed[behind].mean() < 0.3 * plain[behind].mean()
    # beside the shadow (beams passing 5-10 mm from it) the picture is unchanged on average
    beside = (rng_mm > d0 + 10) & (rng_mm < d0 + 60)
    beside &= (np.abs(ang - a0) * d0 > 5.0) & (np.abs(ang - a0) * d0 < 10.0)
    assert abs(shadowed[beside].mean() - plain[beside].mean()) < 0.1 * plain[beside].mean()


def test_tgc_gain_and_depth_are_settings() -> None:
    r = UltrasoundRenderer()
    pose = tip2anatomy(np.asarray(STANDARD_VIEWS["home"].q))
    f = r.render(pose, 0.3)
    tissue = f.labels == Tissue.SURROUNDING
    far = tissue & (np.arange(256)[:, None] > 120)
    no_tgc = r.with_settings(tgc_db_per_cm=0.0).render(pose, 0.3).image
    assert no_tgc[far].mean() < 0.2 * f.image[far].mean()  # attenuation shows without TGC
    brighter = r.with_settings(gain_db=6.0).render(pose, 0.3).image
    # +6 dB moves unsaturated grey up by 6 / dynamic range of the full scale
    mid = tissue & (f.image > 40) & (f.image < 200)
    step = 255.0 * 6.0 / r.config.dynamic_range_db
    assert abs((brighter[mid].astype(float) - f.image[mid]).mean() - step) < 0.25 * step
    shallow = r.with_settings(depth_mm=80.0)
    assert shallow.config.pixel_mm == pytest.approx(r.config.pixel_mm * 80.0 / 140.0)
    assert shallow._texture is r._texture  # the scatterers are shared


def test_lateral_resolution_worsens_with_depth() -> None:
    cfg = ProbeConfig()
    depths = np.array([20.0, 40.0, 80.0, 120.0, 140.0])
    fwhm = cfg.lateral_fwhm_mm(depths)
    assert np.all(np.diff(fwhm) > 0.0)
    # at the transmit focus, the two-way width is 1.02 lambda F# / sqrt(2) (equal beams)
    lam_f = 1.02 * cfg.wavelength_mm * cfg.focus_mm / cfg.aperture_mm
    assert cfg.lateral_fwhm_mm(cfg.focus_mm) == pytest.approx(lam_f / math.sqrt(2.0))


def test_bad_settings_are_rejected() -> None:
    r = UltrasoundRenderer(config=ProbeConfig(n_beams=16, n_samples=32, image_size=32))
    with pytest.raises(ConfigurationError, match=r"gain_db must be in \[-30, 30\] dB, got 45"):
        r.with_settings(gain_db=45.0)
    with pytest.raises(ConfigurationError, match=r"depth_mm must be in \[20, 300\] mm"):
        r.with_settings(depth_mm=400.0)
    with pytest.raises(ConfigurationError, match="tgc_db_per_cm"):
        ProbeConfig(tgc_db_per_cm=-1.0)
    with pytest.raises(ConfigurationError, match="dynamic_range_db"):
        ProbeConfig(dynamic_range_db=5.0)
    with pytest.raises(ConfigurationError, match="frequency_mhz"):
        ProbeConfig(frequency_mhz=40.0)
    with pytest.raises(ConfigurationError, match=r"unknown probe settings \['brightness'\]"):
        r.with_settings(brightness=3.0)


def test_the_speckle_reduction_is_a_physical_width_whatever_the_picture_size() -> None:
    """The display's smoothing is SPECKLE_REDUCTION_MM at every picture size (1.5 pixels of
    the default 256-pixel picture, so those pictures are unchanged); an explicit width in
    pixels is kept; a negative one is refused."""
    assert ProbeConfig().speckle_reduction_sigma_px == pytest.approx(1.5)
    for n in (64, 128, 512):
        cfg = ProbeConfig(image_size=n)
        assert cfg.speckle_reduction_sigma_px * cfg.pixel_mm == pytest.approx(SPECKLE_REDUCTION_MM)
    assert ProbeConfig(image_size=64, speckle_reduction_px=2.0).speckle_reduction_sigma_px == 2.0
    with pytest.raises(ConfigurationError, match="speckle_reduction_px"):
        ProbeConfig(speckle_reduction_px=-1.0)

"""The ICE B-mode renderer: geometry, tissue-fixed speckle, similarity behaviour."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icenav.errors import ConfigurationError, TransformError
from icenav.eval.metrics import beat_similarity, blurred_ncc, ncc
from icenav.sim.anatomy import (
    EXAMPLE_VIEWS,
    CardiacMotion,
    Chamber,
    HeartPhantom,
    Tissue,
    default_phantom,
    tip2anatomy,
)
from icenav.sim.ultrasound import Frame, ProbeConfig, UltrasoundRenderer

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
    renderer = UltrasoundRenderer(_sphere_phantom(point), ProbeConfig(noise_level=0.0))
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
    quiet = UltrasoundRenderer(ph, ProbeConfig(noise_level=0.0))
    p = ph.motion.period_s
    a = quiet.render(pose, 0.2 * p).image
    b = quiet.render(pose, 3.2 * p).image
    np.testing.assert_array_equal(a, b)
    other = UltrasoundRenderer(ph, ProbeConfig(noise_level=0.0, seed=7)).render(pose, 0.2 * p)
    assert ncc(a, other.image) < 0.98


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
    assert values[0] > 0.9 and values[-1] < values[0] - 0.05


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

"""Heart rhythm and breathing: seeded, beat-to-beat variation with the asked statistics,
Lujan's breathing curve, Shechter's displacement, and a phantom that follows both."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from icenav.errors import ConfigurationError
from icenav.sim.anatomy import default_phantom
from icenav.sim.physiology import (
    Breathing,
    BreathingParams,
    CardiacRhythm,
    PhysiologicalHeart,
    RhythmParams,
)


def test_a_regular_rhythm_is_the_phantoms() -> None:
    """No variation: the phase is the default phantom's t / T mod 1 (beats start at -60 s,
    a whole number of 0.833 s beats)."""
    rhythm = CardiacRhythm(RhythmParams(heart_rate_bpm=72.0), seed=0)
    ph = default_phantom()
    for t in np.linspace(0.0, 20.0, 57):
        d = abs(rhythm.phase(t) - ph.cardiac_phase(t))
        assert min(d, 1.0 - d) < 1e-9  # phases wrap at the R wave


def test_beat_to_beat_variation_has_the_asked_statistics() -> None:
    """(P1), (P3): RR sd and lag-1 correlation, amplitude sd, as drawn; seeded."""
    p = RhythmParams(rr_sd=0.04, rr_correlation=0.5, amplitude_sd=0.05)
    rhythm = CardiacRhythm(p, seed=3)
    rr = np.array([rhythm.beat_duration(k) for k in range(2000)]) / p.period_s - 1.0
    assert rr.std() == pytest.approx(0.04, rel=0.1)
    assert np.corrcoef(rr[:-1], rr[1:])[0, 1] == pytest.approx(0.5, abs=0.08)
    amp = np.array([rhythm.amplitude(rhythm.beat_start(k) + 0.01) for k in range(2000)])
    assert amp.std() == pytest.approx(0.05, rel=0.1)
    again = CardiacRhythm(p, seed=3)
    assert again.phase(100.3) == rhythm.phase(100.3)
    assert CardiacRhythm(p, seed=4).phase(100.3) != rhythm.phase(100.3)


def test_breathing_follows_lujan_and_varies_per_breath() -> None:
    """(P4): zero at end-expiration with a long dwell, peak at mid-breath; depths vary."""
    b = Breathing(BreathingParams(period_s=4.0), seed=0)
    t0 = float(b.breath_starts(0.0, 10.0)[0])
    assert float(b.signal(t0)) == pytest.approx(0.0, abs=1e-12)
    assert float(b.signal(t0 + 2.0)) == pytest.approx(1.0)
    assert float(b.signal(t0 + 0.5)) == pytest.approx(np.sin(np.pi / 8) ** 4)
    varied = Breathing(BreathingParams(period_s=4.0, amplitude_sd=0.2, period_sd=0.1), seed=1)
    starts = varied.breath_starts(0.0, 200.0)
    peaks = [float(varied.signal((a + b) / 2)) for a, b in zip(starts, starts[1:], strict=False)]
    assert np.std(peaks) == pytest.approx(0.2, rel=0.35)
    assert np.std(np.diff(starts)) / 4.0 == pytest.approx(0.1, rel=0.35)


def test_the_scalar_level_and_beat_index_are_the_array_paths_to_the_bit() -> None:
    """The hot paths of the contact solve: ``level(t)`` is ``signal(t)`` and ``beat_index``
    is ``np.searchsorted`` on the beat starts, exactly (before, inside and past the draws)."""
    b = Breathing(BreathingParams(period_sd=0.2, amplitude_sd=0.3, baseline_sd=0.2), seed=5)
    rhythm = CardiacRhythm(RhythmParams(rr_sd=0.05, rsa=0.05), seed=5, breathing=b)
    times = np.random.default_rng(5).uniform(-65.0, 300.0, 2000)
    for t in times:
        assert b.level(float(t)) == float(b.signal(float(t)))
        k = rhythm.beat_index(float(t))
        assert k == int(np.searchsorted(np.asarray(rhythm._starts), t, side="right") - 1)  # noqa: SLF001
    assert b.level(t0 := float(b.breath_starts(0.0, 10.0)[0])) == float(b.signal(np.array([t0]))[0])


def test_the_heart_moves_as_shechter_measured() -> None:
    """(P5): at a nominal breath's peak the heart has moved 4.9 mm caudally and 1.3 mm
    anteriorly, and turned by 1.5 deg."""
    b = Breathing(BreathingParams(period_s=4.0), seed=0)
    t = float(b.breath_starts(0.0, 10.0)[0]) + 2.0
    pivot = np.array(BreathingParams().pivot_mm)
    np.testing.assert_allclose(b.displacement(pivot[None], t)[0], [0.0, -1.3, -4.9], atol=1e-9)
    above = b.displacement((pivot + [0, 0, 50.0])[None], t)[0] - [0.0, -1.3, -4.9]
    assert np.degrees(np.arctan2(above[1], 50.0)) == pytest.approx(1.5, rel=1e-3)


def test_the_physiological_heart_follows_rhythm_and_breathing() -> None:
    """Its phase is the rhythm's, its cardiac motion scales with the beat's amplitude, and
    breathing is added; with neither varying it is the default phantom without its
    sinusoidal respiration."""
    base = default_phantom()
    rhythm = CardiacRhythm(RhythmParams(amplitude_sd=0.1), seed=2)
    breathing = Breathing(BreathingParams(), seed=2)
    heart = PhysiologicalHeart(base, rhythm, breathing)
    pts = np.array([[0.0, 0.0, 26.0], [10.0, -17.0, 12.0]])
    for t in (0.3, 1.7, 5.2):
        assert heart.cardiac_phase(t) == rhythm.phase(t)
        still = PhysiologicalHeart(base, rhythm, None).displacement(pts, t)
        np.testing.assert_allclose(
            heart.displacement(pts, t) - still, breathing.displacement(pts, t), atol=1e-12
        )
    plain = PhysiologicalHeart(base, CardiacRhythm(RhythmParams(), 0), None)
    no_resp = default_phantom(motion=type(base.motion)(respiratory_amplitude_mm=(0.0, 0.0, 0.0)))
    np.testing.assert_allclose(plain.displacement(pts, 1.1), no_resp.displacement(pts, 1.1))


def test_the_beat_to_beat_shape_varies_as_drawn_and_is_continuous() -> None:
    """(P6): at the R wave of beat k every point moves by the beat's draw with sd
    ``sigma_d`` per axis, at the centre and far from it alike (the field is normalised;
    session 7's affine field grew with the distance); points close together move together,
    points far apart less so; it moves smoothly within a beat to the next beat's draw (no
    jump at the R wave); the RR and amplitude sequences are those of the same seed without
    it."""
    p = RhythmParams(rr_sd=0.03, amplitude_sd=0.05, shape_sd_mm=1.2, shape_length_mm=30.0)
    rhythm = CardiacRhythm(p, seed=4)
    c = np.asarray(p.shape_centre_mm)
    pts = c + np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [90.0, 0.0, 0.0], [0.0, -60.0, 40.0]])
    u = np.array([rhythm.shape_displacement(pts, rhythm.beat_start(k)) for k in range(100, 1600)])
    for i in range(len(pts)):
        assert np.std(u[:, i]) == pytest.approx(1.2, rel=0.06)
    # consecutive beats at the same phase differ: their difference has sd sigma_d sqrt(2)
    assert np.std(np.diff(u[:, 0], axis=0)) == pytest.approx(1.2 * np.sqrt(2.0), rel=0.08)
    near = np.corrcoef(u[:, 0, 0], u[:, 1, 0])[0, 1]
    far = np.corrcoef(u[:, 0, 0], u[:, 2, 0])[0, 1]
    assert near > 0.98 and far < 0.5
    k = 300
    t1 = rhythm.beat_start(k + 1)
    before = rhythm.shape_displacement(pts, t1 - 1e-6)
    after = rhythm.shape_displacement(pts, t1 + 1e-6)
    np.testing.assert_allclose(before, after, atol=1e-4)
    plain = CardiacRhythm(replace(p, shape_sd_mm=0.0), seed=4)
    for t in (3.1, 50.7, 400.2):
        assert plain.phase(t) == rhythm.phase(t)
        assert plain.amplitude(t) == rhythm.amplitude(t)
        np.testing.assert_array_equal(plain.shape_displacement(pts, t), 0.0)
    base = default_phantom()
    heart = PhysiologicalHeart(base, rhythm, None)
    without = PhysiologicalHeart(base, plain, None)
    w = heart.shape_weight(pts)[:, None]
    np.testing.assert_allclose(
        heart.displacement(pts, 50.7) - without.displacement(pts, 50.7),
        w * rhythm.shape_displacement(pts, 50.7),
        atol=1e-12,
    )


def test_the_beat_to_beat_shape_stays_off_the_caval_veins() -> None:
    """(P6)'s weight ``w``: 1 in the atrium and at the cavo-atrial junctions, falling to 0
    along the IVC and the SVC over ``shape_vein_taper_mm`` beyond them (the veins outside
    the pericardium do not take part in the heart's beat-to-beat shape), 1 again well
    outside a vein."""
    base = default_phantom()
    rhythm = CardiacRhythm(RhythmParams(shape_sd_mm=1.0, shape_vein_taper_mm=20.0), seed=1)
    heart = PhysiologicalHeart(base, rhythm, None)
    ra = np.asarray(base.chamber("ra").centre, np.float64)
    for v in base.vessels:
        if v.name not in ("ivc", "svc"):
            continue
        a, b = np.asarray(v.start, np.float64), np.asarray(v.end, np.float64)
        if np.linalg.norm(a - ra) > np.linalg.norm(b - ra):
            a, b = b, a
        axis = (b - a) / np.linalg.norm(b - a)
        side = np.cross(axis, [1.0, 0.0, 0.0])
        side = side / np.linalg.norm(side)
        pts = np.array(
            [a - 5.0 * axis, a, a + 10.0 * axis, a + 25.0 * axis, a + 25.0 * axis + 40.0 * side]
        )
        np.testing.assert_allclose(heart.shape_weight(pts), [1.0, 1.0, 0.5, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(heart.shape_weight(ra[None]), [1.0])


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ConfigurationError, match="rr_sd"):
        RhythmParams(rr_sd=0.5)
    with pytest.raises(ConfigurationError, match="heart_rate_bpm"):
        RhythmParams(heart_rate_bpm=10.0)
    with pytest.raises(ConfigurationError, match="shape_sd_mm"):
        RhythmParams(shape_sd_mm=-0.1)
    with pytest.raises(ConfigurationError, match="shape_length_mm"):
        RhythmParams(shape_length_mm=0.0)
    with pytest.raises(ConfigurationError, match="shape_vein_taper_mm"):
        RhythmParams(shape_vein_taper_mm=-1.0)
    with pytest.raises(ConfigurationError, match="shape_n"):
        BreathingParams(shape_n=5)
    with pytest.raises(ConfigurationError, match="rotation_axis"):
        BreathingParams(rotation_axis=(0.0, 0.0, 0.0))

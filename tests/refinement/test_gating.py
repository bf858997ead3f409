"""Tests of icenav.refinement.gating: respiratory gating of ICE beats."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from icenav.errors import ConfigurationError
from icenav.recovery.beats import BeatClip
from icenav.refinement.gating import GatedBeatImager, PhantomRespiration
from icenav.sim.anatomy import default_phantom
from icenav.sim.beat_imager import SimClock, SimulatedBeatImager
from icenav.sim.ultrasound import ProbeConfig, UltrasoundRenderer
from tests.support.refinement import TrackedPlant

Array = NDArray[np.float64]
DEG = math.pi / 180


@pytest.fixture(scope="module")
def renderer() -> UltrasoundRenderer:
    cfg = ProbeConfig(image_size=96, n_beams=48, n_samples=128, seed=7)
    return UltrasoundRenderer(default_phantom(), cfg)


def test_phantom_respiration_is_the_phantoms_breathing() -> None:
    """The normalised signal times the amplitude is the phantom's respiratory displacement
    (at a point far from the heart, where the cardiac terms vanish)."""
    phantom = default_phantom()
    resp = PhantomRespiration(phantom)
    far = np.array([[0.0, 0.0, 2000.0]])
    amp = np.array(phantom.motion.respiratory_amplitude_mm)
    for t in np.linspace(0.0, 9.0, 17):
        np.testing.assert_allclose(phantom.displacement(far, float(t))[0],
                                   amp * resp.signal(float(t)), atol=1e-9)  # fmt: skip
    assert float(resp.phase(phantom.motion.respiratory_period_s * 2.25)) == pytest.approx(0.25)


def test_gating_picks_frames_at_the_saved_respiratory_state(renderer: UltrasoundRenderer) -> None:
    """Gated frames keep the exact cardiac phases k / n, lie in the held window, and match
    the reference's respiratory signal frame by frame much better than an ungated beat."""
    phantom = renderer.phantom
    resp = PhantomRespiration(phantom)
    beat = phantom.motion.period_s
    gated_mis, plain_mis = [], []
    for i, (t_ref, now) in enumerate([(3.0, 20.0), (7.7, 33.3), (1.2, 57.1), (11.0, 12.9)]):
        clock = SimClock(now)
        imager = SimulatedBeatImager(TrackedPlant(), renderer, clock.now, frames_per_beat=5)
        ref_times = imager.frame_times(t_ref + beat)
        ref = BeatClip(np.zeros((5, 4, 4)), np.arange(5) / 5, times=ref_times)
        gated = GatedBeatImager(imager, resp, ref, window_beats=5)
        assert gated.beat_duration_s == pytest.approx(5 * beat)
        times = gated.frame_times(now)
        assert np.all(times >= now - 5 * beat - 1e-9) and np.all(times < now)
        phases = np.array([phantom.cardiac_phase(float(t)) for t in times])
        d = np.abs(np.mod(phases - np.arange(5) / 5 + 0.5, 1.0) - 0.5)
        assert np.all(d < 1e-9)
        mis = np.abs(resp.signal(times) - resp.signal(ref_times))
        gated_mis.append(mis.max())
        assert gated.last_mismatch == pytest.approx(mis.max())
        # an independent brute force: the best of the window's frames at each phase
        cand = np.stack([imager.frame_times(now - m * beat) for m in range(5)])
        best = np.min(np.abs(resp.signal(cand) - resp.signal(ref_times)[None, :]), axis=0)
        np.testing.assert_allclose(mis, best, atol=1e-12)
        plain_mis.append(
            np.abs(resp.signal(imager.frame_times(now)) - resp.signal(ref_times)).max()
        )
        if i == 0:
            clip = gated.acquire_beat()
            assert clip.times is not None
            np.testing.assert_allclose(np.asarray(clip.times), np.asarray(times))
    # one breath is about 5 beats: each phase has a frame within about 0.11 breath (|d sin| < 0.7)
    assert max(gated_mis) < 0.7
    assert np.mean(gated_mis) < 0.5 * np.mean(plain_mis)
    with pytest.raises(ConfigurationError, match="frame times"):
        GatedBeatImager(imager, resp, BeatClip(np.zeros((5, 4, 4)), np.arange(5) / 5))
    with pytest.raises(ConfigurationError, match="window_beats"):
        GatedBeatImager(imager, resp, ref, window_beats=0)

"""Respiratory gating of ICE beats: frames at the saved beat's cardiac *and* respiratory
state, so that a returned view is compared with the saved one as consecutive beats are
(beyond the paper).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav.errors import ConfigurationError
from icenav.recovery.beats import BeatClip
from icenav.refinement.similarity import match_by_phase

__all__ = ["GatedBeatImager", "PhantomRespiration", "RespiratoryMonitor", "TimedBeatImager"]


class TimedBeatImager(Protocol):
    """An ECG-gated imager that can render frames at chosen past times (a cine loop kept by
    the scanner): the twin's :class:`icenav.sim.beat_imager.SimulatedBeatImager`."""

    @property
    def beat_duration_s(self) -> float:
        """One heart beat (s)."""
        ...

    clock: Callable[[], float]
    """Current time (s)."""

    def frame_times(self, now: float) -> NDArray[np.float64]:
        """(n,) times (s) of one ECG-gated beat ending at ``now``, frame k at phase k / n."""
        ...

    def clip_at_times(self, times: NDArray[np.float64]) -> BeatClip:
        """Frames at ``times`` (s) from the current pose, in the order given."""
        ...


class RespiratoryMonitor(Protocol):
    """A respiratory signal the system has (a respiratory belt or bellows, the ventilator,
    or a surface / EM reference sensor on the chest): never the catheter's pose."""

    def signal(self, t: ArrayLike) -> NDArray[np.float64]:
        """Normalised respiratory signal at times ``t`` (s), same shape as ``t``."""
        ...


class PhantomRespiration:
    """The twin's respiratory signal: the phantom's breathing as a bellows would record it,
    normalised to [-1, 1] (``sin(2 pi t / T)``, the time course of the phantom's respiratory
    displacement, :meth:`icenav.sim.anatomy.HeartPhantom.displacement`). It depends on time
    only, not on where the catheter is.

    Parameters
    ----------
    phantom : icenav.sim.anatomy.HeartPhantom
        Its ``motion.respiratory_period_s`` sets the breathing period.
    """

    def __init__(self, phantom: object) -> None:
        self.period_s = float(phantom.motion.respiratory_period_s)  # type: ignore[attr-defined]

    def signal(self, t: ArrayLike) -> NDArray[np.float64]:
        """sin(2 pi t / T) at ``t`` (s)."""
        out: NDArray[np.float64] = np.sin(2.0 * math.pi * np.asarray(t, np.float64) / self.period_s)
        return out

    def phase(self, t: ArrayLike) -> NDArray[np.float64]:
        """Respiratory phase in [0, 1) at ``t`` (s), 0 = mid-inspiration (signal rising
        through 0)."""
        out: NDArray[np.float64] = np.mod(np.asarray(t, np.float64) / self.period_s, 1.0)
        return out


class GatedBeatImager:
    """ECG- and respiration-gated beats: frames at the reference beat's respiratory state.

    The catheter is held still for ``window_beats`` heart beats. For each cardiac phase
    ``k / n`` there is one frame per beat of that window (retrospective ECG gating, as
    :class:`icenav.sim.beat_imager.SimulatedBeatImager`); of these, the one whose
    respiratory signal is nearest to the reference beat's at the same cardiac phase is kept
    (retrospective respiratory gating, as clinical 4-D imaging bins frames by respiration).
    The result is one beat whose frames match the reference in cardiac phase *and*
    respiratory state. With ``window_beats`` about one breath (5 beats at 72 /min and 4.1 s
    per breath) the respiratory phase of each kept frame is within about 0.05 breath of the
    reference's signal value.

    Parameters
    ----------
    imager : TimedBeatImager
        Renders the kept frames (at the plant's true pose).
    monitor : RespiratoryMonitor
        The respiratory signal.
    reference : BeatClip
        The beat to match (needs ``times``).
    window_beats : int
        Beats the catheter is held still per gated beat (>= 1).
    """

    def __init__(
        self,
        imager: TimedBeatImager,
        monitor: RespiratoryMonitor,
        reference: BeatClip,
        window_beats: int = 5,
    ) -> None:
        if isinstance(window_beats, bool) or int(window_beats) != window_beats or window_beats < 1:
            raise ConfigurationError(f"window_beats must be an int >= 1, got {window_beats!r}")
        if reference.times is None:
            raise ConfigurationError("respiratory gating needs the reference beat's frame times")
        self.imager = imager
        self.monitor = monitor
        self.window_beats = int(window_beats)
        self.reference_phases = reference.phases.copy()
        self.reference_signal = np.asarray(monitor.signal(reference.times), np.float64)
        self.last_mismatch = math.nan
        """Largest |signal - reference signal| over the frames of the last gated beat."""

    @property
    def beat_duration_s(self) -> float:
        """How long the catheter is held still per gated beat (s): ``window_beats`` beats."""
        return self.window_beats * self.imager.beat_duration_s

    def frame_times(self, now: float) -> NDArray[np.float64]:
        """Times (s) of the kept frames at ``now``, in cardiac-phase order (k / n)."""
        beat = self.imager.beat_duration_s
        cand = np.stack(
            [self.imager.frame_times(now - m * beat) for m in range(self.window_beats)]
        )  # (W, n): frame k of each beat of the window
        n = cand.shape[1]
        target = self.reference_signal[match_by_phase(self.reference_phases, np.arange(n) / n)]
        mis = np.abs(np.asarray(self.monitor.signal(cand), np.float64) - target[None, :])
        pick = np.argmin(mis, axis=0)
        self.last_mismatch = float(np.max(mis[pick, np.arange(n)]))
        out: NDArray[np.float64] = cand[pick, np.arange(n)]
        return out

    def acquire_beat(self) -> BeatClip:
        """One gated beat at the plant's true pose (the catheter held still for the window)."""
        return self.imager.clip_at_times(self.frame_times(float(self.imager.clock())))

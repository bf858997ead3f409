"""A tip pose that heart beat and breathing cannot fool: EM samples averaged over complete
respiratory cycles (or complete heart beats), cut at the physiological signals a real system
records (beyond the paper).

In vivo the tip moves with every beat and every breath (on the twin several millimetres
along the body axis with breathing, through contact and the vessel dragging the shaft). An
average over a fixed 0.8 s, as the pose stage used, lands at whatever respiratory phase the
measurement falls on: two such averages of a still catheter differ by millimetres. Averaged
over *complete* cycles the periodic motion cancels (the mean of a periodic displacement
over whole periods is its mean level, whatever the phase the window starts at), so the
estimate at saving and after a return compares like with like.

Estimator (Eq. R1): the samples ``(t_k, P_k)`` of the last ``window_s`` of a still
catheter; the respiratory signal ``r(t_k)`` (bellows / ventilator, never the catheter);
inspiration onsets ``c_0 < c_1 < ... < c_m``: upward crossings of the window's mid level
``(min r + max r) / 2``. With ``m >= 1`` complete breaths::

    P_hat = mean{ P_k : c_0 <= t_k < c_m }                                          (R1)

(position: arithmetic mean; rotation: the chordal mean,
:func:`icenav.geometry.se3.pose_mean`). Without breathing (a phantom, an apnoea) or with
fewer than one complete breath the cut is at the R waves of the ECG (the cardiac phase
wrapping from 1 to 0), complete beats only; without either, all samples.

On the twin (catheter 100, patient 0, mitral view, truth sampled at 10 Hz over 60 s) the
mean over one complete breath scatters by 0.38 mm between breaths, over two by 0.32 mm:
the catheter's static pose itself wanders by about that (the shaft sticks and slips as the
breathing vessel drags it), which bounds what any refinement can reach.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav._typing import Array
from icenav._validation import check_positive
from icenav.errors import ConfigurationError, ShapeError
from icenav.geometry.se3 import pose_mean
from icenav.refinement.gating import RespiratoryMonitor

__all__ = ["CycleAveragedPose", "CycleWindow", "ExpirationGate", "PoseStream", "complete_cycles"]


class PoseStream(Protocol):
    """A tracker that keeps its recent samples with their times (NDI and the twin do)."""

    def sample_window(self, duration_s: float, rate_hz: float) -> tuple[Array, Array]:
        """The samples of the last ``duration_s`` at ``rate_hz``: (n,) times (s) and (n, 4, 4)
        tip2base poses (mm, base frame); dropped samples left out."""
        ...


@dataclass(frozen=True)
class CycleWindow:
    """Which samples an estimate used."""

    start_s: float
    """First sample time used (s)."""
    end_s: float
    """End of the last complete cycle (s)."""
    cycles: int
    """Complete cycles averaged (0: all samples, no cycle found)."""
    kind: str
    """``breath``, ``beat`` or ``none``."""
    n_samples: int
    """Samples averaged."""


def _onsets(values: NDArray[np.float64], wrap: bool) -> NDArray[np.intp]:
    """Indices where a cycle starts: upward crossings of the mid level, or (``wrap``) where
    a phase in [0, 1) wraps from near 1 to near 0."""
    if len(values) < 2:
        return np.zeros(0, np.intp)
    if wrap:
        out: NDArray[np.intp] = np.flatnonzero(np.diff(values) < -0.5) + 1
        return out
    lo, hi = float(values.min()), float(values.max())
    if not hi - lo > 1e-9:
        return np.zeros(0, np.intp)
    mid = 0.5 * (lo + hi)
    up: NDArray[np.intp] = np.flatnonzero((values[:-1] < mid) & (values[1:] >= mid)) + 1
    return up


def complete_cycles(
    times: ArrayLike,
    respiration: NDArray[np.float64] | None,
    cardiac_phase: NDArray[np.float64] | None,
    *,
    min_breath_s: float = 1.5,
) -> tuple[slice, CycleWindow]:
    """The samples of complete breaths (else complete beats, else all), Eq. (R1).

    Parameters
    ----------
    times : array-like, shape (n,)
        Sample times (s), increasing.
    respiration : ndarray (n,) or None
        The respiratory signal at ``times`` (any scale).
    cardiac_phase : ndarray (n,) or None
        The cardiac phase in [0, 1) at ``times`` (0 = R wave).
    min_breath_s : float
        Onsets closer than this (s) to the previous one are ignored (signal noise).

    Returns
    -------
    (slice, CycleWindow)
        The samples to average and what they are.
    """
    t = np.asarray(times, np.float64).ravel()
    n = len(t)
    for values, kind in ((respiration, "breath"), (cardiac_phase, "beat")):
        if values is None:
            continue
        v = np.asarray(values, np.float64).ravel()
        if v.shape != t.shape:
            raise ShapeError(f"{kind} signal has {v.size} values for {n} sample times")
        idx = _onsets(v, wrap=kind == "beat")
        if kind == "breath" and len(idx):
            keep = [int(idx[0])]
            for i in idx[1:]:
                if t[i] - t[keep[-1]] >= min_breath_s:
                    keep.append(int(i))
            idx = np.asarray(keep, np.intp)
        if len(idx) >= 2:
            a, b = int(idx[0]), int(idx[-1])
            return slice(a, b), CycleWindow(float(t[a]), float(t[b]), len(idx) - 1, kind, b - a)
    end = float(t[-1]) if n else math.nan
    return slice(0, n), CycleWindow(float(t[0]) if n else math.nan, end, 0, "none", n)


class CycleAveragedPose:
    """The tip pose averaged over complete breaths (or beats), Eq. (R1), as a pose sensor
    (``measure_tip2base``), so the EM pose stage servoes on it unchanged.

    The catheter must have been still for the last ``window_s`` when it is asked (the pose
    stage holds ``PoseStageConfig.hold_s``; set it to at least ``window_s``).

    Parameters
    ----------
    stream : PoseStream
        The EM tracker's recent samples.
    respiration : RespiratoryMonitor or None
        The respiratory signal (bellows, ventilator); None without one.
    cardiac_phase : callable t (s) -> phase in [0, 1), or None
        The ECG's cardiac phase (0 at the R wave); None without one.
    window_s : float
        Samples looked back over (s): about 2.5 breaths gives 2 complete ones.
    rate_hz : float
        Sample rate used (Hz).
    """

    def __init__(
        self,
        stream: PoseStream,
        respiration: RespiratoryMonitor | None,
        cardiac_phase: Callable[[float], float] | None,
        *,
        window_s: float = 9.0,
        rate_hz: float = 10.0,
    ) -> None:
        if not callable(getattr(stream, "sample_window", None)):
            raise ConfigurationError("the pose stream must have sample_window(duration_s, rate)")
        self.stream = stream
        self.respiration = respiration
        self.cardiac_phase = cardiac_phase
        self.window_s = check_positive(window_s, "window_s", "s")
        self.rate_hz = check_positive(rate_hz, "rate_hz", "Hz")
        self.last_window: CycleWindow | None = None
        """What the last estimate averaged."""

    def measure_tip2base(self, n_average: int = 1) -> Array | None:
        """Eq. (R1) over the last ``window_s`` (``n_average`` is ignored: the window decides);
        (4, 4) mm, None if every sample dropped out."""
        times, poses = self.stream.sample_window(self.window_s, self.rate_hz)
        if len(times) == 0:
            return None
        resp = None if self.respiration is None else np.asarray(
            self.respiration.signal(times), np.float64
        )  # fmt: skip
        phase = None
        if self.cardiac_phase is not None:
            phase = np.array([self.cardiac_phase(float(t)) for t in times])
        sel, window = complete_cycles(times, resp, phase)
        self.last_window = window
        out: Array = pose_mean(np.asarray(poses)[sel])
        return out


class ExpirationGate:
    """True at end-expiration, from the respiratory signal's recent past only (causal):
    the signal now lies in the lowest ``fraction`` of its range over the last
    ``lookback_s`` and is not rising (Eq. R3)::

        r(t) <= min r + fraction (max r - min r)  and  r(t) <= r(t - 0.1 s)      (R3)

    (the second up to 1e-6 of the range: a flat dwell is not rising)

    (the minimum and maximum over ``[t - lookback_s, t]``). The pose stage waits for it
    before the last leg of each move (``PoseStageConfig.arrive_at_expiration``), so the
    shaft's last slip happens in the end-expiratory dwell, where the vessel wall that then
    carries the stuck shaft stands nearly still, at the same level every time.

    Parameters
    ----------
    respiration : RespiratoryMonitor
        The respiratory signal (bellows, ventilator; never the catheter's pose).
    clock : callable -> s
        The time base of ``respiration``.
    lookback_s : float
        Past looked at (s): more than one breath.
    fraction : float
        Lowest part of the range counted as end-expiration, in (0, 0.5].
    """

    def __init__(
        self,
        respiration: RespiratoryMonitor,
        clock: Callable[[], float],
        *,
        lookback_s: float = 6.0,
        fraction: float = 0.1,
    ) -> None:
        self.respiration = respiration
        self.clock = clock
        self.lookback_s = check_positive(lookback_s, "lookback_s", "s")
        if not 0.0 < fraction <= 0.5:
            raise ConfigurationError(f"fraction must be in (0, 0.5], got {fraction}")
        self.fraction = float(fraction)

    def __call__(self) -> bool:
        """Whether it is end-expiration now (Eq. R3)."""
        now = float(self.clock())
        times = now - np.arange(0.0, self.lookback_s, 0.05)
        r = np.asarray(self.respiration.signal(times), np.float64)
        lo, hi = float(r.min()), float(r.max())
        if not hi - lo > 1e-9:
            return True  # no breathing to wait for
        return bool(r[0] <= lo + self.fraction * (hi - lo) and r[0] <= r[2] + 1e-6 * (hi - lo))

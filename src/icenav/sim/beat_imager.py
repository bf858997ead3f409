"""The twin's ICE imager for the refinement and the evaluation: beats rendered at the
plant's true tip pose (:class:`SimulatedBeatImager`), on a settable clock (:class:`SimClock`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icenav.errors import ConfigurationError
from icenav.recovery.beats import BeatClip
from icenav.sim.anatomy import BASE2ANATOMY

__all__ = ["SimClock", "SimulatedBeatImager"]


class SimClock:
    """A settable simulation clock (s): ``now()`` for the backends, ``advance(dt)`` to step."""

    def __init__(self, t0: float = 0.0) -> None:
        self.t = float(t0)

    def now(self) -> float:
        """Current time (s)."""
        return self.t

    def advance(self, dt: float) -> None:
        """Move time forward by ``dt`` >= 0 s (usable as an injected ``sleep``)."""
        if not dt >= 0.0:
            raise ConfigurationError(f"time can only advance: dt must be >= 0 s, got {dt} s")
        self.t += float(dt)


class SimulatedBeatImager:
    """Renders one beat on the digital twin at the plant's true tip pose.

    Parameters
    ----------
    plant : object with ``state.tip2base`` (4, 4)
        The catheter plant (:class:`icenav.sim.plant.CatheterPlant`).
    renderer : icenav.sim.ultrasound.UltrasoundRenderer
        The ICE image renderer (its phantom sets the heart rate).
    clock : callable returning s
        Simulation time.
    frames_per_beat : int
        Frames rendered per beat.
    ecg_gated : bool
        Frames at the phases ``k / frames_per_beat`` within the last beat-long window
        (retrospective ECG gating); otherwise at ``now - beat + k beat / n``.
    base2anatomy : (4, 4), optional
        Registration of the robot base in the anatomy frame (default the phantom's).
    """

    def __init__(
        self,
        plant: object,
        renderer: object,
        clock: Callable[[], float],
        frames_per_beat: int = 10,
        base2anatomy: ArrayLike | None = None,
        ecg_gated: bool = True,
    ) -> None:
        if isinstance(frames_per_beat, bool) or int(frames_per_beat) < 2:
            raise ConfigurationError(f"frames_per_beat must be an int >= 2, got {frames_per_beat}")
        self.plant = plant
        self.renderer = renderer
        self.clock = clock
        self.frames_per_beat = int(frames_per_beat)
        self.base2anatomy = np.asarray(
            BASE2ANATOMY if base2anatomy is None else base2anatomy, dtype=np.float64
        )
        self._phantom = renderer.phantom  # type: ignore[attr-defined]
        self._beat = float(self._phantom.motion.period_s)
        self.ecg_gated = bool(ecg_gated)

    @property
    def beat_duration_s(self) -> float:
        """One heart beat (s)."""
        return self._beat

    def frame_times(self, now: float) -> NDArray[np.float64]:
        """Acquisition times (s) of the frames :meth:`acquire_beat` returns at ``now``.

        All lie in the last beat-long window ``[now - beat, now)``, so the whole beat was
        recorded while the catheter was held still for at least a beat. ECG gated: frame k
        is the instant of that window at cardiac phase ``k / n`` (retrospective gating, as
        scanners sort frames by the ECG); otherwise evenly spaced from ``now - beat``.
        """
        n = self.frames_per_beat
        start = now - self._beat
        k = np.arange(n) / n
        if not self.ecg_gated:
            return start + k * self._beat
        offset = np.mod(k - self._phantom.cardiac_phase(start), 1.0)
        out: NDArray[np.float64] = start + offset * self._beat
        return out

    def acquire_beat(self) -> BeatClip:
        """One beat at the plant's true pose, frames at :meth:`frame_times` (phase order)."""
        return self.clip_at_times(self.frame_times(float(self.clock())))

    def clip_at_times(self, times: NDArray[np.float64]) -> BeatClip:
        """Frames at the plant's true pose at ``times`` (s), in the order given."""
        pose = self.base2anatomy @ np.asarray(self.plant.state.tip2base)  # type: ignore[attr-defined]
        frames = tuple(
            self.renderer.render(pose, float(t), check=False)  # type: ignore[attr-defined]
            for t in times
        )
        return self._clip(frames, float(times.min()))

    def clip_at(self, tip2anatomy: ArrayLike, t0: float) -> BeatClip:
        """One beat from ``tip2anatomy`` (4, 4): frames at ``t0 + k beat / n`` (s)."""
        n = self.frames_per_beat
        frames = self.renderer.render_clip(  # type: ignore[attr-defined]
            tip2anatomy, t0, n, self._beat / n
        )
        return self._clip(tuple(frames), t0)

    @staticmethod
    def _clip(frames: tuple[Any, ...], t0: float) -> BeatClip:
        images = np.stack([f.image for f in frames]).astype(np.float64)
        phases = np.array([f.cardiac_phase for f in frames])
        times = np.array([f.t for f in frames], dtype=np.float64)
        mask = frames[0].labels >= 0
        return BeatClip(images, phases, mask, t0, frames, times)

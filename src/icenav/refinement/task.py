"""The whole closed-loop refinement of a returned view as one controller task: the EM pose
stage (:mod:`icenav.refinement.pose_stage`), then the image stage
(:mod:`icenav.refinement.image_search`: it measures the gated beats and reports whether the
view is held, moving the catheter only when its search is switched on).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from numpy.typing import ArrayLike

from icenav._typing import Array
from icenav.recovery.beats import BeatClip, BeatImager
from icenav.refinement.image_search import (
    RefinementConfig,
    RefinementResult,
    RefinementTask,
)
from icenav.refinement.pose_stage import (
    PoseSensor,
    PoseStageConfig,
    PoseStageResult,
    PoseStageStatus,
    PoseStageTask,
)

__all__ = ["ViewRefinementTask"]


class ViewRefinementTask:
    """The whole closed-loop refinement as one controller task: the EM pose stage
    (:class:`PoseStageTask`), then the image stage (:class:`RefinementTask`) centred where
    the pose stage ended (its box ``+- RefinementConfig.radius`` around that state; it
    moves only when its search is switched on, else it measures and reports).

    Parameters
    ----------
    q_view, saved_tip2base, sensor, arrival_direction, start_direction, pose_config
        As for :class:`PoseStageTask` (``pose_config`` is its ``config``).
    reference, imager, config
        As for :class:`RefinementTask` (e.g. a :class:`GatedBeatImager`).
    q_start : array-like, shape (4,), optional
        Where the robot is now (default ``q_view``).
    abort : callable, optional
        Polled every cycle by both stages; True ends the task at once.
    """

    label = "refine view (EM pose, then image)"

    def __init__(
        self,
        q_view: ArrayLike,
        saved_tip2base: ArrayLike,
        sensor: PoseSensor,
        reference: BeatClip | Sequence[BeatClip],
        imager: BeatImager,
        *,
        q_start: ArrayLike | None = None,
        arrival_direction: Sequence[int] = (0, 0, 0, 0),
        start_direction: Sequence[int] | None = None,
        pose_config: PoseStageConfig | None = None,
        config: RefinementConfig | None = None,
        abort: Callable[[], bool] | None = None,
    ) -> None:
        self.pose = PoseStageTask(
            q_view,
            saved_tip2base,
            sensor,
            q_start=q_start,
            arrival_direction=arrival_direction,
            start_direction=start_direction,
            config=pose_config,
            abort=abort,
        )
        self._reference = reference
        self._imager = imager
        self._arrival = tuple(arrival_direction)
        self._config = config
        self._abort = abort
        self.image: RefinementTask | None = None
        """The image stage, once the pose stage has ended (None before)."""
        self._done = False

    @property
    def progress(self) -> float:
        """0-0.5 during the pose stage, 0.5-1 during the image stage."""
        if self._done:
            return 1.0
        if self.image is None:
            return 0.5 * self.pose.progress
        return 0.5 + 0.5 * self.image.progress

    def next_command(self, q_measured: Array, dt: float) -> Array | None:
        """The next motor set-point (4,), or None when both stages have ended."""
        if self._done:
            return None
        if self.image is None:
            cmd = self.pose.next_command(q_measured, dt)
            if cmd is not None:
                return cmd
            if self.pose.status in (PoseStageStatus.ABORTED, PoseStageStatus.NO_POSE):
                self._done = True
                return None
            q_end = self.pose.result().q_final
            self.image = RefinementTask(
                q_end,
                self._reference,
                self._imager,
                q_start=q_end,
                arrival_direction=self._arrival,
                config=self._config,
                abort=self._abort,
            )
        cmd = self.image.next_command(q_measured, dt)
        if cmd is None:
            self._done = True
        return cmd

    def result(self) -> tuple[PoseStageResult, RefinementResult | None]:
        """The pose stage's result and the image stage's (None if it never started)."""
        return self.pose.result(), None if self.image is None else self.image.result()

"""The sim's camera schedule as data: which frames carry a depth image (physics steps per
camera frame: :func:`common.config.substeps_per_frame`).

The colour stream runs at ``camera.rgb_hz``; a depth image is taken with the first colour
frame at or after each tick of ``camera.depth_hz``, the ticks spaced in the colour frames' own
period (whole physics steps), ``rgb_hz / depth_hz`` frames apart. The ticks stay on their own
grid (a late frame does not shift the next tick), so a lower depth rate never drifts against
the colour stream. Pure: the sim node and the in-process pipeline (services/pipeline.py) both
step it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from common.config import CameraConfig, Scenario
from services.sim.events import TIME_EPSILON_S


@dataclass(frozen=True)
class DepthSchedule:
    """When the next depth image is due and which frame took the newest one."""

    period_s: float
    next_depth_s: float = 0.0
    depth_frame_seq: int = -1  # frame_seq of the newest depth image (-1: none yet)
    depth_images: int = 0  # taken so far

    @classmethod
    def of(cls, camera: CameraConfig, frame_period_s: float) -> DepthSchedule:
        """Ticks on the sim's own frame grid: ``frame_period_s`` is the colour period in whole
        physics steps (:attr:`Scenario.frame_period_s`), so that depth at the colour rate comes
        with every frame even where physics steps do not divide the camera period."""
        return cls(period_s=frame_period_s * camera.rgb_hz / camera.depth_rate_hz)

    def due(self, t_s: float) -> bool:
        """Does the frame taken at sim time ``t_s`` carry a depth image?"""
        return t_s + TIME_EPSILON_S >= self.next_depth_s

    def taken(self, t_s: float, frame_seq: int) -> DepthSchedule:
        """The schedule after frame ``frame_seq`` (sim time ``t_s``) took a depth image."""
        next_depth_s = self.next_depth_s
        while next_depth_s <= t_s + TIME_EPSILON_S:  # keep the grid, do not drift
            next_depth_s += self.period_s
        return replace(
            self,
            next_depth_s=next_depth_s,
            depth_frame_seq=frame_seq,
            depth_images=self.depth_images + 1,
        )


@dataclass(frozen=True)
class FrameClock:
    """Realtime: when the next colour frame is due. Its ticks lie on the camera's grid in
    whole physics steps (:attr:`Scenario.frame_period_s`), as lockstep's frames and the depth
    schedule's ticks do (1/rgb_hz would put frames off the depth ticks)."""

    period_s: float
    next_frame_s: float = 0.0

    @classmethod
    def of(cls, scenario: Scenario) -> FrameClock:
        return cls(scenario.frame_period_s)

    def missed(self, t_s: float) -> int | None:
        """Is a frame due at sim time ``t_s``? None if not yet; else how many ticks went by
        without a frame (0: none missed). Compared within :data:`TIME_EPSILON_S`: physics
        steps summed one by one fall a hair short of the frame times they meet (8 × 1/240 s
        < 1/30 s in floating point), which would send every frame a physics step late."""
        late_s = t_s + TIME_EPSILON_S - self.next_frame_s
        if late_s < 0:
            return None
        return int(late_s // self.period_s)

    def after_frame(self, missed: int) -> FrameClock:
        """The clock once a frame went out, ``missed`` ticks after the one it was due at."""
        return replace(self, next_frame_s=self.next_frame_s + (missed + 1) * self.period_s)

"""The image error, and when it counts as converged: averaged over the last frames, or settled
on a plateau under a pixel. Pure."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from common.config import ControllerConfig
from common.kinematics import centroid

FloatArray = NDArray[np.float64]


def feature_error_px_rms(s_px: FloatArray, s_star_px: FloatArray) -> float:
    """RMS over the 2N pixel coordinates of ``s - s*``."""
    return float(np.sqrt(np.mean((np.asarray(s_px) - np.asarray(s_star_px)) ** 2)))


# The averaged error must fall by this share to count as progress (plateau_px / plateau_s).
PLATEAU_PROGRESS = 0.05


@dataclass(frozen=True)
class Plateau:
    """The least averaged error (px) since the error last fell by :data:`PLATEAU_PROGRESS`,
    and the sim time (s) it fell to it."""

    best_px: float
    since_s: float

    def after(self, settled_px: float, t_s: float) -> Plateau:
        if settled_px < (1.0 - PLATEAU_PROGRESS) * self.best_px:
            return Plateau(settled_px, t_s)
        return self


def settled_error_px_rms(recent_errors_px: Sequence[FloatArray]) -> float:
    """RMS over the 2N pixel coordinates of ``s - s*`` averaged over the last frames.

    Convergence is judged on it rather than on each frame's error: corners measured from
    pixels jitter by a few tenths of a pixel from frame to frame as the hand's edges cross
    pixel boundaries, and near the goal the law turns that jitter into a small wobble about
    it. A goal within that jitter was otherwise never "reached" for enough consecutive frames
    (runs held 0.3 px and 2 mm from the goal until their timeout), while the mean over a few
    frames lies on the goal."""
    mean = centroid(np.asarray(recent_errors_px, dtype=float))  # per coordinate, over frames
    return float(np.sqrt((mean**2).mean()))


@dataclass
class ConvergenceWindow:
    """The errors ``s − s*`` (px, 2N) of the last frames servoed on a still goal that was seen
    (or fitted), and the plateau under ``plateau_px`` they sit on: whether the hand has settled
    on its goal."""

    errors_px: list[FloatArray] = field(default_factory=list)
    plateau: Plateau | None = None

    def clear(self) -> None:
        """Afresh: what came before no longer tells whether the hand is on this goal."""
        self.errors_px, self.plateau = [], None

    def add(self, error_px: FloatArray, cfg: ControllerConfig) -> None:
        """This frame's error, the window kept to its last ``converged_frames``."""
        self.errors_px = [*self.errors_px, error_px][-cfg.converged_frames :]

    def settled(self, t_s: float, cfg: ControllerConfig) -> bool:
        """Whether the hand has settled (the plateau followed to ``t_s`` on the way).
        Converged: the error averaged over the window is under ``converged_px``, or under
        ``plateau_px`` and has not fallen by :data:`PLATEAU_PROGRESS` for ``plateau_s``. A goal
        beside a joint limit is approached by the joints left free, and the error can settle a
        few tenths of a pixel above the threshold and stay there: the hand is on its goal in
        the image, and waiting for the timeout gains nothing."""
        if len(self.errors_px) < cfg.converged_frames:
            self.plateau = None
            return False
        settled_px = settled_error_px_rms(self.errors_px)
        if settled_px < cfg.converged_px:
            return True
        if settled_px >= cfg.plateau_px:
            self.plateau = None
            return False
        if self.plateau is None:
            self.plateau = Plateau(settled_px, t_s)
        self.plateau = self.plateau.after(settled_px, t_s)
        return t_s - self.plateau.since_s >= cfg.plateau_s

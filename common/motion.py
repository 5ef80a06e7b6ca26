"""How a marker has been moving: its recent views, its velocity, where it is while unseen.

Pure and immutable (each view gives a new :class:`MarkerMotion`). Vision uses it to look for
a hidden target where it must be by now; the controller to feed the target's motion forward
and to follow a target the hand hides.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from common.kinematics import centroid, norm

FloatArray = NDArray[np.float64]

VELOCITY_WINDOW_S = 0.5  # the velocity is the slope of the corners' centroid over this window
MIN_SPAN_S = 0.2  # views spanning less time: no estimate (zero)
MAX_SPEED_M_S = 0.3  # a faster estimate is a glitch, not the object
# A slower estimate is the measurement's wobble, not motion: a still target seen partly hidden
# (fitted corners off by up to 0.5 px) gives slopes of about 1 mm/s, which, carried for the
# seconds the hand hides it, moved the goal 3-4 mm. The moving targets that matter move at
# centimetres per second.
STILL_SPEED_M_S = 0.003
# An unseen marker is carried along its velocity this long at most. The hand follows the
# prediction; if the object stopped, the hand moves on past it, uncovers it and sees it again.
PREDICTION_HORIZON_S = 5.0


@dataclass(frozen=True)
class MarkerMotion:
    """Recent views: sim time (s) and the centroid of the marker's corners (3-D, camera frame,
    m), kept as the centroid since that is all the velocity needs."""

    views: tuple[tuple[float, FloatArray], ...] = ()

    def seen(self, t_s: float, points_m: FloatArray) -> MarkerMotion:
        """With one more view (the corners' 3-D points, (4, 3) m); views older than the window
        before it are dropped."""
        kept = tuple(v for v in self.views if v[0] >= t_s - VELOCITY_WINDOW_S and v[0] < t_s)
        centre = centroid(np.asarray(points_m, dtype=float))
        return MarkerMotion((*kept, (t_s, centre)))

    def velocity_m_s(self, t_s: float) -> FloatArray:
        """Velocity believed at ``t_s``: :attr:`estimated_velocity_m_s`, kept for at most
        :data:`PREDICTION_HORIZON_S` after the latest view (then zero: the marker is believed
        to have stopped where the prediction ended)."""
        if not self.views or t_s - self.views[-1][0] > PREDICTION_HORIZON_S:
            return np.zeros(3)
        return self.estimated_velocity_m_s.copy()

    @cached_property  # immutable views: computed once (vision and controller ask per frame)
    def estimated_velocity_m_s(self) -> FloatArray:
        """The least-squares slope of the corners' centroid over the window before the latest
        view; zero until the views span :data:`MIN_SPAN_S`, and zero below
        :data:`STILL_SPEED_M_S`; at most :data:`MAX_SPEED_M_S`."""
        velocity = np.zeros(3)
        if not self.views or self.views[-1][0] - self.views[0][0] < MIN_SPAN_S:
            velocity.setflags(write=False)
            return velocity
        t = np.array([v[0] for v in self.views])
        centres = np.array([v[1] for v in self.views])
        dt = t - t.mean()
        velocity = dt @ (centres - centroid(centres)) / float(dt @ dt)
        speed = norm(velocity)
        if speed < STILL_SPEED_M_S:
            velocity = np.zeros(3)
        elif speed > MAX_SPEED_M_S:
            velocity = velocity * (MAX_SPEED_M_S / speed)
        velocity.setflags(write=False)  # cached: shared by every caller
        return velocity

    def shift_m(self, t_s: float) -> FloatArray:
        """How far the marker has moved since its latest view, if it kept its velocity for at
        most :data:`PREDICTION_HORIZON_S` (the prediction stays where it ended, rather than
        jumping back to the last view)."""
        if not self.views:
            return np.zeros(3)
        elapsed_s = min(max(t_s - self.views[-1][0], 0.0), PREDICTION_HORIZON_S)
        return self.estimated_velocity_m_s * elapsed_s

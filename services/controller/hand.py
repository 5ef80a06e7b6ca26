"""Where the hand marker is while vision cannot use it: its last view carried along the motion
the joint encoders measured since. Pure.

On the way to its goal the hand can turn so that its own forearm crosses the marker, or its
edge comes to the camera, for a few frames: vision then reports it ``partial`` and the law
would hold with nothing to bring it back (constant's bent paths did, from five starts of the
random-start campaign). The marker rides rigidly on the end effector, whose pose the encoders
give at every frame, so its last usable corners moved by the end effector's motion since are
where it is now, to the accuracy of the kinematic model and of the assumed camera pose's
rotation (the motion is relative, so an error in the camera's position cancels). Used for a
bounded time (``controller.predict_hand_s``), only while the carried corners stay in the
image, and never to call a run converged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics
from common.marker import Marker
from services.controller.acquisition import border_distance_px

FloatArray = NDArray[np.float64]


def carried_by_encoders(
    last_hand: Marker,
    t_base_ee_then: FloatArray,
    t_base_ee_now: FloatArray,
    t_base_cam: FloatArray,
    k: CameraIntrinsics,
) -> Marker | None:
    """``last_hand`` (seen with the end effector at ``t_base_ee_then``, 4×4, base frame) moved
    with the end effector to ``t_base_ee_now``, as the camera at ``t_base_cam`` (the assumed
    pose) sees it; None when a corner would fall outside the image or behind the camera."""
    moved_base = t_base_ee_now @ np.linalg.inv(t_base_ee_then)
    moved_cam = np.linalg.inv(t_base_cam) @ moved_base @ t_base_cam
    points = last_hand.points_m @ moved_cam[:3, :3].T + moved_cam[:3, 3]
    if np.any(points[:, 2] <= 1e-3):
        return None
    carried = Marker.seen_at(points, k, last_hand.depth_sigma_m)
    return None if border_distance_px(carried.corners_px, k) < 0.0 else carried


@dataclass
class HandMemory:
    """The hand's last usable view, the end effector's pose then, and since when (sim s) the
    hand has been carried from it (None: seen now, or not carried)."""

    last: Marker | None = None
    t_base_ee_then: FloatArray | None = None
    carried_since_s: float | None = None

    def now(
        self,
        hand: Marker,
        t_base_ee: FloatArray,
        t_base_cam: FloatArray,
        k: CameraIntrinsics,
        t_s: float,
        limit_s: float,
    ) -> tuple[Marker, bool]:
        """``(hand, carried)``: the hand as seen, remembered when usable; when not, for at most
        ``limit_s`` (0: never) its last view carried to ``t_base_ee`` while it stays in the
        image (:func:`carried_by_encoders`); else the hand as seen."""
        if hand.usable:
            self.last, self.t_base_ee_then, self.carried_since_s = hand, t_base_ee, None
            return hand, False
        if self.last is None or self.t_base_ee_then is None or limit_s == 0.0:
            return hand, False
        since = t_s if self.carried_since_s is None else self.carried_since_s
        if t_s - since > limit_s:
            return hand, False
        carried = carried_by_encoders(self.last, self.t_base_ee_then, t_base_ee, t_base_cam, k)
        if carried is None:
            return hand, False
        self.carried_since_s = since
        return carried, True

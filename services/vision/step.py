"""Vision's one step as a pure function: a colour frame and the depth image it names →
both markers' wire features and the tracker state for the next frame.

The vision node and the in-process pipeline (services/pipeline.py) both call it; the node only
adds the transport (waiting for a depth image, the frame ring's overwrite check, publishing).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from common.camera import CameraIntrinsics
from common.config import VisionConfig
from common.marker import Marker
from common.messages import DepthFrame, Features, Header, RgbFrame
from services.vision.tracking import DepthImage, TrackerState, observe


def depth_for(frame: RgbFrame, depths: OrderedDict[int, DepthFrame]) -> DepthFrame | None:
    """The depth image ``frame`` names, else the newest one taken at or before it."""
    if frame.depth_frame_seq in depths:
        return depths[frame.depth_frame_seq]
    older = [seq for seq in depths if seq <= frame.header.frame_seq]
    return depths[max(older)] if older else None


def depth_image(
    depth_m: np.ndarray, intrinsics: CameraIntrinsics, taken_s: float, frame_s: float
) -> DepthImage:
    """A depth image taken at sim time ``taken_s``, for the colour frame taken at ``frame_s``."""
    return DepthImage(depth_m, intrinsics, max(0.0, frame_s - taken_s))


@dataclass(frozen=True)
class VisionStep:
    """One frame's measurements (``measured``: vision's own), and the state for the next."""

    measured: dict[str, Marker]
    tracker: TrackerState
    depth_age_s: float | None

    def features(self, header: Header, intrinsics: CameraIntrinsics) -> Features:
        """What vision publishes for this frame."""
        return Features(
            header=header,
            intrinsics=intrinsics,
            hand=self.measured["hand"].to_wire(),
            target=self.measured["target"].to_wire(),
            depth_age_s=self.depth_age_s,
        )


def vision_step(
    rgb: np.ndarray,
    intrinsics: CameraIntrinsics,
    depth: DepthImage | None,
    config: VisionConfig,
    marker_size_m: float,
    tracker: TrackerState,
    t_s: float,
    orientation_cue: bool = False,
) -> VisionStep:
    """Both markers in the colour frame taken at sim time ``t_s`` with the newest depth image
    (None: none yet), given the tracker state the previous frame left; ``orientation_cue``
    (``marker.orientation_cue``): corners labelled by each marker's cue."""
    measured, next_tracker = observe(
        rgb, intrinsics, depth, config, marker_size_m, tracker, t_s, orientation_cue
    )
    return VisionStep(measured, next_tracker, None if depth is None else depth.age_s)

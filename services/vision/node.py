"""Vision service: RGB-D frame → corners, depths and 3-D points of both markers."""

from __future__ import annotations

import numpy as np

from common.codec import FRAME_MAX_BYTES
from common.messages import Features, MarkerFeatures, RgbdFrame
from common.runtime import ServiceContext
from common.transport import Node
from services.vision.features import MarkerMeasurement, measure_markers


def to_message(m: MarkerMeasurement) -> MarkerFeatures:
    return MarkerFeatures(
        visible=m.visible,
        corners_px=m.corners_px.tolist(),
        depth_m=m.depths_m.tolist(),
        points_m=m.points_m.tolist(),
        reason=m.reason,
    )


class VisionService:
    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.config = ctx.scenario.vision
        self.node = Node("vision", ctx.keys, ctx.session, self.status_fields, self.degraded)
        self.pub = self.node.publisher(ctx.keys.features)
        self.node.subscribe(ctx.keys.rgbd, RgbdFrame, FRAME_MAX_BYTES, latest_only=True)
        # Last visible corners per marker: keeps the corner order from flipping as a square turns.
        self.previous: dict[str, np.ndarray] = {}
        self.visible: dict[str, bool] = {"hand": False, "target": False}
        self.reasons: dict[str, str] = {"hand": "", "target": ""}

    def status_fields(self) -> dict:
        # RGB and depth come registered in one frame, so the depth is as old as the image.
        return {
            "markers_visible": dict(self.visible),
            "lost_reasons": dict(self.reasons),
            "depth_age_s": 0.0,
        }

    def degraded(self) -> str:
        lost = [f"{n}: {r}" for n, r in self.reasons.items() if r]
        return "marker not visible (" + "; ".join(lost) + ")" if lost else ""

    def on_frame(self, frame: RgbdFrame) -> None:
        rgb, depth = frame.rgb.to_array(), frame.depth_m.to_array()
        measured = measure_markers(rgb, depth, frame.intrinsics, self.config, self.previous)
        for name, m in measured.items():
            self.visible[name] = m.visible
            self.reasons[name] = m.reason
            if m.visible:
                self.previous[name] = m.corners_px
        header = self.node.header(frame.header.sim_time_s, frame.header.frame_seq)
        self.pub.put(
            Features(
                header=header,
                intrinsics=frame.intrinsics,
                hand=to_message(measured["hand"]),
                target=to_message(measured["target"]),
            )
        )

    def run(self) -> None:
        self.node.spin(self.ctx.stop, lambda _key, frame: self.on_frame(frame))


def main(argv: list[str] | None = None) -> int:
    VisionService(ServiceContext("vision", argv)).run()
    return 0

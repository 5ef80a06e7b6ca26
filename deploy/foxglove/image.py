"""The camera's images as Foxglove messages: the colour frame as JPEG, the depth image, the
calibration, and the overlay of the markers, the desired corners, the error and the trail."""

from __future__ import annotations

import cv2
import numpy as np
from foxglove.messages import (
    CameraCalibration,
    CircleAnnotation,
    Color,
    CompressedImage,
    ImageAnnotations,
    KeyValuePair,
    Point2,
    PointsAnnotation,
    PointsAnnotationType,
    RawImage,
    TextAnnotation,
)

from common.camera import CameraIntrinsics
from common.messages import DepthFrame, Features, MarkerFeatures, RgbFrame
from deploy.foxglove.style import CYAN, GREEN, ORANGE, RED, WHITE, YELLOW, color
from deploy.foxglove.topics import CAMERA
from deploy.foxglove.transforms import stamp

FloatArray = np.ndarray


def compressed_image(frame: RgbFrame, jpeg_quality: int = 85) -> CompressedImage:
    """The colour frame as JPEG (OpenCV), in the ``camera`` frame."""
    bgr = cv2.cvtColor(frame.rgb.to_array(), cv2.COLOR_RGB2BGR)
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError("OpenCV could not encode the frame as JPEG")
    return CompressedImage(
        timestamp=stamp(frame.header.sim_time_s),
        frame_id=CAMERA,
        data=jpeg.tobytes(),
        format="jpeg",
    )


def depth_image(frame: DepthFrame) -> RawImage:
    """The depth image as it is (float32 metres, 0 = no measurement): encoding ``32FC1``."""
    h, w = frame.depth_m.shape
    return RawImage(
        timestamp=stamp(frame.header.sim_time_s),
        frame_id=CAMERA,
        width=w,
        height=h,
        encoding="32FC1",
        step=4 * w,
        data=bytes(frame.depth_m.data),
    )


def calibration(k: CameraIntrinsics, t_s: float) -> CameraCalibration:
    """Pinhole intrinsics of the colour image, no distortion (the simulated Kinect has none)."""
    return CameraCalibration(
        timestamp=stamp(t_s),
        frame_id=CAMERA,
        width=k.width_px,
        height=k.height_px,
        distortion_model="plumb_bob",
        D=[0.0] * 5,
        K=[k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0],
    )


def _points(
    kind: PointsAnnotationType,
    pts: FloatArray,
    rgba: tuple[float, float, float, float],
    t_s: float,
    name: str,
    thickness: float = 2.0,
) -> PointsAnnotation:
    return PointsAnnotation(
        timestamp=stamp(t_s),
        type=kind,
        points=[Point2(x=float(u), y=float(v)) for u, v in pts],
        outline_color=color(rgba),
        thickness=thickness,
        metadata=[KeyValuePair(key="name", value=name)],
    )


def _marker_colour(m: MarkerFeatures, seen: tuple[float, float, float, float]):
    return seen if m.state == "visible" else ORANGE


def _state_text(name: str, m: MarkerFeatures) -> str:
    extra = " (fitted)" if m.fitted else ""
    extra += " (occluded)" if m.occluded else ""
    return f"{name}: {m.state}{extra}"


def image_annotations(
    features: Features,
    desired_px: FloatArray | None,
    trail_px: list[tuple[float, float]],
    error_px_rms: float | None,
) -> ImageAnnotations:
    """Fig. 5.10-5.16's overlay: the hand's square (green), the target's (red), both orange
    when only partly seen, the controller's desired corners s* (yellow; ``desired_px`` row i
    is where hand corner i is driven), the error vectors s → s* (cyan),
    the hand-marker centre's trail (white dots) and the states and pixel error as text.
    Each points annotation names itself in its metadata (``name``: hand, target, desired,
    error, trail)."""
    t = features.header.sim_time_s
    points: list[PointsAnnotation] = []
    circles: list[CircleAnnotation] = []
    loop = PointsAnnotationType.LineLoop
    for name, m, rgba in (("hand", features.hand, GREEN), ("target", features.target, RED)):
        if not m.usable:
            continue
        corners = np.asarray(m.corners_px, dtype=float)
        points.append(_points(loop, corners, _marker_colour(m, rgba), t, name))
        circles.extend(
            CircleAnnotation(
                timestamp=stamp(t),
                position=Point2(x=float(u), y=float(v)),
                diameter=6.0,
                thickness=1.5,
                outline_color=color(_marker_colour(m, rgba)),
            )
            for u, v in corners
        )
    if desired_px is not None:
        points.append(_points(loop, desired_px, YELLOW, t, "desired", 1.5))
        if features.hand.usable:
            hand = np.asarray(features.hand.corners_px, dtype=float)
            segments = np.stack([hand, desired_px], axis=1).reshape(-1, 2)
            points.append(_points(PointsAnnotationType.LineList, segments, CYAN, t, "error", 1.5))
    if trail_px:
        points.append(
            _points(PointsAnnotationType.Points, np.array(trail_px), WHITE, t, "trail", 3.0)
        )
    lines = [
        _state_text("hand", features.hand),
        _state_text("target", features.target),
        "e: -" if error_px_rms is None else f"e: {error_px_rms:.2f} px rms",
    ]
    texts = [
        TextAnnotation(
            timestamp=stamp(t),
            position=Point2(x=8.0, y=20.0 + 18.0 * i),
            text=line,
            font_size=14.0,
            text_color=color(WHITE),
            background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
        )
        for i, line in enumerate(lines)
    ]
    return ImageAnnotations(circles=circles, points=points, texts=texts)

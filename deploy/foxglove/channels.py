"""The Foxglove channels of the view, on one SDK context: the live server and the exporter
each make their own context and log :class:`~deploy.foxglove.convert.Out` records to it.

Well-known Foxglove schemas (the SDK encodes them as protobuf) for images, annotations,
transforms, scenes, joint states and logs; JSON with a JSON schema for the plot topics.
"""

from __future__ import annotations

from typing import Any

import foxglove
from foxglove.channels import (
    CameraCalibrationChannel,
    CompressedImageChannel,
    FrameTransformsChannel,
    ImageAnnotationsChannel,
    JointStatesChannel,
    LogChannel,
    RawImageChannel,
    SceneUpdateChannel,
)

from deploy.foxglove import convert, topics

WELL_KNOWN: dict[str, Any] = {
    topics.COLOUR_IMAGE: CompressedImageChannel,
    topics.DEPTH_IMAGE: RawImageChannel,
    topics.CALIBRATION: CameraCalibrationChannel,
    topics.ANNOTATIONS: ImageAnnotationsChannel,
    topics.TRANSFORMS: FrameTransformsChannel,
    topics.SCENE: SceneUpdateChannel,
    topics.TRUTH_SCENE: SceneUpdateChannel,
    topics.JOINT_STATES: JointStatesChannel,
    topics.JOINT_COMMAND: JointStatesChannel,
    topics.LOG: LogChannel,
}
TOPICS: tuple[str, ...] = (*WELL_KNOWN, *topics.JSON_SCHEMAS)


class FoxgloveChannels:
    """One channel per view topic on ``context``."""

    def __init__(self, context: foxglove.Context) -> None:
        self.channels: dict[str, Any] = {
            topic: kind(topic, context=context) for topic, kind in WELL_KNOWN.items()
        }
        for topic, schema in topics.JSON_SCHEMAS.items():
            self.channels[topic] = foxglove.Channel(topic, schema=schema, context=context)

    def wanted(self, topic: str) -> bool:
        """Someone listens on ``topic`` (a client subscribed, or a file is open)."""
        return self.channels[topic].has_sinks()

    def any_wanted(self) -> bool:
        return any(ch.has_sinks() for ch in self.channels.values())

    def log(self, out: convert.Out) -> None:
        self.channels[out.topic].log(out.message, log_time=out.log_time_ns)

    def log_all(self, outs: list[convert.Out]) -> None:
        for out in outs:
            self.log(out)

    def close(self) -> None:
        for channel in self.channels.values():
            channel.close()

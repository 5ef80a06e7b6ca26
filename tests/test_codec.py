"""The wire format: round trips, and one clear error type for every kind of bad payload."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from common.camera import CameraIntrinsics
from common.codec import DEFAULT_MAX_BYTES, FRAME_MAX_BYTES, MessageError, decode, encode
from common.messages import DepthFrame, Header, ImageData, JointVelocityCommand, RgbFrame

K = CameraIntrinsics.from_fov(64, 48, 57.0)


HEADER = Header(seq=3, sim_time_s=0.1, send_time_s=1.0, frame_seq=3)


def frame() -> RgbFrame:
    rgb = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    return RgbFrame(header=HEADER, intrinsics=K, rgb=ImageData.from_array(rgb), depth_frame_seq=3)


def depth_frame() -> DepthFrame:
    depth = np.full((48, 64), 0.7, dtype=np.float32)
    return DepthFrame(header=HEADER, intrinsics=K, depth_m=ImageData.from_array(depth))


def command(**kw) -> dict:
    base = JointVelocityCommand(
        header=Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0),
        velocity_rad_s=[0.1] * 6,
    ).model_dump()
    base.update(kw)
    return base


def test_frame_round_trip_keeps_images_as_bytes() -> None:
    f, d = frame(), depth_frame()
    payload = encode(f)
    assert len(payload) < 48 * 64 * 3 + 1000  # raw bytes, not lists of numbers
    back = decode(payload, RgbFrame, FRAME_MAX_BYTES)
    np.testing.assert_array_equal(back.rgb.to_array(), f.rgb.to_array())
    assert back.depth_frame_seq == 3
    payload = encode(d)
    assert len(payload) < 48 * 64 * 4 + 1000
    back_depth = decode(payload, DepthFrame, FRAME_MAX_BYTES)
    np.testing.assert_array_equal(back_depth.depth_m.to_array(), d.depth_m.to_array())


@pytest.mark.parametrize(
    "payload, fragment",
    [
        (b"\xc1garbage", "not valid msgpack"),
        (msgpack.packb([1, 2, 3]), "expected a map"),
        (msgpack.packb(command(velocity_rad_s=[0.1] * 5)), "velocity_rad_s"),
        (msgpack.packb(command(velocity_rad_s=[math.nan] * 6)), "velocity_rad_s"),
        (msgpack.packb(command(velocity_rad_s=["a"] * 6)), "velocity_rad_s"),
        (msgpack.packb(command(extra=1)), "extra"),
        (msgpack.packb(command(velocity_rad_s=[1e6] * 6)), "less than or equal"),
        (msgpack.packb(command()) + b"\x00" * DEFAULT_MAX_BYTES, "exceeds"),
    ],
)
def test_bad_payloads_raise_message_error(payload: bytes, fragment: str) -> None:
    with pytest.raises(MessageError, match=fragment):
        decode(payload, JointVelocityCommand, DEFAULT_MAX_BYTES)


def test_truncated_frame_is_rejected() -> None:
    payload = encode(frame())
    with pytest.raises(MessageError):
        decode(payload[: len(payload) // 2], RgbFrame, FRAME_MAX_BYTES)


def test_image_size_must_match_shape() -> None:
    data = frame().model_dump()
    data["rgb"]["data"] = data["rgb"]["data"][:-3]
    with pytest.raises(MessageError, match="rgb"):
        decode(msgpack.packb(data), RgbFrame, FRAME_MAX_BYTES)
    data = depth_frame().model_dump()
    data["depth_m"] = ImageData.from_array(np.zeros((10, 10), np.float32)).model_dump()
    with pytest.raises(MessageError, match="depth_m"):
        decode(msgpack.packb(data), DepthFrame, FRAME_MAX_BYTES)
    data = depth_frame().model_dump()
    data["depth_m"] = ImageData.from_array(np.zeros((48, 64), np.uint8)).model_dump()
    with pytest.raises(MessageError, match="float32"):
        decode(msgpack.packb(data), DepthFrame, FRAME_MAX_BYTES)

"""The wire format: round trips, and one clear error type for every kind of bad payload."""

from __future__ import annotations

import math
from typing import get_args

import msgpack
import numpy as np
import pytest

from common.camera import CameraIntrinsics
from common.codec import (
    DEFAULT_MAX_BYTES,
    FRAME_ALIGN,
    FRAME_MAGIC,
    FRAME_MAX_BYTES,
    FRAME_PREFIX,
    FRAME_VERSION,
    MessageError,
    decode,
    encode,
    unpack,
)
from common.messages import (
    ITEMSIZE,
    DepthFrame,
    Header,
    ImageData,
    ImageDtype,
    ImageSpec,
    JointVelocityCommand,
    RgbFrame,
)

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


def test_frame_round_trip_keeps_images_as_raw_bytes() -> None:
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


def test_image_sizes_are_numpys_for_every_allowed_dtype() -> None:
    assert set(get_args(ImageDtype)) == set(ITEMSIZE)
    for dtype in ITEMSIZE:
        for shape in ([480, 640], [240, 320, 3], [1, 1]):
            expected = np.zeros(shape, dtype).nbytes
            assert ImageSpec(shape=shape, dtype=dtype).nbytes == expected  # type: ignore[arg-type]


# --- the raw frame layout --------------------------------------------------------------------
def test_frames_travel_as_a_header_and_raw_pixels_decoded_as_views() -> None:
    f, d = frame(), depth_frame()
    payload = encode(f)
    assert payload[:4] == FRAME_MAGIC
    start = len(payload) - 48 * 64 * 3
    assert start % FRAME_ALIGN == 0 and payload[start:] == f.rgb.to_array().tobytes()
    back = decode(payload, RgbFrame, FRAME_MAX_BYTES)
    pixels = back.rgb.to_array()
    np.testing.assert_array_equal(pixels, f.rgb.to_array())
    assert not pixels.flags.writeable and not pixels.flags.owndata  # a view, not a copy
    assert back.header == f.header and back.intrinsics == f.intrinsics
    back_depth = decode(encode(d), DepthFrame, FRAME_MAX_BYTES)
    assert back_depth.depth_m.to_array().dtype == np.float32
    np.testing.assert_array_equal(back_depth.depth_m.to_array(), d.depth_m.to_array())


def test_a_frame_made_from_a_view_encodes_like_one_made_from_a_copy() -> None:
    rgb = np.random.default_rng(1).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    copied = RgbFrame(header=HEADER, intrinsics=K, rgb=ImageData.from_array(rgb))
    viewed = RgbFrame(header=HEADER, intrinsics=K, rgb=ImageData.view_of(rgb))
    assert encode(viewed) == encode(copied)
    with pytest.raises(ValueError, match="float32"):  # intrinsics and shape are still checked
        RgbFrame(header=HEADER, intrinsics=K, rgb=ImageData.view_of(rgb[:, :, 0].astype("f4")))
    with pytest.raises(ValueError):
        ImageData.view_of(np.zeros((4, 4), np.float64))  # a dtype the wire does not carry


def test_frames_in_plain_msgpack_still_decode() -> None:
    """Recordings made before the raw layout hold frames as one msgpack map."""
    legacy = msgpack.packb(frame().model_dump(), use_bin_type=True)
    back = decode(legacy, RgbFrame, FRAME_MAX_BYTES)
    np.testing.assert_array_equal(back.rgb.to_array(), frame().rgb.to_array())


def _layout(head: dict, pixels: bytes, version: int = FRAME_VERSION, head_len: int | None = None):
    h = msgpack.packb(head, use_bin_type=True)
    used = FRAME_PREFIX.size + len(h)
    pad = bytes(-(-used // FRAME_ALIGN) * FRAME_ALIGN - used)
    n = len(h) if head_len is None else head_len
    return FRAME_PREFIX.pack(FRAME_MAGIC, version, n) + h + pad + pixels


@pytest.mark.parametrize(
    "change, fragment",
    [
        (lambda h, p: _layout(h, p, version=2), "version 2"),
        (lambda h, p: _layout(h, p, head_len=1 << 20), "does not fit"),
        (lambda h, p: _layout(h, p)[:40], "truncated|does not fit"),
        (lambda h, p: _layout(h, p[:-1]), "rgb: image data has"),
        (lambda h, p: _layout(h, p + b"\0"), "rgb: image data has"),
        (lambda h, p: _layout({**h, "rgb": {"shape": [48, 64, 3]}}, p), "rgb.dtype"),
        (lambda h, p: _layout({**h, "rgb": {**h["rgb"], "x": 1}}, p), "rgb.x"),
        (lambda h, p: _layout({k: v for k, v in h.items() if k != "rgb"}, p), "missing image"),
        (lambda h, p: _layout({**h, "rgb": {"shape": [24, 64, 3], "dtype": "uint8"}}, p), "rgb"),
        (lambda h, p: _layout({**h, "depth_frame_seq": -5}, p), "depth_frame_seq"),
        (lambda h, p: _layout({**h, "extra": 1}, p), "extra"),
        (lambda h, p: FRAME_MAGIC + b"\x01\x00", "shorter than its prefix"),
        (lambda h, p: FRAME_MAGIC + b"\x01\x00\x03\x00\x00\x00\xc1\xc1\xc1", "not valid msgpack"),
    ],
)
def test_bad_frame_layouts_raise_message_error(change, fragment: str) -> None:
    f = frame()
    head = f.model_dump(exclude={"rgb": {"data"}})
    pixels = f.rgb.to_array().tobytes()
    assert decode(_layout(head, pixels), RgbFrame, FRAME_MAX_BYTES) == decode(
        encode(f), RgbFrame, FRAME_MAX_BYTES
    )
    with pytest.raises(MessageError, match=fragment):
        decode(change(head, pixels), RgbFrame, FRAME_MAX_BYTES)


def test_a_frame_on_the_wrong_key_is_rejected() -> None:
    with pytest.raises(MessageError, match="DepthFrame"):
        decode(encode(frame()), DepthFrame, FRAME_MAX_BYTES)


def test_unpack_reads_headers_of_both_layouts_without_pixels() -> None:
    f = frame()
    assert unpack(encode(f))["header"]["frame_seq"] == 3
    assert "data" not in unpack(encode(f))["rgb"]
    assert unpack(msgpack.packb(f.model_dump(), use_bin_type=True))["depth_frame_seq"] == 3
    assert unpack(b"\xc1garbage") is None and unpack(FRAME_MAGIC + b"\x01") is None

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
    FrameUnreachable,
    MessageError,
    by_reference,
    decode,
    encode,
    frame_parts,
    is_by_reference,
    unpack,
    whole_frame,
)
from common.frame_ring import FrameRef, RingReader, RingWriter
from common.messages import (
    ITEMSIZE,
    DepthFrame,
    Header,
    ImageData,
    ImageDtype,
    ImageSpec,
    JointVelocityCommand,
    MarkerFeatures,
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


def marker(**kw) -> dict:
    """A visible 40 px marker 0.8 m away (500 px focal length), as a dict to spoil."""
    corners = [[300.0, 200.0], [340.0, 200.0], [340.0, 240.0], [300.0, 240.0]]
    base = {
        "state": "visible",
        "corners_px": corners,
        "depth_m": [0.8] * 4,
        "depth_sigma_m": [0.001] * 4,
        "points_m": [[(u - 320) * 0.0016, (v - 240) * 0.0016, 0.8] for u, v in corners],
    }
    return base | kw


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"depth_m": [0.8, 0.8, 0.0, 0.8]}, "at least 0.01 m in front"),
        ({"points_m": [[0.0, 0.0, 0.0]] * 4}, "at least 0.01 m in front"),
        ({"corners_px": [[300.0, 200.0]] * 4}, "corners_px enclose no area"),
        ({"points_m": [[0.1, 0.0, 0.8]] * 4}, "points_m enclose no area"),
        ({"state": "partial", "fitted": True, "depth_m": [0.0] * 4}, "partial marker needs"),
    ],
)
def test_a_usable_marker_the_controller_could_not_act_on_is_refused(change, fragment) -> None:
    """The controller divides by a usable marker's depths and fits its points: zero depth or a
    collapsed square would end it with a NaN twist, so the wire format refuses them."""
    payload = msgpack.packb(marker(**change))
    with pytest.raises(MessageError, match=fragment):
        decode(payload, MarkerFeatures, DEFAULT_MAX_BYTES)


def test_a_marker_not_usable_may_carry_zeros() -> None:
    assert decode(msgpack.packb(marker()), MarkerFeatures, DEFAULT_MAX_BYTES).usable
    zeros = {"depth_m": [0.0] * 4, "points_m": [[0.0] * 3] * 4, "corners_px": [[0.0] * 2] * 4}
    for state in ("lost", "no_depth", "partial"):
        m = decode(msgpack.packb(marker(state=state, **zeros)), MarkerFeatures, DEFAULT_MAX_BYTES)
        assert not m.usable


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
        (lambda h, p: _layout(h, p, version=3), "version 3"),
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


# --- frames by reference ------------------------------------------------------------------
@pytest.fixture()
def rings(tmp_path):
    writer, reader = RingWriter(4, tmp_path, "host/boot"), RingReader(tmp_path, "host/boot")
    yield writer, reader
    writer.close()


def by_ref(writer: RingWriter, message: RgbFrame | DepthFrame) -> tuple[bytes, FrameRef]:
    head, pixels = frame_parts(message)
    image = message.rgb if isinstance(message, RgbFrame) else message.depth_m
    ref = writer.write(pixels, image.shape, image.dtype)
    return by_reference(head, ref), ref


def test_a_frame_by_reference_decodes_to_the_same_message_viewing_the_ring(rings) -> None:
    writer, reader = rings
    for original, model in ((frame(), RgbFrame), (depth_frame(), DepthFrame)):
        payload, ref = by_ref(writer, original)
        assert is_by_reference(payload) and not is_by_reference(encode(original))
        assert len(payload) < 512  # the header and a reference, no pixels
        back = decode(payload, model, DEFAULT_MAX_BYTES, reader)
        image = back.rgb if model is RgbFrame else back.depth_m
        assert back.model_dump(exclude={"rgb", "depth_m"}) == original.model_dump(
            exclude={"rgb", "depth_m"}
        )
        want = original.rgb if model is RgbFrame else original.depth_m
        np.testing.assert_array_equal(image.to_array(), want.to_array())
        assert image.ring_ref == ref and image.intact()
        assert not image.to_array().flags.writeable
        # Read in place: the ring's next writes into that slot show through the view, and
        # the image says so.
        for _ in range(4):
            by_ref(writer, original)
        assert not image.intact()
        # The header reads like any frame's, for tools that only need it.
        assert unpack(payload)["header"]["frame_seq"] == 3


def test_whole_frame_turns_a_reference_back_into_the_ordinary_layout(rings) -> None:
    writer, reader = rings
    f = frame()
    payload, _ref = by_ref(writer, f)
    assert whole_frame(payload, RgbFrame, reader) == encode(f)
    assert whole_frame(encode(f), RgbFrame, reader) == encode(f)  # already whole
    for _ in range(4):
        by_ref(writer, f)
    with pytest.raises(MessageError, match="overwritten"):
        whole_frame(payload, RgbFrame, reader)


def test_a_reference_out_of_reach_or_overwritten_is_refused_with_its_reason(rings) -> None:
    writer, reader = rings
    payload, ref = by_ref(writer, frame())
    elsewhere = RingReader(writer.directory, "another/host")
    with pytest.raises(FrameUnreachable, match="another host") as caught:
        decode(payload, RgbFrame, DEFAULT_MAX_BYTES, elsewhere)
    assert caught.value.ref == ref  # what to ask the publisher for
    for _ in range(4):
        by_ref(writer, frame())
    with pytest.raises(MessageError, match=r"overwritten in .* before it was read") as caught:
        decode(payload, RgbFrame, DEFAULT_MAX_BYTES, reader)
    assert not isinstance(caught.value, FrameUnreachable)  # nobody has that frame any more
    writer.close()
    with pytest.raises(FrameUnreachable, match="cannot open"):
        decode(payload, RgbFrame, DEFAULT_MAX_BYTES, RingReader(writer.directory, "host/boot"))


@pytest.mark.parametrize(
    "change, fragment",
    [
        (lambda m: {**m, "shape": [48, 64]}, "header says uint8"),
        (lambda m: {**m, "dtype": "float32"}, "header says uint8"),
        (lambda m: {k: v for k, v in m.items() if k != "slot"}, "missing 'slot'"),
        (lambda m: [1, 2], "expected a map"),
    ],
)
def test_a_bad_reference_is_a_message_error(rings, change, fragment: str) -> None:
    writer, reader = rings
    payload, ref = by_ref(writer, frame())
    body = msgpack.packb(ref.to_map(), use_bin_type=True)
    forged = payload[: -len(body)] + msgpack.packb(change(ref.to_map()), use_bin_type=True)
    with pytest.raises(MessageError, match=fragment):
        decode(forged, RgbFrame, DEFAULT_MAX_BYTES, reader)

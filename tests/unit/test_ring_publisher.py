"""A camera stream's publisher with its frame ring, without Zenoh (a stand-in session that
keeps what is put): frames drawn straight into a reserved slot go by reference without a copy,
anything else is copied in, a frame put again is the same reference, and a slot written since
is never sent again."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from common.camera import CameraIntrinsics
from common.codec import FRAME_MAX_BYTES, decode, is_by_reference
from common.frame_ring import RingError, RingReader, RingWriter
from common.messages import Header, ImageData, RgbFrame
from common.publishers import RingPublisher, TypedPublisher

SLOTS = 4
HOST = "test-host/boot"
K = CameraIntrinsics.from_fov(64, 48, 57.0)
SHAPE = (48, 64, 3)


def image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, SHAPE, dtype=np.uint8)


def frame(seq: int, pixels: np.ndarray) -> RgbFrame:
    header = Header(seq=seq, sim_time_s=0.0, send_time_s=1.0, frame_seq=seq)
    return RgbFrame(header=header, intrinsics=K, rgb=ImageData.view_of(pixels))


class Sent:
    """A stand-in for a Zenoh session and publisher: keeps every payload put."""

    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.payloads.append(payload)

    def declare_queryable(self, _key: str, _callback: object) -> SimpleNamespace:
        return SimpleNamespace(undeclare=lambda: None)

    def undeclare(self) -> None:
        pass


@pytest.fixture()
def stream(tmp_path: Path):
    sent = Sent()
    ring = RingPublisher(sent, "test/rgb")  # type: ignore[arg-type]
    ring.ring = RingWriter(SLOTS, tmp_path, HOST)
    pub = TypedPublisher("test/rgb", sent, frames=ring)
    yield pub, ring, sent, RingReader(tmp_path, HOST)
    pub.close()


def received(sent: Sent, reader: RingReader) -> RgbFrame:
    payload = sent.payloads[-1]
    assert is_by_reference(payload)
    return decode(payload, RgbFrame, FRAME_MAX_BYTES, reader)


def test_a_frame_drawn_into_the_reserved_slot_is_committed_without_a_copy(stream) -> None:
    pub, ring, sent, reader = stream
    slot = pub.reserve(SHAPE, "uint8")
    assert slot is not None and slot.flags.writeable
    slot[...] = image(1)  # as the renderer draws it
    message = frame(1, slot)
    pub.put(message)
    assert (ring.in_place, ring.copied) == (1, 0)
    got = received(sent, reader)
    np.testing.assert_array_equal(got.rgb.to_array(), image(1))
    assert got.rgb.intact() and got.header == message.header
    # Put again (a lockstep resend): the same reference, nothing committed or copied again.
    pub.put(message)
    assert sent.payloads[-1] == sent.payloads[-2]
    assert (ring.in_place, ring.copied) == (1, 0) and pub.meter.by_ref == 2


def test_a_frame_drawn_elsewhere_is_copied_into_the_ring(stream) -> None:
    pub, ring, sent, reader = stream
    slot = pub.reserve(SHAPE, "uint8")  # reserved, but the image comes from elsewhere
    assert slot is not None
    pub.put(frame(1, image(1)))  # (the Kinect model's output, TinyRenderer's arrays)
    first = received(sent, reader)
    np.testing.assert_array_equal(first.rgb.to_array(), image(1))
    np.testing.assert_array_equal(slot, image(1))  # into the slot that was reserved
    pub.put(frame(2, image(2)))  # nothing reserved: into the next slot
    second = received(sent, reader)
    np.testing.assert_array_equal(second.rgb.to_array(), image(2))
    assert second.rgb.ring_ref.seq == first.rgb.ring_ref.seq + 1
    assert (ring.in_place, ring.copied) == (0, 2)
    assert first.rgb.intact() and second.rgb.intact()


def test_a_frame_whose_slot_was_written_since_is_never_sent_again(stream) -> None:
    pub, _ring, sent, _reader = stream
    slot = pub.reserve(SHAPE, "uint8")
    assert slot is not None
    slot[...] = image(1)
    old = frame(1, slot)
    pub.put(old)
    for seq in range(2, 2 + SLOTS):  # the ring wraps past it
        pub.put(frame(seq, image(seq)))
    count = len(sent.payloads)
    with pytest.raises(RingError, match="frame 1 was overwritten"):
        pub.put(old)
    assert len(sent.payloads) == count  # nothing was put


def test_without_a_ring_nothing_is_reserved_and_frames_go_whole(tmp_path: Path) -> None:
    sent = Sent()
    assert TypedPublisher("test/rgb", sent).reserve(SHAPE, "uint8") is None  # ring off
    ring = RingPublisher(sent, "test/rgb")  # type: ignore[arg-type]
    ring.ring = RingWriter(SLOTS, tmp_path / "no-such-dir", HOST)  # no room for one here
    pub = TypedPublisher("test/rgb", sent, frames=ring)
    assert pub.reserve(SHAPE, "uint8") is None and "cannot create" in ring.unavailable
    pub.put(frame(1, image(1)))
    assert not is_by_reference(sent.payloads[-1]) and pub.meter.by_copy == 1
    whole = decode(sent.payloads[-1], RgbFrame, FRAME_MAX_BYTES)
    np.testing.assert_array_equal(whole.rgb.to_array(), image(1))

"""Camera frames by reference over Zenoh (loopback, one process, a unique key prefix): the
publisher's ring, the subscriber's one decoding path, the whole frame for a subscriber that
cannot map the ring, the recorder, and frames by copy when the ring is off."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import zenoh

from common.camera import CameraIntrinsics
from common.codec import (
    FRAME_MAX_BYTES,
    by_reference,
    decode,
    encode,
    frame_parts,
    is_by_reference,
)
from common.frame_ring import RING_SLOTS, RingReader, RingWriter
from common.keys import Keys
from common.messages import DepthFrame, Header, ImageData, RgbFrame
from common.node import Node
from common.publishers import typed_publisher
from common.session import ENV_SHM, free_tcp_endpoint, open_session
from deploy.recording.read import iter_messages
from deploy.recording.record import Recorder
from tests.prefixes import unique_keys

K = CameraIntrinsics.from_fov(64, 48, 57.0)
ELSEWHERE = RingReader(host="another-host/boot")  # as a subscriber on another machine maps


def frame(seq: int, run: int = 0) -> RgbFrame:
    rgb = np.random.default_rng(seq).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    header = Header(seq=seq, sim_time_s=0.0, send_time_s=1.0, frame_seq=seq, run=run)
    return RgbFrame(header=header, intrinsics=K, rgb=ImageData.view_of(rgb))


@dataclass
class Loopback:
    """The publisher's session on a loopback endpoint, and nodes connected to it."""

    endpoint: str
    keys: Keys
    session: zenoh.Session
    nodes: list[Node] = field(default_factory=list)

    def node(self, name: str) -> Node:
        n = Node(name, self.keys, open_session(connect=[self.endpoint]))
        self.nodes.append(n)
        return n


@pytest.fixture()
def net() -> Iterator[Loopback]:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    loopback = Loopback(endpoint, keys, open_session(connect=[], listen=[endpoint]))
    yield loopback
    for n in loopback.nodes:
        n.close()
    loopback.session.close()


def receive(node: Node, put, timeout_s: float = 10.0) -> RgbFrame:
    """Put (again, until the subscription has reached the publisher) and take the frame."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        put()
        event = node.next_event(0.3)
        if event is not None:
            return event[1]
    raise AssertionError(f"nothing received; last rejection: {node.last_rejection}")


def test_a_local_subscriber_reads_frames_in_the_publisher_s_ring(net: Loopback) -> None:
    session, keys = net.session, net.keys
    vision = net.node("vision")
    vision.subscribe(keys.rgb, RgbFrame, FRAME_MAX_BYTES)
    pub = typed_publisher(session, keys.rgb, frames=True)
    try:
        got = receive(vision, lambda: pub.put(frame(1)))
        assert got.rgb.ring_ref is not None and got.rgb.intact()
        np.testing.assert_array_equal(got.rgb.to_array(), frame(1).rgb.to_array())
        assert got.header == frame(1).header
        stats = vision.status().received[keys.rgb]
        assert stats.by_ref == stats.count >= 1 and stats.by_copy == stats.fetched == 0
        assert pub.meter.by_ref == pub.meter.count and pub.meter.by_copy == 0
        assert pub.frames is not None and pub.frames.served == 0  # nobody asked for it whole
    finally:
        pub.close()


def test_a_subscriber_that_cannot_map_the_ring_gets_whole_frames(net: Loopback) -> None:
    session, keys = net.session, net.keys
    remote = net.node("vision")
    remote.subscribe(keys.rgb, RgbFrame, FRAME_MAX_BYTES, rings=ELSEWHERE)
    pub = typed_publisher(session, keys.rgb, frames=True)
    try:
        got = receive(remote, lambda: pub.put(frame(2)))
        assert got.rgb.ring_ref is None  # its own bytes, not a view of a ring
        np.testing.assert_array_equal(got.rgb.to_array(), frame(2).rgb.to_array())
        stats = remote.status().received[keys.rgb]
        assert stats.by_copy == stats.fetched == stats.count >= 1 and stats.by_ref == 0
        assert pub.frames is not None and pub.frames.served >= 1
        assert pub.meter.by_ref == pub.meter.count  # the publisher still sent references
    finally:
        pub.close()


def test_a_restarted_publisher_s_frames_are_fetched_whole_again(net: Loopback) -> None:
    """A fetched frame older than one delivered is late and dropped, but only within one run:
    a restarted sim numbers its messages from 0 again, and a remote vision must not drop them
    all until the new numbers pass the old ones (the loop stalled that long)."""
    session, keys = net.session, net.keys
    remote = net.node("vision")
    remote.subscribe(keys.rgb, RgbFrame, FRAME_MAX_BYTES, rings=ELSEWHERE)
    pub = typed_publisher(session, keys.rgb, frames=True)
    try:
        assert receive(remote, lambda: pub.put(frame(50, run=1))).header.seq == 50
        deadline = time.monotonic() + 10.0
        got = None
        while (got is None or got.header.run != 2) and time.monotonic() < deadline:
            got = receive(remote, lambda: pub.put(frame(0, run=2)))
        assert got is not None and got.header.run == 2 and got.header.seq == 0
        np.testing.assert_array_equal(got.rgb.to_array(), frame(0).rgb.to_array())
    finally:
        pub.close()


def test_a_frame_no_longer_in_the_ring_is_rejected_with_its_reason(net: Loopback) -> None:
    """A reference put after its slot was overwritten: the local subscriber refuses it
    (never wrong pixels), the remote one is told by the publisher that it is gone."""
    session, keys = net.session, net.keys
    local, remote = net.node("vision"), net.node("remote")
    local.subscribe(keys.rgb, RgbFrame, FRAME_MAX_BYTES)
    remote.subscribe(keys.rgb, RgbFrame, FRAME_MAX_BYTES, rings=ELSEWHERE)
    pub = typed_publisher(session, keys.rgb, frames=True)
    try:
        receive(local, lambda: pub.put(frame(3)))
        receive(remote, lambda: pub.put(frame(3)))
        time.sleep(0.5)  # every earlier put has arrived (and is still in the ring)
        while local.next_event(0.0) or remote.next_event(0.0):
            pass
        assert local.rejected == remote.rejected == 0
        assert pub.frames is not None
        stale, by_ref = pub.frames.payload(frame(4))
        assert by_ref and is_by_reference(stale)
        for _ in range(RING_SLOTS):  # the ring wraps
            pub.frames.payload(frame(5))
        pub.publisher.put(stale)
        deadline = time.monotonic() + 10
        while not (local.rejected and remote.rejected) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert local.rejected == 1 and "before it was read" in local.last_rejection
        assert remote.rejected == 1 and "no longer in the ring" in remote.last_rejection
        assert local.next_event(0.2) is None and remote.next_event(0.2) is None
    finally:
        pub.close()


def test_with_the_ring_off_frames_go_whole(net: Loopback, monkeypatch: pytest.MonkeyPatch) -> None:
    session, keys = net.session, net.keys
    monkeypatch.setenv(ENV_SHM, "0")
    vision = net.node("vision")
    vision.subscribe(keys.rgb, RgbFrame, FRAME_MAX_BYTES)
    pub = typed_publisher(session, keys.rgb, frames=True)
    try:
        assert pub.frames is None
        got = receive(vision, lambda: pub.put(frame(6)))
        assert got.rgb.ring_ref is None
        np.testing.assert_array_equal(got.rgb.to_array(), frame(6).rgb.to_array())
        stats = vision.status().received[keys.rgb]
        assert stats.by_copy == stats.count >= 1 and stats.by_ref == stats.fetched == 0
        assert pub.meter.by_copy == pub.meter.count and pub.meter.by_ref == 0
    finally:
        pub.close()


def test_the_publisher_unlinks_its_ring_when_closed(net: Loopback) -> None:
    session, keys = net.session, net.keys
    pub = typed_publisher(session, keys.rgb, frames=True)
    pub.put(frame(7))
    assert pub.frames is not None
    segment = Path("/dev/shm") / pub.frames.ring.segment
    assert segment.exists()
    pub.close()
    assert not segment.exists()


@pytest.mark.parametrize("rings", [None, ELSEWHERE], ids=["same host", "another host"])
def test_the_recorder_stores_whole_frames(net: Loopback, tmp_path: Path, rings) -> None:
    session, keys = net.session, net.keys
    path = tmp_path / "frames.mcap"
    recorder_session = open_session(connect=[net.endpoint])
    pub = typed_publisher(session, keys.rgb, frames=True)
    try:
        with Recorder(path, recorder_session, keys, rings=rings) as recorder:
            deadline = time.monotonic() + 10
            seq = 10
            while recorder.message_counts().get(keys.rgb, 0) < 3:
                assert time.monotonic() < deadline, f"recorded nothing ({recorder.last_loss})"
                pub.put(frame(seq))
                seq += 1
                time.sleep(0.1)
            time.sleep(0.3)  # the last fetched frames
        assert recorder.lost == 0, recorder.last_loss
    finally:
        pub.close()
        recorder_session.close()
    recorded = [data for topic, _t, _p, data in iter_messages(path) if topic == keys.rgb]
    assert len(recorded) >= 3
    for data in recorded:
        assert not is_by_reference(data)
        message = decode(data, RgbFrame, FRAME_MAX_BYTES)
        assert data == encode(frame(message.header.seq))  # exactly what a copy would carry


def test_vision_drops_a_measurement_whose_frame_was_overwritten_while_read(
    net: Loopback, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sim's ring wraps while vision measures a frame it reads in place: vision must
    publish nothing computed from those pixels, and count the frame as rejected, with why."""
    from common.config import load_scenario
    from services.vision import node as vision_node

    scenario = load_scenario()
    ctx = SimpleNamespace(
        scenario=scenario,
        keys=net.keys,
        session=open_session(connect=[net.endpoint]),
        stop=threading.Event(),
    )
    vision = vision_node.VisionService(ctx)  # type: ignore[arg-type]
    net.nodes.append(vision.node)
    colour_ring, depth_ring, reader = RingWriter(), RingWriter(), RingReader()
    k, kd = scenario.camera.intrinsics(), scenario.camera.depth_intrinsics()

    def header(seq: int) -> Header:
        return Header(seq=seq, sim_time_s=seq / 30.0, send_time_s=1.0, frame_seq=seq)

    def colour(seq: int) -> RgbFrame:
        rgb = np.zeros((k.height_px, k.width_px, 3), np.uint8)
        return RgbFrame(header=header(seq), intrinsics=k, rgb=ImageData.view_of(rgb))

    def in_ring(writer: RingWriter, message: RgbFrame | DepthFrame):
        head, pixels = frame_parts(message)
        image = message.rgb if isinstance(message, RgbFrame) else message.depth_m
        ref = writer.write(pixels, image.shape, image.dtype)
        return decode(by_reference(head, ref), type(message), FRAME_MAX_BYTES, reader)

    try:
        depth_m = np.full((kd.height_px, kd.width_px), 1.0, np.float32)
        depth = DepthFrame(header=header(0), intrinsics=kd, depth_m=ImageData.view_of(depth_m))
        vision.on_event(net.keys.depth, in_ring(depth_ring, depth))
        vision.on_event(net.keys.rgb, in_ring(colour_ring, colour(0)))
        assert vision.pub.meter.count == 1 and vision.node.rejected == 0  # measured, published

        measure = vision_node.vision_step

        def observe_while_the_ring_wraps(*args, **kwargs):
            out = measure(*args, **kwargs)
            for _ in range(RING_SLOTS):  # the sim goes on writing frames meanwhile
                in_ring(colour_ring, colour(1))
            return out

        monkeypatch.setattr(vision_node, "vision_step", observe_while_the_ring_wraps)
        vision.on_event(net.keys.rgb, in_ring(colour_ring, colour(1)))
        assert vision.pub.meter.count == 1  # nothing published from the torn frame
        assert vision.node.rejected == 1
        assert "overwritten while vision read it" in vision.node.last_rejection
        assert vision.status_fields().frames_overwritten == 1
    finally:
        colour_ring.close()
        depth_ring.close()


def test_vision_behind_the_camera_skips_to_the_newest_frame(ctx, pipeline_frames, tmp_path) -> None:
    """A vision that has fallen behind the camera works on the newest frame: a colour frame by
    reference whose successor the sim has already begun (its ring's next slot reserved) is
    dropped, counted, not measured; the frame before and the successor are measured."""
    from services.vision.node import VisionService
    from tests.services_in_process import published

    host = "test-host/boot"
    writer, reader = RingWriter(4, tmp_path, host), RingReader(tmp_path, host)

    def referring(seq: int, ref) -> RgbFrame:
        """Frame ``seq`` as vision decodes it when its pixels are at ``ref`` in the ring."""
        head, _ = frame_parts(pipeline_frames[seq].rgb)
        return decode(by_reference(head, ref), RgbFrame, FRAME_MAX_BYTES, reader)

    def written(seq: int):
        pixels = pipeline_frames[seq].rgb.rgb.to_array()
        return writer.write(memoryview(pixels).cast("B"), pixels.shape, str(pixels.dtype))

    service = VisionService(ctx)  # type: ignore[arg-type]
    try:
        sent = published(service)
        service.on_event(ctx.keys.rgb, referring(0, written(0)))
        behind = referring(1, written(1))
        lease = writer.reserve(behind.rgb.shape, behind.rgb.dtype)  # the sim draws frame 2
        assert behind.rgb.superseded()
        service.on_event(ctx.keys.rgb, behind)
        lease.pixels[...] = pipeline_frames[2].rgb.rgb.to_array()
        service.on_event(ctx.keys.rgb, referring(2, writer.commit(lease)))
        assert [f.header.frame_seq for f in sent] == [0, 2]
        assert service.node.received[ctx.keys.rgb].dropped == 1
    finally:
        service.node.close()
        writer.close()

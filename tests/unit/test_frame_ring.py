"""The shared-memory frame ring on its own, without Zenoh: round trips, overwritten slots,
torn reads, unreachable segments, size changes, and the writer's clean-up, in this process
(tests/integration/test_frame_ring_processes.py: across processes)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest

from common.frame_ring import (
    ALIGN,
    SEGMENT_PREFIX,
    FrameRef,
    RingReader,
    RingUnavailable,
    RingUnreachable,
    RingWriter,
    SlotLease,
    SlotOverwritten,
    remove_segments_of,
)

SLOTS = 4
HOST = "test-host/boot"


def image(seed: int, shape: tuple[int, ...] = (48, 64, 3)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, shape, dtype=np.uint8)


def write(writer: RingWriter, a: np.ndarray) -> FrameRef:
    return writer.write(memoryview(a).cast("B"), a.shape, str(a.dtype))


def as_array(view: memoryview, ref: FrameRef) -> np.ndarray:
    return np.frombuffer(view, dtype=ref.dtype).reshape(ref.shape)


@pytest.fixture()
def ring(tmp_path: Path):
    writer = RingWriter(SLOTS, tmp_path, HOST)
    reader = RingReader(tmp_path, HOST)
    yield writer, reader
    writer.close()


def test_a_frame_written_reads_back_as_a_read_only_view_of_its_slot(ring) -> None:
    writer, reader = ring
    colour, depth = image(1), np.linspace(0.3, 2.0, 48 * 64, dtype=np.float32).reshape(48, 64)
    ref = write(writer, colour)
    assert (ref.seq, ref.slot, ref.host, ref.shape, ref.dtype) == (1, 1, HOST, (48, 64, 3), "uint8")
    assert ref.offset % ALIGN == 0
    view = reader.view(ref)
    back = as_array(view, ref)
    np.testing.assert_array_equal(back, colour)
    assert not back.flags.writeable and view.readonly
    assert reader.intact(ref)
    # The reference is small, and survives its map form.
    assert FrameRef.from_map(ref.to_map()) == ref
    assert len(str(ref.to_map())) < 200
    # float32 images too, in a ring of their own
    depth_writer = RingWriter(SLOTS, writer.directory, HOST)
    try:
        dref = write(depth_writer, depth)
        np.testing.assert_array_equal(as_array(reader.view(dref), dref), depth)
    finally:
        depth_writer.close()


def test_a_slot_overwritten_before_it_is_read_is_refused(ring) -> None:
    writer, reader = ring
    refs = [write(writer, image(i)) for i in range(SLOTS + 1)]
    with pytest.raises(
        SlotOverwritten, match=f"frame 1 was overwritten .* holds frame {SLOTS + 1}"
    ):
        reader.view(refs[0])  # its slot holds the last frame now
    assert not reader.intact(refs[0])
    for i, ref in enumerate(refs[1:], start=1):  # the ring's last SLOTS frames are all there
        np.testing.assert_array_equal(as_array(reader.view(ref), ref), image(i))
        assert reader.intact(ref)


def test_a_view_whose_slot_is_overwritten_while_in_use_is_no_longer_intact(ring) -> None:
    writer, reader = ring
    ref = write(writer, image(1))
    view = reader.view(ref)
    for i in range(SLOTS):  # the ring wraps while the view is in use
        write(writer, image(10 + i))
    assert not reader.intact(ref)
    np.testing.assert_array_equal(as_array(view, ref), image(10 + SLOTS - 1))  # what it shows now


def test_a_frame_is_superseded_once_the_writer_begins_the_next(ring) -> None:
    """A reader that has fallen behind skips to the newest frame: one is superseded from the
    moment the writer begins the frame after it (reserved: being drawn), never before, also
    where the ring wraps; the newest frame never is."""
    writer, reader = ring
    refs = [write(writer, image(i)) for i in range(SLOTS)]  # the last one in slot 0
    reader.view(refs[-1])  # mapped
    assert not reader.superseded(refs[-1])
    assert all(reader.superseded(r) for r in refs[:-1])
    lease = writer.reserve((48, 64, 3), "uint8")  # the next frame begun, not yet committed
    assert reader.superseded(refs[-1])
    writer.commit(lease)
    assert not reader.superseded(lease.ref) and reader.superseded(refs[-1])


def _poke_seq(directory: Path, ref: FrameRef, begin: int | None, end: int | None) -> None:
    """Change a slot's sequence numbers as a writer would, in the segment's file."""
    with open(directory / ref.segment, "r+b") as f:
        for value, at in ((begin, 0), (end, 8)):
            if value is not None:
                f.seek(ref.offset - ALIGN + at)
                f.write(struct.pack("<Q", value))


def test_a_torn_read_is_detected(ring) -> None:
    """The writer begins the next frame in the slot (seq_begin changes) in the middle of a
    reader's use of the view: the reader must find out; and a slot whose write has begun
    but not finished is not handed out at all."""
    writer, reader = ring
    ref = write(writer, image(1))
    view = reader.view(ref)
    assert as_array(view, ref)[:24].sum() > 0  # half way through the pixels...
    _poke_seq(writer.directory, ref, begin=ref.seq + SLOTS, end=None)  # ...a write begins
    assert not reader.intact(ref)  # so what the reader made of them is thrown away
    with pytest.raises(SlotOverwritten):
        reader.view(ref)  # begun, not finished: seq_end still names the old frame
    _poke_seq(writer.directory, ref, begin=ref.seq, end=ref.seq + SLOTS)
    with pytest.raises(SlotOverwritten):
        reader.view(ref)  # an inconsistent pair is never accepted either


def test_a_missing_segment_or_another_host_is_unreachable(ring, tmp_path: Path) -> None:
    writer, reader = ring
    ref = write(writer, image(1))
    other_host = FrameRef(**{**ref.__dict__, "host": "elsewhere/boot"})
    with pytest.raises(RingUnreachable, match="another host"):
        reader.view(other_host)
    gone = FrameRef(**{**ref.__dict__, "segment": f"{SEGMENT_PREFIX}1-0123456789abcdef"})
    with pytest.raises(RingUnreachable, match="cannot open"):
        reader.view(gone)
    not_a_ring = tmp_path / f"{SEGMENT_PREFIX}2-0123456789abcdef"
    not_a_ring.write_bytes(bytes(4096))
    with pytest.raises(RingUnreachable, match="not a frame ring"):
        reader.view(FrameRef(**{**ref.__dict__, "segment": not_a_ring.name}))
    beyond = FrameRef(**{**ref.__dict__, "slot": SLOTS + 3})
    with pytest.raises(RingUnreachable, match="no slot"):
        reader.view(beyond)
    assert not reader.intact(gone)


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"segment": "../etc/passwd"}, "not a frame ring segment"),
        ({"seq": -1}, "integers >= 0"),
        ({"slot": "1"}, "integers >= 0"),
        ({"dtype": "float64"}, "dtype"),
        ({"shape": [48, 0]}, "shape"),
        ({"host": None}, "strings"),
    ],
)
def test_a_malformed_reference_is_refused(change: dict, fragment: str) -> None:
    good = FrameRef(HOST, f"{SEGMENT_PREFIX}1-00", 1, 1, 128, (2, 2), "uint8").to_map()
    with pytest.raises(ValueError, match=fragment):
        FrameRef.from_map({**good, **change})
    missing = {k: v for k, v in good.items() if k != "seq"}
    with pytest.raises(ValueError, match="missing 'seq'"):
        FrameRef.from_map(missing)


def test_a_larger_frame_gets_a_new_segment_and_old_views_stay_valid(ring) -> None:
    writer, reader = ring
    small = write(writer, image(1, (24, 32, 3)))
    old_view = reader.view(small)
    first_segment = writer.segment
    smaller = write(writer, image(2, (12, 16, 3)))  # fits the slots: same segment
    assert smaller.segment == first_segment
    large = write(writer, image(3, (48, 64, 3)))
    assert large.segment != first_segment and large.seq == 3
    assert not (writer.directory / first_segment).exists()  # the old one is unlinked...
    np.testing.assert_array_equal(as_array(reader.view(large), large), image(3, (48, 64, 3)))
    # ...and a reader that mapped it keeps what it had: nothing writes there any more.
    assert reader.intact(small)
    np.testing.assert_array_equal(as_array(old_view, small), image(1, (24, 32, 3)))
    # A reader that had not mapped it cannot any more.
    with pytest.raises(RingUnreachable):
        RingReader(writer.directory, HOST).view(small)


def test_the_writer_copies_a_frame_it_still_holds_for_a_remote_reader(ring) -> None:
    writer, _reader = ring
    refs = [write(writer, image(i)) for i in range(SLOTS + 1)]
    found = writer.copy_frame(writer.segment, refs[-1].seq)
    assert found is not None and found[1] == refs[-1]
    assert found[0] == image(SLOTS).tobytes()
    assert writer.copy_frame(writer.segment, refs[0].seq) is None  # overwritten
    assert writer.copy_frame("umay-frames-1-other", refs[-1].seq) is None  # another segment
    assert writer.copy_frame(writer.segment, 99) is None  # never written


def test_close_unlinks_and_a_killed_writer_s_segments_can_be_removed(tmp_path: Path) -> None:
    writer = RingWriter(SLOTS, tmp_path, HOST)
    ref = write(writer, image(1))
    assert [p.name for p in tmp_path.iterdir()] == [ref.segment]
    assert ref.segment.startswith(f"{SEGMENT_PREFIX}{os.getpid()}-")
    writer.close()
    writer.close()  # idempotent
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RingUnreachable):
        RingReader(tmp_path, HOST).view(ref)
    # What a writer killed outright leaves: removed by pid, others' segments left alone.
    left = RingWriter(SLOTS, tmp_path, HOST)
    write(left, image(2))
    other = tmp_path / f"{SEGMENT_PREFIX}{os.getpid() + 1}-0123456789abcdef"
    other.write_bytes(b"")
    assert remove_segments_of(os.getpid(), tmp_path) == [left.segment]
    assert [p.name for p in tmp_path.iterdir()] == [other.name]


def test_a_new_writer_removes_the_segments_of_processes_that_ended(tmp_path: Path) -> None:
    """A sim killed together with its supervisor leaves its segments to no one: the next
    writer removes those whose pid no longer exists, and only those."""
    ended_pid = 4_194_305  # above Linux's PID_MAX_LIMIT: names no process
    dead = tmp_path / f"{SEGMENT_PREFIX}{ended_pid}-0123456789abcdef"
    alive = tmp_path / f"{SEGMENT_PREFIX}{os.getppid()}-fedcba9876543210"
    unrelated = tmp_path / "not-a-ring"
    for path in (dead, alive, unrelated):
        path.write_bytes(b"")
    writer = RingWriter(SLOTS, tmp_path, HOST)
    ref = write(writer, image(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [alive.name, unrelated.name, ref.segment]
    )
    writer.close()


def test_a_ring_that_cannot_be_created_says_why(tmp_path: Path) -> None:
    with pytest.raises(RingUnavailable, match="cannot create"):
        write(RingWriter(SLOTS, tmp_path / "no-such-dir", HOST), image(1))
    with pytest.raises(ValueError, match="at least 2 slots"):
        RingWriter(1, tmp_path, HOST)
    with pytest.raises(ValueError, match="not a uint8 image"):
        RingWriter(SLOTS, tmp_path, HOST).write(b"abc", (2, 2), "uint8")


def reserve_like(writer: RingWriter, a: np.ndarray) -> SlotLease:
    return writer.reserve(a.shape, str(a.dtype))


def test_a_frame_drawn_into_a_reserved_slot_is_read_only_once_committed(ring) -> None:
    writer, reader = ring
    previous = write(writer, image(1))  # the frame the reader holds
    old_view = reader.view(previous)
    for i in range(SLOTS - 1):  # the next reservation takes the held frame's slot
        write(writer, image(10 + i))
    lease = reserve_like(writer, image(2))
    assert lease.ref.slot == previous.slot and lease.ref.seq == previous.seq + SLOTS
    assert lease.pixels.flags.writeable and lease.pixels.shape == (48, 64, 3)
    # Reserved: the old frame's readers find out at once, and the new one is not there yet.
    assert not reader.intact(previous)
    with pytest.raises(SlotOverwritten):
        reader.view(lease.ref)
    assert writer.copy_frame(writer.segment, lease.ref.seq) is None
    assert writer.copy_frame(writer.segment, previous.seq) is None
    lease.pixels[...] = image(2)  # drawn in place, half way...
    with pytest.raises(SlotOverwritten):
        reader.view(lease.ref)  # ...and still not a frame until committed
    ref = writer.commit(lease)
    assert ref == lease.ref and writer.intact(ref)
    np.testing.assert_array_equal(as_array(reader.view(ref), ref), image(2))
    np.testing.assert_array_equal(as_array(old_view, ref), image(2))  # the same memory
    assert reader.intact(ref) and not reader.intact(previous)
    found = writer.copy_frame(writer.segment, ref.seq)  # a remote reader's whole frame
    assert found is not None and found == (image(2).tobytes(), ref)
    assert writer.commit(lease) == ref and reader.intact(ref)  # once more: nothing changes


def test_a_lease_whose_slot_was_reserved_again_is_never_committed(ring) -> None:
    writer, reader = ring
    lease = reserve_like(writer, image(1))
    lease.pixels[...] = image(1)
    later = [write(writer, image(10 + i)) for i in range(SLOTS)]  # the ring wraps past it
    assert later[-1].slot == lease.ref.slot
    with pytest.raises(SlotOverwritten, match=f"reserved again \\(frame {later[-1].seq}\\)"):
        writer.commit(lease)
    # The slot keeps the later frame, intact; the lease's frame never existed for readers.
    np.testing.assert_array_equal(as_array(reader.view(later[-1]), later[-1]), image(13))
    assert reader.intact(later[-1]) and not writer.intact(lease.ref)
    with pytest.raises(SlotOverwritten):
        reader.view(lease.ref)


def test_a_lease_of_a_replaced_segment_is_never_committed(ring) -> None:
    writer, reader = ring
    lease = reserve_like(writer, image(1, (24, 32, 3)))
    old_segment = writer.segment
    large = write(writer, image(2))  # a larger frame: a new segment, the old one let go
    assert large.segment != old_segment
    assert not (writer.directory / old_segment).exists()
    lease.pixels[...] = image(1, (24, 32, 3))  # still mapped while the lease lives: no fault
    with pytest.raises(SlotOverwritten, match="was replaced"):
        writer.commit(lease)
    assert not writer.intact(lease.ref) and writer.intact(large)
    np.testing.assert_array_equal(as_array(reader.view(large), large), image(2))
    writer.close()  # with a lease still holding the old mapping, and one of its own
    lease2 = reserve_like(writer, image(3))
    writer.close()
    lease2.pixels[...] = 0  # unlinked, still mapped until the lease goes
    assert list(writer.directory.iterdir()) == []

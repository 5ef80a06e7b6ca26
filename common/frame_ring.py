"""Camera frames by reference: a ring of preallocated slots in POSIX shared memory.

One writer (the sim, one ring per camera stream) puts each frame's pixels into the next
slot of a segment in ``/dev/shm`` and sends only a small :class:`FrameRef` (segment, slot,
sequence number, shape, dtype, byte offset) where the pixels would have gone; any number of
readers on the same host map the segment once, read-only, and get a memoryview of the slot.
The writer either copies a finished frame in (:meth:`RingWriter.write`) or draws it straight
into the slot: :meth:`RingWriter.reserve` gives a writable numpy view of the next slot and
:meth:`RingWriter.commit` publishes what was drawn there, so the pixels are never copied at
all, instead of twice through Zenoh's pool and once out again.

Each slot starts with two sequence numbers, written seqlock style: the writer stores the
frame's sequence number in ``seq_begin``, then the pixels, then the same number in
``seq_end``. A reader accepts a slot only when ``seq_end`` equals its descriptor's number
(the write it names is complete, and no later write has finished) and ``seq_begin`` still
equals it (no later write has started); :meth:`RingReader.intact` asks the second question
again after the reader is done with the pixels, so a view that the writer overwrote while it
was in use is detected, and the result computed from it is thrown away. A reserved slot has
its new ``seq_begin`` from :meth:`RingWriter.reserve` on, and its ``seq_end`` only from
:meth:`RingWriter.commit`: while it is being drawn, neither its old frame nor the new one reads
as intact. That order is enough
on CPUs that keep stores in program order (x86-64, the hosts this runs on); a weakly ordered
CPU (ARM) would need fences that Python does not offer.

A ring of :data:`RING_SLOTS` slots holds a stream's last 16 frames, about half a second at
30 Hz: a reader must be done with a frame before the writer has written 16 more. Vision works
on one colour frame at a time and keeps its last 4 depth images, so it meets this by a wide
margin; when it does not (a reader stalled for half a second), the overwrite is detected,
never read as a wrong frame.

A reader on another host, or whose ``/dev/shm`` is not the writer's (a container), cannot map
the segment: :meth:`RingReader.view` raises :class:`RingUnreachable` and the caller gets the
whole frame another way (:mod:`common.publishers` asks the publisher for it). The host is
identified by its hostname and boot id, so a reader does not even try a segment name of
another machine.

Segments are plain files under ``/dev/shm`` (Linux), created with ``os.open`` and reserved
with ``posix_fallocate``, so that a ``/dev/shm`` too small for the ring fails here, at
creation, instead of with SIGBUS at the first write into a page tmpfs cannot back; and so
that no ``multiprocessing`` resource tracker registers (and later unlinks, or warns about) a
segment its process only reads. The writer unlinks its segment when it closes, or when its
process exits normally without closing it; a writer killed outright leaves it behind, and
:func:`remove_segments_of` (the supervisor calls it when a child ends) removes what a process
left. A sim killed with its supervisor (``kill -9`` of the group, the OOM killer) leaves its
segments to no one: the next writer removes those of processes that no longer exist
(:func:`remove_orphan_segments`). Segment names carry the writer's pid and a random token.
"""

from __future__ import annotations

import contextlib
import logging
import math
import mmap
import os
import secrets
import socket
import struct
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from common.processes import pid_exists

log = logging.getLogger("umay")

SHM_DIR = Path("/dev/shm")
SEGMENT_PREFIX = "umay-frames-"
RING_SLOTS = 16
RING_MAGIC = b"UMYRING1"
ALIGN = 64  # slot headers and pixels start on a cache line (and any dtype's alignment)
# Segment header: magic, random token (16 hex chars, also in the name), slots, slot capacity
# in bytes, slot stride in bytes.
SEGMENT_HEADER = struct.Struct("<8s16sIQQ")
SEQS = struct.Struct("<QQ")  # a slot's seq_begin, seq_end
SEQ = struct.Struct("<Q")
ITEMSIZE = {"uint8": 1, "float32": 4}
MAX_READER_SEGMENTS = 4  # mappings a reader keeps (a new segment per size change)
# Every page mapped at once (Linux), by writer and readers: otherwise each of a ring's first
# RING_SLOTS frames pays a page fault per 4 KiB page, drawn or read, on the frame's way.
MAP_FLAGS = mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0)


class RingError(Exception):
    """A frame reference that cannot be resolved into pixels."""


class RingUnavailable(RingError):
    """The writer cannot create a ring here (no ``/dev/shm``, too small, read-only)."""


class RingUnreachable(RingError):
    """The reader cannot map the segment: another host, or the segment is gone."""


class SlotOverwritten(RingError):
    """The slot no longer holds the frame the reference names (the ring wrapped)."""


@cache
def host_identity() -> str:
    """``hostname/boot id``: the same on every process that shares this kernel's boot and
    hostname, different on another machine, or the same one after a reboot."""
    try:
        boot_id = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        boot_id = ""
    return f"{socket.gethostname()}/{boot_id}"


def _aligned(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


@dataclass(frozen=True)
class FrameRef:
    """Where one frame's pixels are: what travels instead of them."""

    host: str  # host_identity() of the writer
    segment: str  # file name under /dev/shm
    slot: int
    seq: int  # the writer's sequence number of this frame (1, 2, ...)
    offset: int  # of the pixels in the segment, bytes
    shape: tuple[int, ...]
    dtype: str

    @property
    def nbytes(self) -> int:
        return math.prod(self.shape) * ITEMSIZE[self.dtype]

    def to_map(self) -> dict[str, Any]:
        return {
            "host": self.host,
            "segment": self.segment,
            "slot": self.slot,
            "seq": self.seq,
            "offset": self.offset,
            "shape": list(self.shape),
            "dtype": self.dtype,
        }

    @classmethod
    def from_map(cls, data: object) -> FrameRef:
        """A reference from its map; ValueError naming what is wrong."""
        if not isinstance(data, dict):
            raise ValueError(f"frame reference: expected a map, got {type(data).__name__}")
        try:
            host, segment = data["host"], data["segment"]
            numbers = [data["slot"], data["seq"], data["offset"]]
            shape, dtype = data["shape"], data["dtype"]
        except KeyError as exc:
            raise ValueError(f"frame reference: missing {exc.args[0]!r}") from None
        if not isinstance(host, str) or not isinstance(segment, str):
            raise ValueError("frame reference: host and segment must be strings")
        if not segment.startswith(SEGMENT_PREFIX) or "/" in segment:
            raise ValueError(f"frame reference: {segment!r} is not a frame ring segment")
        if not all(type(n) is int and n >= 0 for n in numbers):
            raise ValueError("frame reference: slot, seq and offset must be integers >= 0")
        if dtype not in ITEMSIZE:
            raise ValueError(f"frame reference: dtype {dtype!r}")
        if not isinstance(shape, list) or not all(type(d) is int and d > 0 for d in shape):
            raise ValueError(f"frame reference: shape {shape!r}")
        slot, seq, offset = numbers
        return cls(host, segment, slot, seq, offset, tuple(shape), dtype)


@dataclass(frozen=True)
class SlotLease:
    """A slot reserved for a frame (:meth:`RingWriter.reserve`): ``pixels`` is a writable
    view of it, to be filled before :meth:`RingWriter.commit` publishes it as ``ref``."""

    ref: FrameRef
    pixels: np.ndarray


def _slot_offsets(slots: int, capacity_bytes: int) -> tuple[int, int]:
    """(stride, size) of a segment of ``slots`` slots of ``capacity_bytes`` pixels each."""
    stride = ALIGN + _aligned(capacity_bytes)
    return stride, ALIGN + slots * stride


def _unlink(path: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


class RingWriter:
    """The writer's side: a segment created at the first frame, replaced by a new one when a
    frame no longer fits its slots (the old one is unlinked; readers that still map it keep
    their views, which no write touches any more).

    :meth:`write`, :meth:`reserve` and :meth:`commit` run on the publishing thread;
    :meth:`copy_frame` may run on another (a Zenoh query callback) at the same time: the
    seqlock tells it whether what it copied is the frame it asked for."""

    def __init__(
        self, slots: int = RING_SLOTS, directory: Path = SHM_DIR, host: str | None = None
    ) -> None:
        if slots < 2:
            raise ValueError(f"a ring needs at least 2 slots, got {slots}")
        self.slots = slots
        self.directory = directory
        self.host = host or host_identity()
        self.segment = ""  # name of the current segment ("" before the first frame)
        self.capacity_bytes = 0
        self._stride = 0
        self._map: mmap.mmap | None = None
        self._view: memoryview | None = None
        self._seq = 0
        self._refs: dict[int, FrameRef] = {}  # slot → the frame it holds
        self._unlink_at_exit: weakref.finalize | None = None
        self._lock = threading.Lock()  # the segment's replacement against copy_frame

    def reserve(self, shape: tuple[int, ...] | list[int], dtype: str) -> SlotLease:
        """The next slot, to draw a frame of ``shape`` and ``dtype`` into, then
        :meth:`commit`. Its ``seq_begin`` is written now: the frame it held is no longer
        intact for any reader. Raises :class:`RingUnavailable` when no segment for it can be
        made. A lease that is never committed leaves its slot torn (never read as a frame)."""
        ref = self._begin(tuple(int(d) for d in shape), dtype)
        view = self._view
        assert view is not None
        # A slice of its own, so that the segment can be let go while the lease lives on.
        pixels = np.frombuffer(view[ref.offset : ref.offset + ref.nbytes], dtype)
        return SlotLease(ref, pixels.reshape(ref.shape))

    def commit(self, lease: SlotLease) -> FrameRef:
        """Publish what was drawn into ``lease``'s slot: ``seq_end`` is written and the
        reference returned. :class:`SlotOverwritten` when the slot was reserved again since
        (the ring wrapped) or the segment replaced (a larger frame): nothing is written then.
        Committing a committed lease again changes nothing."""
        return self._commit(lease.ref)

    def _commit(self, ref: FrameRef) -> FrameRef:
        view = self._view
        if view is None or ref.segment != self.segment:
            raise SlotOverwritten(f"frame {ref.seq}: segment {ref.segment} was replaced")
        base = ref.offset - ALIGN
        begin = SEQ.unpack_from(view, base)[0]
        if begin != ref.seq:
            raise SlotOverwritten(
                f"frame {ref.seq}: slot {ref.slot} was reserved again (frame {begin})"
            )
        SEQ.pack_into(view, base + SEQ.size, ref.seq)  # seq_end last: the frame is complete
        self._refs[ref.slot] = ref  # for copy_frame
        return ref

    def write(self, pixels: Any, shape: tuple[int, ...] | list[int], dtype: str) -> FrameRef:
        """Copy ``pixels`` (C-contiguous bytes of ``shape`` and ``dtype``) into the next slot:
        :meth:`reserve`, copy, :meth:`commit`. Raises :class:`RingUnavailable` when no
        segment for them can be made."""
        data = memoryview(pixels).cast("B")
        shape = tuple(int(d) for d in shape)
        if len(data) != math.prod(shape) * ITEMSIZE[dtype]:
            raise ValueError(f"{len(data)} bytes are not a {dtype} image of shape {shape}")
        ref = self._begin(shape, dtype)
        view = self._view
        assert view is not None
        view[ref.offset : ref.offset + len(data)] = data
        return self._commit(ref)

    def intact(self, ref: FrameRef) -> bool:
        """Whether the current segment's slot still holds the committed frame ``ref``."""
        view = self._view
        if view is None or ref.segment != self.segment:
            return False
        return SEQS.unpack_from(view, ref.offset - ALIGN) == (ref.seq, ref.seq)

    def _begin(self, shape: tuple[int, ...], dtype: str) -> FrameRef:
        """The next slot's reference for a frame of ``shape``, its ``seq_begin`` written."""
        nbytes = math.prod(shape) * ITEMSIZE[dtype]
        if self._view is None or nbytes > self.capacity_bytes:
            self._replace_segment(nbytes)
        view = self._view
        assert view is not None
        self._seq += 1
        seq, slot = self._seq, self._seq % self.slots
        base = ALIGN + slot * self._stride
        self._refs.pop(slot, None)
        SEQ.pack_into(view, base, seq)  # seq_begin first: readers of the old frame now fail
        return FrameRef(self.host, self.segment, slot, seq, base + ALIGN, shape, dtype)

    def copy_frame(self, segment: str, seq: int) -> tuple[bytes, FrameRef] | None:
        """A copy of the pixels of frame ``seq`` and its reference, if the ring still holds
        it intact (None: another segment, never written, or overwritten since)."""
        with self._lock:
            view = self._view
            if view is None or segment != self.segment:
                return None
            ref = self._refs.get(seq % self.slots)
            if ref is None or ref.seq != seq:
                return None
            base = ref.offset - ALIGN
            if SEQS.unpack_from(view, base) != (seq, seq):
                return None
            data = bytes(view[ref.offset : ref.offset + ref.nbytes])
            if SEQ.unpack_from(view, base)[0] != seq:  # overwritten while copying
                return None
            return data, ref

    def _replace_segment(self, frame_bytes: int) -> None:
        if not self.segment:  # this writer's first: clear what dead writers left
            removed = remove_orphan_segments(self.directory)
            if removed:
                log.info("removed frame rings of ended processes: %s", ", ".join(removed))
        token = secrets.token_hex(8)
        name = f"{SEGMENT_PREFIX}{os.getpid()}-{token}"
        stride, size = _slot_offsets(self.slots, frame_bytes)
        path = self.directory / name
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_RDWR, 0o600)
        except OSError as exc:
            raise RingUnavailable(f"cannot create {path}: {exc.strerror}") from exc
        try:
            try:
                os.posix_fallocate(fd, 0, size)  # the pages exist, or it fails now
            except OSError as exc:
                raise RingUnavailable(
                    f"no room for a ring of {self.slots} frames ({size / 2**20:.1f} MiB) in "
                    f"{self.directory}: {exc.strerror}"
                ) from exc
            new_map = mmap.mmap(fd, size, MAP_FLAGS, mmap.PROT_READ | mmap.PROT_WRITE)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise
        finally:
            os.close(fd)
        SEGMENT_HEADER.pack_into(
            new_map, 0, RING_MAGIC, token.encode(), self.slots, frame_bytes, stride
        )
        with self._lock:
            self._release()
            self._map, self._view = new_map, memoryview(new_map)
            self.segment, self.capacity_bytes, self._stride = name, frame_bytes, stride
            self._refs.clear()
            # Unlinked also if the writer is dropped without close(), or at the interpreter's
            # exit: a forgotten close() must not leave the ring in /dev/shm.
            self._unlink_at_exit = weakref.finalize(self, _unlink, path)

    def _release(self) -> None:
        """Unlink and unmap the current segment (called with the lock held)."""
        if self._view is not None:
            self._view.release()
            self._view = None
        if self._map is not None:
            if self._unlink_at_exit is not None:
                self._unlink_at_exit()  # once: a finalizer does nothing the second time
            # Leases' pixels (and messages made of them) may still view it: then it is
            # unmapped when the last of them goes.
            with contextlib.suppress(BufferError):
                self._map.close()
            self._map = None

    def close(self) -> None:
        """Unlink the segment: readers that map it keep what they have, new ones cannot."""
        with self._lock:
            self._release()
            self.segment = ""


@dataclass(frozen=True)
class _Mapped:
    """A segment as a reader maps it."""

    view: memoryview
    slots: int
    capacity: int  # bytes of pixels a slot holds
    stride: int  # bytes from one slot to the next


class RingReader:
    """The readers' side: maps each segment once (read-only) and resolves references into
    memoryviews of slots. Thread-safe (Zenoh calls back from several threads)."""

    def __init__(
        self,
        directory: Path = SHM_DIR,
        host: str | None = None,
        max_segments: int = MAX_READER_SEGMENTS,
    ) -> None:
        self.directory = directory
        self.host = host or host_identity()
        self.max_segments = max_segments
        self._maps: OrderedDict[str, _Mapped] = OrderedDict()
        self._lock = threading.Lock()

    def view(self, ref: FrameRef) -> memoryview:
        """The frame's pixels in its slot (read-only, no copy). Raises
        :class:`RingUnreachable` or :class:`SlotOverwritten`. The caller must check
        :meth:`intact` again once it is done with them."""
        mapped = self._segment(ref)
        base = ALIGN + ref.slot * mapped.stride
        if ref.slot >= mapped.slots or ref.offset != base + ALIGN or ref.nbytes > mapped.capacity:
            raise RingUnreachable(f"{ref.segment}: no slot {ref.slot} for {ref.nbytes} bytes")
        segment = mapped.view
        begin, end = SEQS.unpack_from(segment, base)
        if end != ref.seq or begin != ref.seq:
            raise SlotOverwritten(
                f"frame {ref.seq} was overwritten in {ref.segment} slot {ref.slot} before it "
                f"was read (the slot holds frame {max(begin, end)})"
            )
        return segment[ref.offset : ref.offset + ref.nbytes]

    def intact(self, ref: FrameRef) -> bool:
        """Whether no write into the frame's slot has begun since the frame was written: a
        view of it taken before still shows that frame. False, to be safe, for a segment this
        reader no longer keeps (more than ``max_segments`` since)."""
        mapped = self._kept(ref)
        return mapped is not None and SEQ.unpack_from(mapped.view, ref.offset - ALIGN)[0] == ref.seq

    def superseded(self, ref: FrameRef) -> bool:
        """Whether the writer has begun a later frame than ``ref`` in the slot after its: a
        newer frame of the stream is drawn or sent, so a consumer that has fallen behind can
        skip this one (frames are written slot after slot). False for a segment this reader
        does not keep."""
        mapped = self._kept(ref)
        if mapped is None:
            return False
        following = (ref.slot + 1) % mapped.slots
        return SEQ.unpack_from(mapped.view, ALIGN + following * mapped.stride)[0] > ref.seq

    def _kept(self, ref: FrameRef) -> _Mapped | None:
        """The segment of ``ref`` if this reader keeps it mapped (never maps one)."""
        with self._lock:
            return self._maps.get(ref.segment)

    def _segment(self, ref: FrameRef) -> _Mapped:
        if ref.host != self.host:
            raise RingUnreachable(f"frames of another host ({ref.host})")
        with self._lock:
            mapped = self._maps.get(ref.segment)
            if mapped is not None:
                self._maps.move_to_end(ref.segment)
                return mapped
        mapped = self._open(ref.segment)
        with self._lock:
            self._maps[ref.segment] = mapped
            while len(self._maps) > self.max_segments:
                # Not unmapped: views of it may still be in use; the mapping goes with them.
                self._maps.popitem(last=False)
        return mapped

    def _open(self, name: str) -> _Mapped:
        path = self.directory / name
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError as exc:
            raise RingUnreachable(f"cannot open {path}: {exc.strerror}") from exc
        try:
            size = os.fstat(fd).st_size
            if size < SEGMENT_HEADER.size:
                raise RingUnreachable(f"{path}: {size} bytes, not a frame ring")
            mapped = mmap.mmap(fd, size, MAP_FLAGS, mmap.PROT_READ)
        finally:
            os.close(fd)
        magic, token, slots, capacity, stride = SEGMENT_HEADER.unpack_from(mapped, 0)
        if magic != RING_MAGIC or not name.endswith(token.decode(errors="replace")):
            mapped.close()
            raise RingUnreachable(f"{path}: not a frame ring")
        if _slot_offsets(slots, capacity) != (stride, size):
            mapped.close()
            raise RingUnreachable(f"{path}: inconsistent ring header")
        return _Mapped(memoryview(mapped), slots, capacity, stride)

    def close(self) -> None:
        """Forget every mapping (each is unmapped once no view of it is left)."""
        with self._lock:
            self._maps.clear()


_shared_reader: RingReader | None = None
_shared_lock = threading.Lock()


def shared_reader() -> RingReader:
    """This process's reader (one mapping per segment for all its subscribers)."""
    global _shared_reader
    with _shared_lock:
        if _shared_reader is None:
            _shared_reader = RingReader()
        return _shared_reader


def remove_orphan_segments(directory: Path = SHM_DIR) -> list[str]:
    """Unlink the segments whose writer (the pid in the name, looked up in this host's pid
    namespace) no longer exists; their names."""
    names = (p.name.removeprefix(SEGMENT_PREFIX) for p in directory.glob(f"{SEGMENT_PREFIX}*-*"))
    pids = {int(pid) for pid, _, _ in (n.partition("-") for n in names) if pid.isdigit()}
    ended = sorted(pid for pid in pids if not pid_exists(pid))
    return [name for pid in ended for name in remove_segments_of(pid, directory)]


def remove_segments_of(pid: int, directory: Path = SHM_DIR) -> list[str]:
    """Unlink the segments a process (ended, for instance killed) left; their names."""
    removed = []
    for path in directory.glob(f"{SEGMENT_PREFIX}{pid}-*"):
        with contextlib.suppress(OSError):
            path.unlink()
            removed.append(path.name)
    return removed

"""Typed publishers, and camera frames by reference.

Camera frames go **by reference** between processes of one host: the pixels are in a
shared-memory ring (:mod:`common.frame_ring`), drawn there in place by a producer that asked
for the slot first (:meth:`TypedPublisher.reserve`) or else copied in, and the publisher puts
on the frame's key the same message with the pixels replaced by a small reference
(:mod:`common.codec`'s layout version 2); a subscriber's decoding resolves it into the usual
``RgbFrame``/``DepthFrame`` whose image is a view of the ring's slot. This is an optimisation
of the key's contract, not a second protocol: the key, the message and every subscriber's code
stay the same. A subscriber that cannot map the ring (another host, a ``/dev/shm`` of its own,
the segment gone) gets the whole frame from the publisher, which answers
``<frame key>/whole?segment=S;seq=N`` from its ring (:class:`RingPublisher`,
:func:`fetch_whole_frame`): one request per frame, asked without blocking the callback, so
such a subscriber gets every frame a little later, and a publisher with no remote subscriber
never sends a whole frame at all. Publishing the whole frame as well, on another key, for
remote subscribers was the alternative; it would have made every tool (recorder, replay,
``umay status``) know two keys for one stream. ``$UMAY_ZENOH_SHM=0`` turns frames by
reference off with Zenoh's shared memory: frames then go whole, by copy.

A producer that draws into reserved slots keeps its messages as usual: the image of a message
is a view of the slot, and putting it again (a lockstep resend) sends the same reference again,
as long as the slot still holds that frame; the publisher never copies from a slot that has
been written since, nor commits a reservation twice.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np
import zenoh
from pydantic import BaseModel

from common.codec import (
    FrameUnreachable,
    MessageError,
    by_reference,
    decode,
    encode,
    frame_parts,
    image_field,
)
from common.frame_ring import (
    RING_SLOTS,
    FrameRef,
    RingError,
    RingReader,
    RingUnavailable,
    RingWriter,
    SlotLease,
)
from common.keys import whole_frame_key
from common.messages import Header, ImageData, Stamp
from common.metrics import TopicMeter
from common.session import shm_enabled

M = TypeVar("M", bound=BaseModel)
log = logging.getLogger("umay")


STAMPS_KEPT = 4096  # per key: about 2 min of a 30 Hz stream
STAMPS_MAX_BYTES = 1 << 20  # a stamps reply: the sim has 5 keys × 4096 stamps × ≤ 24 bytes


class RingPublisher:
    """A camera stream's frames by reference: each frame's pixels go into a
    :class:`~common.frame_ring.RingWriter` of this publisher's own and the payload carries
    only their reference; the publisher answers ``<key>/whole`` with the whole frame of a
    reference for subscribers that cannot map the ring. Where the host cannot give a ring (no
    ``/dev/shm``, too small, read-only, as in some containers) every frame goes whole, by
    copy, and :attr:`unavailable` says why.

    :meth:`reserve` lends the next slot to draw the next frame into; a message whose image is
    that slot's view is then committed without a copy (:attr:`in_place`), any other copied
    into the slot (:attr:`copied`)."""

    def __init__(self, session: zenoh.Session, key: str, slots: int = RING_SLOTS) -> None:
        self.key = key
        self.ring = RingWriter(slots)
        self.served = 0  # whole frames sent to subscribers that could not map the ring
        self.in_place = 0  # frames committed where they were drawn (no copy)
        self.copied = 0  # frames copied into a slot
        self.unavailable = ""  # why there is no ring ("": there is one, or not yet)
        # slot → (ring seq, frame_parts head) of the frame the slot holds, for the answers
        self._heads: dict[int, tuple[int, bytes]] = {}
        self._lease: SlotLease | None = None  # reserved, not yet committed
        # slot → the committed lease, to know a message put again (its image is the lease's)
        self._committed: dict[int, SlotLease] = {}
        self._queryable = session.declare_queryable(whole_frame_key(key), self._answer)

    def reserve(self, shape: tuple[int, ...], dtype: str) -> np.ndarray | None:
        """A writable view of the slot the next frame will go into, to draw it there (None
        without a ring). A reservation not put is given up at the next one."""
        if self.unavailable:
            return None
        try:
            self._lease = self.ring.reserve(shape, dtype)
        except RingUnavailable as exc:
            self._no_ring(exc)
            return None
        self._committed.pop(self._lease.ref.slot, None)
        return self._lease.pixels

    def payload(self, message: BaseModel) -> tuple[bytes, bool]:
        """What to put for ``message`` and whether it is by reference: its reference, or the
        whole frame without a ring."""
        head, pixels = frame_parts(message)
        if not self.unavailable:
            try:
                ref = self._into_ring(pixels, getattr(message, image_field(type(message)) or ""))
            except RingUnavailable as exc:
                self._no_ring(exc)
            else:
                self._heads[ref.slot] = (ref.seq, head)
                return by_reference(head, ref), True
        return b"".join((head, pixels)), False

    def _into_ring(self, pixels: memoryview, image: ImageData) -> FrameRef:
        """The reference of ``pixels`` in the ring: committed in place when they are the
        reserved slot's view, the same again when they are a committed slot's (a message put
        again), else copied into the reserved slot or the next one."""
        owner = pixels.obj  # the array a view of a slot was made from (ImageData.view_of)
        lease, self._lease = self._lease, None
        for sent in self._committed.values():
            if sent.pixels is owner:
                if not self.ring.intact(sent.ref):  # never resend pixels written since
                    raise RingError(f"{self.key}: frame {sent.ref.seq} was overwritten")
                return sent.ref
        shape, dtype = tuple(image.shape), image.dtype
        if lease is None or lease.ref.shape != shape or lease.ref.dtype != dtype:
            self.copied += 1
            return self.ring.write(pixels, shape, dtype)
        if lease.pixels is owner:
            self.in_place += 1
        else:
            memoryview(lease.pixels).cast("B")[:] = pixels
            self.copied += 1
        ref = self.ring.commit(lease)
        self._committed[ref.slot] = lease
        return ref

    def _no_ring(self, exc: RingUnavailable) -> None:
        self.unavailable = str(exc)
        self._lease = None
        log.warning("%s: camera frames go whole, by copy (%s)", self.key, exc)

    def _answer(self, query: zenoh.Query) -> None:
        """The whole frame ``segment``/``seq`` of the query's parameters (Zenoh's thread)."""
        try:
            segment = query.parameters.get("segment") or ""
            seq = int(query.parameters.get("seq") or -1)
            found = self.ring.copy_frame(segment, seq)
            entry = self._heads.get(found[1].slot) if found else None
            if found is None or entry is None or entry[0] != seq:
                query.reply_err(f"frame {seq} of {segment} is no longer in the ring".encode())
                return
            query.reply(query.key_expr, entry[1] + found[0])
            self.served += 1
        except Exception:  # an answer must never take the service down
            log.exception("%s: whole-frame answer failed", self.key)

    def close(self) -> None:
        self._queryable.undeclare()
        self.ring.close()


def fetch_whole_frame(
    session: zenoh.Session,
    key: str,
    ref: FrameRef,
    on_frame: Callable[[bytes], None],
    on_failure: Callable[[str], None],
    timeout_s: float = 1.0,
) -> None:
    """Ask the publisher of ``key`` for the whole frame ``ref`` names, without waiting:
    ``on_frame`` gets its payload (ordinary frame layout), or ``on_failure`` why not, on a
    Zenoh thread. Safe to call from a subscriber's callback."""
    answered = False

    def on_reply(reply: zenoh.Reply) -> None:
        nonlocal answered
        if answered:
            return
        answered = True
        if reply.ok is not None:
            on_frame(reply.ok.payload.to_bytes())
        else:
            on_failure(reply.err.payload.to_bytes().decode(errors="replace"))

    def on_done() -> None:
        if not answered:
            on_failure(f"no answer from {whole_frame_key(key)} within {timeout_s:g} s")

    selector = f"{whole_frame_key(key)}?segment={ref.segment};seq={ref.seq}"
    session.get(selector, zenoh.handlers.Callback(on_reply, on_done), timeout=timeout_s)


def decode_or_fetch(
    session: zenoh.Session,
    key: str,
    payload: bytes,
    model: type[M],
    max_bytes: int,
    on_message: Callable[[M, float | None], None],
    on_reject: Callable[[str], None],
    rings: RingReader | None = None,
) -> None:
    """What a subscriber does with a sample's ``payload`` on ``key``: ``on_message(message,
    fetched_s)`` gets it decoded and validated, at once (``fetched_s`` None), or, for a camera
    frame by reference to a ring this process cannot map (``rings``, default the process's
    shared reader), once its publisher has sent it whole (:func:`fetch_whole_frame`;
    ``fetched_s`` the wall-clock time it came, before its decode; on a Zenoh thread).
    ``on_reject`` gets why a payload, or a frame asked for whole, cannot be used."""
    try:
        message = decode(payload, model, max_bytes, rings)
    except FrameUnreachable as exc:
        seq = exc.ref.seq

        def on_whole(whole: bytes) -> None:
            came_s = time.time()  # the decode counts as processing, as for any message
            try:
                fetched = decode(whole, model, max_bytes)
            except MessageError as error:
                on_reject(f"whole frame {seq}: {error}")
                return
            on_message(fetched, came_s)

        fetch_whole_frame(
            session, key, exc.ref, on_whole, lambda why: on_reject(f"whole frame {seq}: {why}")
        )
        return
    except MessageError as exc:
        on_reject(str(exc))
        return
    on_message(message, None)


@dataclass
class TypedPublisher(Generic[M]):
    key: str
    publisher: Any
    meter: TopicMeter = field(default_factory=TopicMeter)
    frames: RingPublisher | None = None  # camera frames by reference
    # The header stamps of the last messages put, for the service's stamps queryable.
    stamps: deque[Stamp] = field(default_factory=lambda: deque(maxlen=STAMPS_KEPT))
    # Held for the whole of a put: its counters (the meter's, the ring's) change together for
    # whoever reads them under the same lock (Node.status, on a Zenoh thread).
    counting: threading.Lock = field(default_factory=threading.Lock)

    @property
    def matched(self) -> bool:
        """Whether this session knows of a subscriber to the key (Zenoh's matching status):
        until then a put reaches nobody."""
        return bool(self.publisher.matching_status.matching)

    def reserve(self, shape: tuple[int, ...], dtype: str) -> np.ndarray | None:
        """Where to draw the next camera frame's image so that it goes by reference without a
        copy: a writable view of the ring's next slot (:meth:`RingPublisher.reserve`), or
        None (no ring: draw it anywhere). The message put next has that view as its image
        (``ImageData.view_of``)."""
        return None if self.frames is None else self.frames.reserve(shape, dtype)

    def put(self, message: M) -> None:
        """Encode and put ``message``; a camera frame put again whose ring slot has been
        written since raises :class:`~common.frame_ring.RingError` (its pixels are gone)."""
        with self.counting:
            self._put(message)

    def _put(self, message: M) -> None:
        is_frame = image_field(type(message)) is not None
        if self.frames is not None and is_frame:
            payload, by_ref = self.frames.payload(message)
        else:
            payload, by_ref = encode(message), False
        self.publisher.put(payload)
        self.meter.tick()
        if is_frame:
            self.meter.by_ref += by_ref
            self.meter.by_copy += not by_ref
        header = getattr(message, "header", None)
        if isinstance(header, Header):
            self.stamps.append((header.frame_seq, header.recv_time_s, header.send_time_s))

    def close(self) -> None:
        """Undeclare; a ring of frames by reference is unlinked."""
        if self.frames is not None:
            self.frames.close()
        self.publisher.undeclare()


def typed_publisher(
    session: zenoh.Session,
    key: str,
    block: bool = True,
    frames: bool = False,
    counting: threading.Lock | None = None,
) -> TypedPublisher[Any]:
    """A :class:`TypedPublisher` on ``key`` (see :meth:`Node.publisher` for the options);
    ``counting``: the lock its puts hold (its own when None)."""
    cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
    ring = RingPublisher(session, key) if frames and shm_enabled() else None
    publisher = session.declare_publisher(key, congestion_control=cc)
    return TypedPublisher(key, publisher, frames=ring, counting=counting or threading.Lock())

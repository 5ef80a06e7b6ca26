"""Typed publishers, and camera frames by reference.

Camera frames go **by reference** between processes of one host: the publisher copies the
pixels into a shared-memory ring (:mod:`common.frame_ring`) and puts on the frame's key the
same message with the pixels replaced by a small reference (:mod:`common.codec`'s layout
version 2); a subscriber's decoding resolves it into the usual ``RgbFrame``/``DepthFrame``
whose image is a view of the ring's slot. This is an optimisation of the key's contract, not a
second protocol: the key, the message and every subscriber's code stay the same. A subscriber
that cannot map the ring (another host, a ``/dev/shm`` of its own, the segment gone) gets the
whole frame from the publisher, which answers ``<frame key>/whole?segment=S;seq=N`` from its
ring (:class:`RingPublisher`, :func:`fetch_whole_frame`): one request per frame, asked without
blocking the callback, so such a subscriber gets every frame a little later, and a publisher
with no remote subscriber never sends a whole frame at all. Publishing the whole frame as well,
on another key, for remote subscribers was the alternative; it would have made every tool
(recorder, replay, ``umay status``) know two keys for one stream. ``$UMAY_ZENOH_SHM=0`` turns
frames by reference off with Zenoh's shared memory: frames then go whole, by copy.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import zenoh
from pydantic import BaseModel

from common.codec import (
    by_reference,
    encode,
    frame_parts,
    image_field,
)
from common.frame_ring import RING_SLOTS, FrameRef, RingUnavailable, RingWriter
from common.keys import whole_frame_key
from common.messages import Header, Stamp
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
    copy, and :attr:`unavailable` says why."""

    def __init__(self, session: zenoh.Session, key: str, slots: int = RING_SLOTS) -> None:
        self.key = key
        self.ring = RingWriter(slots)
        self.served = 0  # whole frames sent to subscribers that could not map the ring
        self.unavailable = ""  # why there is no ring ("": there is one, or not yet)
        # slot → (ring seq, frame_parts head) of the frame the slot holds, for the answers
        self._heads: dict[int, tuple[int, bytes]] = {}
        self._queryable = session.declare_queryable(whole_frame_key(key), self._answer)

    def payload(self, message: BaseModel) -> tuple[bytes, bool]:
        """What to put for ``message`` and whether it is by reference: its reference, or the
        whole frame without a ring."""
        head, pixels = frame_parts(message)
        if not self.unavailable:
            image = getattr(message, image_field(type(message)) or "")
            try:
                ref = self.ring.write(pixels, image.shape, image.dtype)
            except RingUnavailable as exc:
                self.unavailable = str(exc)
                log.warning("%s: camera frames go whole, by copy (%s)", self.key, exc)
            else:
                self._heads[ref.slot] = (ref.seq, head)
                return by_reference(head, ref), True
        return b"".join((head, pixels)), False

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


@dataclass
class TypedPublisher(Generic[M]):
    key: str
    publisher: Any
    meter: TopicMeter = field(default_factory=TopicMeter)
    frames: RingPublisher | None = None  # camera frames by reference
    # The header stamps of the last messages put, for the service's stamps queryable.
    stamps: deque[Stamp] = field(default_factory=lambda: deque(maxlen=STAMPS_KEPT))

    def put(self, message: M) -> None:
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
    session: zenoh.Session, key: str, block: bool = True, frames: bool = False
) -> TypedPublisher[Any]:
    """A :class:`TypedPublisher` on ``key`` (see :meth:`Node.publisher` for the options)."""
    cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
    ring = RingPublisher(session, key) if frames and shm_enabled() else None
    return TypedPublisher(key, session.declare_publisher(key, congestion_control=cc), frames=ring)

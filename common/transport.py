"""Zenoh helpers: session configuration and a small node base with one event inbox.

A node declares typed publishers and subscribers; subscriber callbacks (Zenoh threads) only
decode and validate, then hand the message to the node's single event loop through
:meth:`Node.next_event`, so service state is touched by one thread only (as in dora-rs nodes).
A payload that fails validation is counted, its reason kept and logged at a limited rate; it
never reaches the service and never kills it.

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

import json
import logging
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import zenoh
from pydantic import BaseModel

from common.codec import (
    DEFAULT_MAX_BYTES,
    FrameUnreachable,
    MessageError,
    by_reference,
    decode,
    encode,
    frame_parts,
    image_field,
)
from common.frame_ring import RING_SLOTS, FrameRef, RingReader, RingUnavailable, RingWriter
from common.keys import Keys, whole_frame_key
from common.messages import Header, PublishedStamps, ServiceStatus, Stamp
from common.metrics import DurationMeter, TopicMeter

M = TypeVar("M", bound=BaseModel)

ENV_CONFIG = "UMAY_ZENOH_CONFIG"  # path of a Zenoh JSON5 config file: used as is
ENV_CONNECT = "UMAY_ZENOH_CONNECT"  # comma-separated endpoints to connect to
# "0": no shared memory, so payloads take the network path even between processes on one host
# (what a peer on another host gets); benchmarks compare both. Applies to config files too.
ENV_SHM = "UMAY_ZENOH_SHM"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"  # where `umay up` listens and tools connect

log = logging.getLogger("umay")


class ZenohConfigError(ValueError):
    """A Zenoh config file that cannot be read; the message names the file and the reason."""


def zenoh_config(
    config_path: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
) -> zenoh.Config:
    """Peer mode, loopback only, multicast scouting off, unless a config file says otherwise.

    Precedence: ``config_path`` argument, then ``$UMAY_ZENOH_CONFIG``, then the defaults with
    ``connect`` (argument, else ``$UMAY_ZENOH_CONNECT``, else :data:`DEFAULT_ENDPOINT`).
    Peers find each other through gossip over the first connection. With a config file, an
    explicit ``connect`` (argument or environment) replaces the file's endpoints, so one file
    (say a client's credentials) serves wherever the router happens to be.

    Zenoh's shared memory is on by default: between processes on one host, payloads above
    3 KB (camera frames) go through a shared pool instead of the socket, and a peer that
    cannot map it (another host) gets them over the network. ``$UMAY_ZENOH_SHM=0`` turns it
    off.
    """
    cfg = _base_config(config_path, connect, listen)
    if not shm_enabled():
        cfg.insert_json5("transport/shared_memory/enabled", "false")
    return cfg


def _base_config(
    config_path: str | None, connect: list[str] | None, listen: list[str] | None
) -> zenoh.Config:
    if connect is None:
        env = os.environ.get(ENV_CONNECT, "")
        connect = [e for e in env.split(",") if e] or None
    path = config_path or os.environ.get(ENV_CONFIG)
    if path:
        try:
            cfg = zenoh.Config.from_file(path)
            if connect:
                cfg.insert_json5("connect/endpoints", json.dumps(connect))
        except zenoh.ZError as exc:
            raise ZenohConfigError(f"{path}: not a usable Zenoh config: {exc}") from exc
        return cfg
    connect = connect if connect is not None else [DEFAULT_ENDPOINT]
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("listen/endpoints", json.dumps(listen or ["tcp/127.0.0.1:0"]))
    cfg.insert_json5("connect/endpoints", json.dumps(connect))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


def check_endpoints(value: str) -> list[str]:
    """The comma-separated Zenoh endpoints in ``value`` (``tcp/127.0.0.1:7447,...``), each
    checked by Zenoh's own parser; ValueError naming the first bad one and why."""
    endpoints = [e.strip() for e in value.split(",")]
    for endpoint in endpoints:
        try:
            zenoh.Config().insert_json5("connect/endpoints", json.dumps([endpoint]))
        except zenoh.ZError:
            raise ValueError(
                f"invalid endpoint {endpoint!r}: expected <protocol>/<address>[?<metadata>], "
                f"e.g. {DEFAULT_ENDPOINT}"
            ) from None
    return endpoints


def open_session(
    config_path: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
) -> zenoh.Session:
    """A session on :func:`zenoh_config` (opened by :func:`open_zenoh`). Raises
    :class:`ZenohConfigError` for a bad config file, ``zenoh.ZError`` if it cannot open."""
    return open_zenoh(zenoh_config(config_path, connect, listen))


def open_zenoh(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open(config)``; where the host cannot give Zenoh shared memory (no writable
    ``/dev/shm``, as in some containers, where Zenoh fails to open at all) it opens without
    it, with a warning: large payloads then go over the network."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        # Only for shared memory's errors ("Unable to create POSIX shm segment"): a retry
        # after any other (a router that does not answer) would double the wait for nothing.
        if "shm" not in str(exc).lower():
            raise
        config.insert_json5("transport/shared_memory/enabled", "false")
        try:
            session = zenoh.open(config)
        except zenoh.ZError:
            raise exc from None  # the first error is the one to report
        log.warning("Zenoh session opened without shared memory (%s)", zenoh_reason(exc))
        return session


def zenoh_reason(exc: zenoh.ZError) -> str:
    """A Zenoh error's message without the Rust source location that ends it."""
    return str(exc).split(" at /", 1)[0]


def free_tcp_endpoint() -> str:
    """A loopback endpoint on a port that is free right now (for tests and the supervisor)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


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


def shm_enabled() -> bool:
    """False when ``$UMAY_ZENOH_SHM=0`` turns Zenoh's shared memory, and frames by
    reference, off."""
    return os.environ.get(ENV_SHM, "").strip() != "0"


STAMPS_KEPT = 4096  # per key: about 2 min of a 30 Hz stream
STAMPS_MAX_BYTES = 1 << 20  # a stamps reply: the sim has 5 keys × 4096 stamps × ≤ 24 bytes


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


class Node:
    """One service: a Zenoh session, typed pub/sub, a status queryable, a liveliness token.

    ``status_fields`` returns the service-specific part of the status answer.
    """

    def __init__(
        self,
        service: str,
        keys: Keys,
        session: zenoh.Session,
        status_fields: Callable[[], dict[str, Any]] = dict,
        degraded_reason: Callable[[], str] = str,
    ) -> None:
        self.service = service
        self.keys = keys
        self.session = session
        self.state = "starting"
        self._status_fields = status_fields
        self._degraded_reason = degraded_reason
        self.processing = DurationMeter()
        self._started = time.monotonic()
        self._seq = 0
        self._cond = threading.Condition()
        # (key, message, wall-clock receive time): the time goes into the headers of what
        # handling the message publishes (Header.recv_time_s), for per-hop latency.
        self._inbox: deque[tuple[str, BaseModel, float]] = deque()
        self.event_recv_time_s = 0.0  # receive time of the event next_event returned last
        self._handling_recv_time_s = 0.0  # ... while spin() handles it, else 0
        self._latest_only: set[str] = set()
        self._publishers: dict[str, TypedPublisher[Any]] = {}
        self._subscribers: list[Any] = []
        self.received: dict[str, TopicMeter] = {}
        self.rejected = 0
        self.last_rejection = ""
        self._last_reject_log = 0.0
        self._closed = False
        # When the event loop last left next_event (None: it has not called it yet) and
        # whether it is inside it now: the status's loop_busy_s, read by the supervisor.
        self._loop_left_s: float | None = None
        self._loop_waiting = False
        self._queryable = session.declare_queryable(keys.status(service), self._answer_status)
        self._stamps_queryable = session.declare_queryable(
            keys.stamps(service), self._answer_stamps
        )
        self._token: Any = None

    def ready(self) -> None:
        """Subscriptions are in place: announce liveliness and report ``running``."""
        self.state = "running"
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.service))

    # --- publishing -------------------------------------------------------------------
    def publisher(self, key: str, block: bool = True, frames: bool = False) -> TypedPublisher[Any]:
        """``block``: back-pressure instead of dropping when the network is congested.
        ``frames``: camera frames, sent by reference through a shared-memory ring
        (:class:`RingPublisher`) unless shared memory is off."""
        pub = typed_publisher(self.session, key, block, frames)
        self._publishers[key] = pub
        return pub

    def header(self, sim_time_s: float, frame_seq: int, recv_time_s: float | None = None) -> Header:
        """A fresh header: per-node sequence number, wall-clock send time, and the receive time
        of the event being handled by :meth:`spin` (0 outside one) unless ``recv_time_s``."""
        recv = self._handling_recv_time_s if recv_time_s is None else recv_time_s
        h = Header(
            seq=self._seq,
            sim_time_s=sim_time_s,
            send_time_s=time.time(),
            frame_seq=frame_seq,
            recv_time_s=recv,
        )
        self._seq += 1
        return h

    # --- subscribing ------------------------------------------------------------------
    def subscribe(
        self,
        key: str,
        model: type[M],
        max_bytes: int = DEFAULT_MAX_BYTES,
        latest_only: bool = False,
        rings: RingReader | None = None,
    ) -> None:
        """Deliver validated ``model`` messages on ``key`` to :meth:`next_event`.

        ``latest_only``: an undelivered older message on the same key is replaced (and counted
        as dropped), so a slow consumer always works on the newest data.
        ``rings``: what maps the publisher's ring for camera frames sent by reference
        (default: the process's :func:`~common.frame_ring.shared_reader`); a frame it cannot
        map is asked whole from the publisher (:func:`fetch_whole_frame`).
        """
        meter = self.received[key] = TopicMeter()
        if latest_only:
            self._latest_only.add(key)
        field = image_field(model)
        newest_seq = -1  # header.seq of the newest message delivered on this key

        def deliver(message: BaseModel, received: float, by_ref: bool, fetched: bool) -> None:
            nonlocal newest_seq
            seq = message.header.seq if isinstance(getattr(message, "header", None), Header) else -1
            with self._cond:
                if fetched and seq < newest_seq:  # a newer frame came first: this one is late
                    meter.dropped += 1
                    return
                newest_seq = max(newest_seq, seq)
                meter.tick()
                if field is not None:
                    meter.by_ref += by_ref
                    meter.by_copy += not by_ref
                    meter.fetched += fetched
                if key in self._latest_only:
                    for i, (k, _, _) in enumerate(self._inbox):
                        if k == key:
                            del self._inbox[i]
                            meter.dropped += 1
                            break
                self._inbox.append((key, message, received))
                self._cond.notify()

        def on_whole_frame(payload: bytes) -> None:
            received = time.time()
            try:
                message = decode(payload, model, max_bytes)
            except MessageError as exc:
                self._reject(key, f"whole frame: {exc}")
                return
            deliver(message, received, by_ref=False, fetched=True)

        def on_sample(sample: zenoh.Sample) -> None:
            received = time.time()  # before the copy and decode: those count as processing
            try:
                message = decode(sample.payload.to_bytes(), model, max_bytes, rings)
            except FrameUnreachable as exc:  # by reference, but not to a ring this host maps
                seq = exc.ref.seq
                fetch_whole_frame(
                    self.session,
                    key,
                    exc.ref,
                    on_whole_frame,
                    lambda reason: self._reject(key, f"whole frame {seq}: {reason}"),
                )
                return
            except MessageError as exc:
                self._reject(key, str(exc))
                return
            by_ref = field is not None and getattr(message, field).ring_ref is not None
            deliver(message, received, by_ref, fetched=False)

        self._subscribers.append(self.session.declare_subscriber(key, on_sample))

    def next_event(self, timeout_s: float | None) -> tuple[str, Any] | None:
        """The next ``(key, message)``, or None after ``timeout_s`` or when closed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            self._loop_waiting = True
            try:
                while not self._inbox and not self._closed:
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        return None
                    self._cond.wait(remaining)
                if not self._inbox:
                    return None
                key, message, self.event_recv_time_s = self._inbox.popleft()
                return key, message
            finally:
                self._loop_waiting = False
                self._loop_left_s = time.monotonic()

    def reject(self, key: str, reason: str) -> None:
        """Count a message on ``key`` the service could not use (a frame whose ring slot was
        overwritten while it was in use): as a payload that failed validation."""
        self._reject(key, reason)

    def _reject(self, key: str, reason: str) -> None:
        with self._cond:
            self.rejected += 1
            self.last_rejection = f"{key}: {reason}"
        now = time.monotonic()
        if now - self._last_reject_log > 1.0:  # rate-limited: a flood must not flood the log
            self._last_reject_log = now
            log.warning(
                "%s rejected a message (%d so far): %s", self.service, self.rejected, reason
            )

    # --- status -----------------------------------------------------------------------
    def status(self) -> ServiceStatus:
        now = time.monotonic()
        reason = self._degraded_reason() if self.state == "running" else ""
        p50, p99 = self.processing.percentiles()
        return ServiceStatus(
            service=self.service,
            pid=os.getpid(),
            host=socket.gethostname(),
            uptime_s=now - self._started,
            state="degraded" if reason else self.state,  # type: ignore[arg-type]
            degraded_reason=reason,
            received={k: m.stats(now) for k, m in self.received.items()},
            published={k: p.meter.stats(now) for k, p in self._publishers.items()},
            rejected=self.rejected,
            last_rejection=self.last_rejection,
            processing_ms_p50=p50,
            processing_ms_p99=p99,
            loop_busy_s=self.loop_busy_s(now),
            fields=self._status_fields(),
        )

    def loop_busy_s(self, now_s: float) -> float | None:
        """Seconds since the event loop left :meth:`next_event` (0 while it is inside)."""
        left = self._loop_left_s
        if left is None:
            return None
        return 0.0 if self._loop_waiting else max(0.0, now_s - left)

    def _answer_status(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.status(self.service), encode(self.status()))
        except Exception:  # a status reply must never take the service down
            log.exception("%s: status reply failed", self.service)

    def published_stamps(self) -> PublishedStamps:
        return PublishedStamps(
            service=self.service,
            stamps={self.keys.relative(k): list(p.stamps) for k, p in self._publishers.items()},
        )

    def _answer_stamps(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.stamps(self.service), encode(self.published_stamps()))
        except Exception:  # as for status: a diagnostic must never take the service down
            log.exception("%s: stamps reply failed", self.service)

    def spin(
        self,
        stop: threading.Event,
        on_event: Callable[[str, Any], None],
        timeout_s: float = 0.1,
        on_idle: Callable[[], None] | None = None,
    ) -> None:
        """The node's one event loop: announce readiness, handle events until ``stop``, close.

        ``on_idle`` runs after every wake-up (an event or ``timeout_s`` without one).
        """
        self.ready()
        try:
            while not stop.is_set():
                event = self.next_event(timeout_s)
                if event is not None:
                    started = time.perf_counter()
                    self._handling_recv_time_s = self.event_recv_time_s
                    try:
                        on_event(*event)
                    finally:
                        self._handling_recv_time_s = 0.0
                    self.processing.add(1000.0 * (time.perf_counter() - started))
                if on_idle is not None:
                    on_idle()
        finally:
            self.close()

    def close(self) -> None:
        self.state = "stopping"
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        for s in self._subscribers:
            s.undeclare()
        for p in self._publishers.values():
            if p.frames is not None:
                p.frames.close()  # the ring's segment is unlinked
        self._queryable.undeclare()
        self._stamps_queryable.undeclare()
        if self._token is not None:
            self._token.undeclare()
        self.session.close()


def status_from_reply(reply: zenoh.Reply) -> ServiceStatus | None:
    """The status in a reply to a status query; None for an error reply. MessageError when
    the payload is not a valid status."""
    if reply.ok is None:
        return None
    return decode(reply.ok.payload.to_bytes(), ServiceStatus, DEFAULT_MAX_BYTES)


def query_status(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> list[ServiceStatus]:
    """Ask every service under ``keys.prefix`` for its status."""
    out = []
    for reply in session.get(keys.all_status, timeout=timeout_s):
        try:
            status = status_from_reply(reply)
        except MessageError as exc:
            log.warning("bad status reply: %s", exc)
            continue
        if status is not None:
            out.append(status)
    return out


def query_stamps(
    session: zenoh.Session, keys: Keys, service: str, timeout_s: float = 2.0
) -> PublishedStamps | None:
    """``service``'s :class:`PublishedStamps`, or None when it does not answer in time."""
    for reply in session.get(keys.stamps(service), timeout=timeout_s):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), PublishedStamps, STAMPS_MAX_BYTES)
    return None


def setup_logging(service: str) -> None:
    logging.basicConfig(
        level=os.environ.get("UMAY_LOG_LEVEL", "INFO"),
        format=f"%(asctime)s {service} %(levelname)s %(message)s",
    )


def alive_services(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> set[str]:
    """Services whose liveliness token is present under ``keys.prefix``."""
    names = set()
    for reply in session.liveliness().get(keys.all_alive, timeout=timeout_s):
        if reply.ok is not None:
            names.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return names
